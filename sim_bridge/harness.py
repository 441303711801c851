"""Run the whole product on the virtual cell as separate processes, as a user would.

Used by `leadthrough demo`, `leadthrough bench` and the stack tests: it writes a cell config and
a simulator truth file for free loopback ports and a CAN socket address of its own (so stacks run
side by side), starts ``leadthrough sim`` and
``leadthrough gateway`` (which starts the drivers and the control process), talks to the gateway
like an operator, and tears everything down, child processes included.

On a machine with two CPUs or more the virtual cell and the product can run on different ones
(``Stack(place=True)``, :func:`placement`): the simulator on the last CPU this process may use,
the product on the others (its cell config's ``[realtime] cpu_affinity``).
"""

from __future__ import annotations

import contextlib
import copy
import csv
import os
import secrets
import signal
import socket
import subprocess
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import tomli_w

from drivers.can.seqpacket import socket_address
from gateway.bus import BusConfig
from gateway.config import load_toml
from gateway.operator_request import OperatorClient
from gateway.parent_death import ENV as PARENT_ENV
from sim_bridge import proc_stat
from sim_bridge.sim import truth_log_columns

REPO = Path(__file__).resolve().parent.parent
SIM_CELL = REPO / "deploy" / "config" / "sim_cell.toml"
TRUTH = Path(__file__).with_name("gr630st_truth.toml")
#: SCHED_FIFO priority of the virtual controller in real-time runs and of its I/O module in
#: all runs (Stack.__init__)
VIRTUAL_CONTROLLER_FIFO_PRIORITY = 60

SIM_CELL_CIA402 = REPO / "deploy" / "config" / "sim_cell_cia402.toml"
TRUTH_CIA402 = Path(__file__).with_name("gr630st_truth_cia402.toml")


def _cia402_profile() -> tuple[dict[str, Any], dict[str, Any]]:
    """The CiA 402 drives ([controller] of gr630st_truth_cia402.toml) and the product's [can]
    for them (sim_cell_cia402.toml, its EDS path made absolute)."""
    controller = load_toml(TRUTH_CIA402)["controller"]
    can_section = copy.deepcopy(load_toml(SIM_CELL_CIA402)["can"])
    eds = Path(can_section["cia402"]["eds"])
    can_section["cia402"]["eds"] = str(eds if eds.is_absolute() else SIM_CELL_CIA402.parent / eds)
    can_section.pop("transport", None)
    return {"controller": controller}, {"can": can_section}


#: The CAN profiles (drivers/can/PROTOCOL.md §2 and §10, and CiA 402 drives over CANopen) as
#: (virtual controller overrides, cell config overrides): both ends must speak the same one.
CAN_PROFILES: dict[str, tuple[dict[str, Any], dict[str, Any]]] = {
    "classic": ({}, {}),
    "fd": (
        {"controller": {"can_profile": "fd"}},
        {"can": {"adapter": "ltc_fd", "transport": {"fd": True}}},
    ),
    "cia402": _cia402_profile(),
}
#: [can].adapter → the virtual controller's [controller].can_profile that speaks to it
VIRTUAL_PROFILE = {"ltc_dbc": "classic", "ltc_fd": "fd", "cia402": "cia402"}


class TruthTail:
    """The newest rows of the simulator's truth log, read incrementally: each
    :meth:`update` parses only the lines appended since the last one, and only ``columns``.
    A whole read of the growing file (:meth:`Stack.truth`) takes tens of ms of CPU once the
    log holds seconds at 500 rows a second: from the product it runs beside, and between a
    condition seen and acted on. ``first_teaching_t_s`` and ``last_teaching_t_s`` are the
    first and the newest row's ``t_s`` with ``teaching`` set (when both columns are read)."""

    def __init__(self, path: Path, columns: Sequence[str], keep: int = 100) -> None:
        self.path, self.names, self.keep = path, list(columns), keep
        self._offset, self._pending = 0, b""
        self._index: list[int] | None = None
        self._rows = np.zeros((0, len(self.names)))
        self.first_teaching_t_s: float | None = None
        self.last_teaching_t_s: float | None = None

    def update(self) -> np.ndarray:
        """The newest (at most ``keep``) rows, shape (k, len(columns))."""
        if not self.path.exists():
            return self._rows
        with self.path.open("rb") as fh:
            fh.seek(self._offset)
            chunk = fh.read()
        self._offset += len(chunk)
        *lines, self._pending = (self._pending + chunk).split(b"\n")
        new: list[list[float]] = []
        for line in lines:
            parts = line.split(b",")
            if self._index is None:
                header = [p.decode() for p in parts]
                self._index = [header.index(n) for n in self.names]
                self._width = len(header)
                continue
            if len(parts) == self._width:
                new.append([float(parts[i]) for i in self._index])
        if new:
            rows = np.array(new)
            if {"t_s", "teaching"} <= set(self.names):
                t, teach = rows[:, self.names.index("t_s")], rows[:, self.names.index("teaching")]
                on = np.flatnonzero(teach > 0.5)
                if on.size:
                    if self.first_teaching_t_s is None:
                        self.first_teaching_t_s = float(t[on[0]])
                    self.last_teaching_t_s = float(t[on[-1]])
            self._rows = np.vstack([self._rows, rows])[-self.keep :]
        return self._rows


#: the columns :func:`tail_tool_speed` reads, in this order
TOOL_COLUMNS = ("t_s", "tool_x", "tool_y", "tool_z")


def tail_tool_speed(rows: np.ndarray, span: int, end: int = -1) -> float:
    """Tool speed [m/s] over the ``span`` rows up to row ``end`` of :class:`TruthTail` rows
    whose first columns are :data:`TOOL_COLUMNS`."""
    a, b = rows[end - span], rows[end]
    return float(np.linalg.norm(b[1:4] - a[1:4]) / (b[0] - a[0]))


def free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def deep_merge(base: dict[str, Any], over: dict[str, Any]) -> dict[str, Any]:
    out = copy.deepcopy(base)
    for k, v in over.items():
        if isinstance(v, dict) and isinstance(out.get(k), dict):
            out[k] = deep_merge(out[k], v)
        else:
            out[k] = copy.deepcopy(v)
    return out


def unique_can_address() -> str:
    """An abstract-namespace seqpacket address no other stack uses (no file to clean up)."""
    return f"@leadthrough-{os.getpid()}-{secrets.token_hex(4)}"


def placement() -> tuple[tuple[int, ...], tuple[int, ...]] | None:
    """(the product's CPUs, the simulator's) when this process may use two CPUs or more:
    the simulator gets the last, the product the others; None on one CPU."""
    cpus = sorted(os.sched_getaffinity(0))
    if len(cpus) < 2:
        return None
    return tuple(cpus[:-1]), (cpus[-1],)


def pin_process_tree(pid: int, cpus: tuple[int, ...]) -> int:
    """Set the CPU affinity of every thread of ``pid`` and of its descendants (threads and
    processes started later inherit it); returns how many threads were pinned. Threads or
    processes that exit meanwhile are skipped."""
    pinned, todo = 0, [pid]
    while todo:
        task_dir = Path(f"/proc/{todo.pop()}/task")
        try:
            tids = [int(t.name) for t in task_dir.iterdir()]
        except OSError:
            continue
        for tid in tids:
            with contextlib.suppress(OSError):
                os.sched_setaffinity(tid, cpus)
                pinned += 1
            with contextlib.suppress(OSError, ValueError):
                todo += [int(c) for c in (task_dir / str(tid) / "children").read_text().split()]
    return pinned


def running_with_argument(arg: str | Path) -> dict[int, str]:
    """Every live process but this one with ``arg`` as one of its command-line arguments:
    pid → command line (zombies left out)."""
    marker = str(arg).encode()
    found = {}
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit() or int(entry.name) == os.getpid():
            continue
        try:
            argv = (entry / "cmdline").read_bytes()
        except OSError:
            continue
        if marker in argv.split(b"\0") and proc_stat.state(int(entry.name)) not in (None, "Z"):
            found[int(entry.name)] = argv.replace(b"\0", b" ").decode(errors="replace")
    return found


def _wait_seqpacket(address: str, timeout_s: float, proc: subprocess.Popen) -> None:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if proc.poll() is not None:
            raise RuntimeError(f"process exited with {proc.returncode} before opening {address}")
        try:
            with socket.socket(socket.AF_UNIX, socket.SOCK_SEQPACKET) as s:
                s.connect(socket_address(address))
                return
        except OSError:
            time.sleep(0.05)
    raise TimeoutError(f"nothing listening on {address} after {timeout_s} s")


def _wait_port(host: str, port: int, timeout_s: float, proc: subprocess.Popen) -> None:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if proc.poll() is not None:
            raise RuntimeError(f"process exited with {proc.returncode} before opening {port}")
        try:
            with socket.create_connection((host, port), timeout=0.2):
                return
        except OSError:
            time.sleep(0.05)
    raise TimeoutError(f"nothing listening on {host}:{port} after {timeout_s} s")


#: the gateway's joint-state watchdog in lock-step runs [s]: twice the controller's wait
LOCKSTEP_STATE_TIMEOUT_S = 0.5
#: the CAN driver's wait for a command in lock-step runs ([can].lockstep_answer_wait_s) [s]:
#: the most it allows, under the virtual controller's own 0.25 s wait for an answer
LOCKSTEP_ANSWER_WAIT_S = 0.2
#: how long the gateway's children may take to stop after it did [s]
STOP_GRACE_S = 5.0


class Stack:
    """The product + virtual cell, each a separate process."""

    def __init__(
        self,
        workdir: Path,
        sim_overrides: dict[str, Any] | None = None,
        cell_overrides: dict[str, Any] | None = None,
        lockstep: bool = False,
        quiet: bool = True,
        plant_seed: int = 0,
        model: str | Path | None = None,
        inner_loop: str | Path | None = None,
        current_zero: str | Path | None = None,
        place: bool = False,
        cell_file: Path = SIM_CELL,
    ) -> None:
        """``plant_seed``: the virtual robot drawn (:mod:`sim_bridge.truth`; 0 is the truth
        file as written). ``model``: what the control process compensates: a ``model.json``
        path (with the ``inner_loop.json`` of the same identification, or None), or None for
        a cell that is not commissioned yet (it identifies but refuses to teach); the plant
        seed's commissioned model is :func:`.commission.commissioned_stack`'s. ``current_zero``:
        the ``current_zero.json`` of that identification (the CAN driver keeps the current
        sensors' zero the model was identified with; None: it measures one now). ``place``:
        run the simulator and the product on different CPUs (:func:`placement`). Off by
        default: placed, the loop answers more cycles in time (`leadthrough bench --place`),
        but `make demo`'s replay took 22-23 s instead of 17.6 s and the identified model's
        J2 error in it read 17-29 N·m instead of 9.7 (one run each, 2026-11-27; not traced),
        and four of the five lock-step stack tests took 8-16 % longer in one `make test`.
        ``cell_file``: the product's cell config to start from (its ``[can].adapter`` picks
        the virtual controller that speaks to it, :data:`VIRTUAL_PROFILE`)."""
        self.workdir = Path(workdir)
        self.workdir.mkdir(parents=True, exist_ok=True)
        self.lockstep = lockstep
        self.quiet = quiet
        self.ports = {"bus": free_port(), "modbus": free_port()}
        self.can_address = unique_can_address()
        self.bus = BusConfig(endpoint=f"tcp/127.0.0.1:{self.ports['bus']}")
        cell = load_toml(cell_file)
        eds = cell.get("can", {}).get("cia402", {}).get("eds")
        if eds and not Path(eds).is_absolute():
            cell["can"]["cia402"]["eds"] = str(Path(cell_file).resolve().parent / eds)
        if current_zero is not None:
            cell["can"]["current_zero_file"] = str(current_zero)
        for key, path in (("model", model), ("inner_loop", inner_loop)):
            if path is not None:
                cell["control"][key] = str(path)
        cell = deep_merge(
            cell,
            {
                "bus": {"endpoint": self.bus.endpoint},
                "can": {"transport": {"interface": "seqpacket", "channel": self.can_address}},
                "modbus": {"port": self.ports["modbus"]},
            },
        )
        if lockstep:
            # Lock-step, the product paces the joint-state stream: the virtual controller waits
            # up to ``lockstep_timeout_s`` (0.25 s) for each answer, so a product process that
            # stalls (a cold start compiling its imports on a loaded machine) pauses the stream
            # that long without anything being wrong with the link. The gateway's watchdog
            # must outlast that wait, or it faults the cell on the test's own pacing. Lock-step
            # runs the simulator flat out, and the loaded machine answers Modbus polls late
            # too: the I/O watchdogs get the same allowance (commissioning in `make test`
            # faulted once on a Modbus reply 0.2 s late).
            # The CAN driver waits for each command as the virtual controller does: a command
            # late by the machine's load then slows the virtual plant instead of cutting holds
            # and coasts into the motion commissioning records (under CPU steal, 14-245 per
            # segment, and a model 4x its noise floor, 2026-11-29).
            # CiA 402 drives never wait: the host's SYNC clocks them, and in lock-step each
            # SYNC advances the virtual plant by one servo cycle (its [controller]
            # cycle_period_s, set to the host's SYNC period), so the bus waits for the host.
            wait = LOCKSTEP_STATE_TIMEOUT_S
            answer_wait = {} if cell.get("can", {}).get("adapter") == "cia402" else {
                "can": {"lockstep_answer_wait_s": LOCKSTEP_ANSWER_WAIT_S}
            }  # fmt: skip
            cell = deep_merge(
                cell,
                {
                    "gateway": {"joint_state_timeout_s": wait, "io_timeout_s": wait},
                    "control": {"io_timeout_s": wait},
                    **answer_wait,
                },
            )
        self.placement = placement() if place else None
        if self.placement is not None:
            cell = deep_merge(cell, {"realtime": {"cpu_affinity": list(self.placement[0])}})
        self.cell = deep_merge(cell, cell_overrides or {})
        credentials = self.cell.get("bus", {}).get("credentials_file", "")
        if credentials:  # a locked bus: the harness's requests come as the operator
            self.bus = replace(self.bus, credentials_file=str(credentials))
        truth = load_toml(TRUTH)
        truth = deep_merge(
            truth,
            {
                "plant_seed": plant_seed,
                "endpoints": {
                    "can_interface": "seqpacket",
                    "can_channel": self.can_address,
                    "modbus_port": self.ports["modbus"],
                },
            },
        )
        # The virtual controller stands for the robot's controller, a computer of its own
        # that the cell PC's load never delays; sharing the test machine with the product,
        # it starved with it under load (65 cycles late, 59 ms at worst, the I/O module's
        # replies 0.1 s late) and the gateway faulted for want of joint states, a fault
        # no real cell has. So its processes run at SCHED_FIFO above the product's
        # (deploy/config/cell.toml: 40) where the OS permits; elsewhere it runs on, and its
        # summary's "scheduling" says what was refused. Lock-step runs too: their loop waits
        # for the product's every answer, but the product's wall-clock watchdogs do not wait
        # for the loop (at normal priority it stalled 1.06 s beside two busy processes,
        # session 88; sim_bridge/sim.py VirtualCell.open).
        truth = deep_merge(
            truth, {"scheduling": {"sched_fifo_priority": VIRTUAL_CONTROLLER_FIFO_PRIORITY}}
        )
        # The virtual controller that speaks the product's adapter (explicit overrides win).
        adapter = self.cell.get("can", {}).get("adapter", "ltc_dbc")
        truth = deep_merge(truth, CAN_PROFILES.get(VIRTUAL_PROFILE.get(adapter, ""), ({},))[0])
        self.truth_cfg = deep_merge(truth, sim_overrides or {})
        self.cell_path = self.workdir / "cell.toml"
        self.truth_path = self.workdir / "truth.toml"
        self.cell_path.write_bytes(tomli_w.dumps(self.cell).encode())
        self.truth_path.write_bytes(tomli_w.dumps(self.truth_cfg).encode())
        self.truth_log = self.workdir / "truth.csv"
        self.sim_summary = self.workdir / "sim_summary.json"
        self.sim: subprocess.Popen | None = None
        self.gateway: subprocess.Popen | None = None
        self._logs: list[Any] = []
        self._client: OperatorClient | None = None

    def _spawn(self, name: str, args: list[str]) -> subprocess.Popen:
        out = (self.workdir / f"{name}.log").open("w")
        self._logs.append(out)
        # the simulator and the gateway stop when this process dies (gateway/parent_death.py)
        env = {**os.environ, "PYTHONUNBUFFERED": "1", PARENT_ENV: str(os.getpid())}
        return subprocess.Popen(
            [sys.executable, "-m", "gateway.cli", *args],
            stdout=out,
            stderr=subprocess.STDOUT,
            start_new_session=True,
            cwd=REPO,
            env=env,
        )

    def start(self, duration_s: float | None = None, timeout_s: float = 30.0) -> None:
        sim_args = ["sim", "--truth", str(self.truth_path), "--log", str(self.truth_log),
                    "--summary", str(self.sim_summary)]  # fmt: skip
        if self.lockstep:
            sim_args.append("--lockstep")
        if duration_s is not None:
            sim_args += ["--duration", str(duration_s)]
        self.sim = self._spawn("sim", sim_args)
        _wait_seqpacket(self.can_address, timeout_s, self.sim)
        _wait_port("127.0.0.1", self.ports["modbus"], timeout_s, self.sim)
        if self.placement is not None:  # every thread and the I/O process are up by now
            pin_process_tree(self.sim.pid, self.placement[1])
        self.gateway = self._spawn("gateway", ["gateway", "--config", str(self.cell_path)])

    def request(self, command: str, timeout_s: float = 3.0, **fields: Any) -> dict[str, Any]:
        """An operator command's reply, over one kept session (``wait_status`` polls every
        0.1 s: :class:`~gateway.operator_request.OperatorClient`)."""
        if self._client is None or self._client.bus != self.bus:
            if self._client is not None:
                self._client.close()
            self._client = OperatorClient(self.bus)
        return self._client.request(command, timeout_s, **fields)

    def restart_gateway(self, timeout_s: float = 10.0) -> None:
        """Start the gateway again (after a test killed it); the simulator runs on.

        The killed gateway's children must have stopped first (they get SIGTERM when it
        dies): one left running would keep the controller's heartbeat alive and answer its
        cycles next to the new gateway's CAN driver. RuntimeError (after killing them) if
        any is still running after ``timeout_s``."""
        if self.gateway is not None and self.gateway.poll() is None:
            raise RuntimeError("the gateway is still running")
        left = self.wait_gone(self.product_pids(), timeout_s)
        if left:
            raise RuntimeError(
                f"the killed gateway's children were still running {timeout_s} s later "
                f"(killed now): {left}"
            )
        self.gateway = self._spawn("gateway2", ["gateway", "--config", str(self.cell_path)])

    def product_pids(self) -> dict[int, str]:
        """Every running process started with this stack's cell config (the gateway and its
        children, also orphans of a killed gateway): pid → command line."""
        return running_with_argument(self.cell_path)

    def wait_gone(self, pids: dict[int, str], timeout_s: float) -> dict[int, str]:
        """Wait up to ``timeout_s`` for ``pids`` to exit; SIGKILL and return those that did
        not."""
        deadline = time.monotonic() + timeout_s
        while pids and time.monotonic() < deadline:
            time.sleep(0.05)
            pids = {pid: cmd for pid, cmd in pids.items() if pid in self.product_pids()}
        for pid in pids:
            with contextlib.suppress(ProcessLookupError):
                os.kill(pid, signal.SIGKILL)
        return pids

    def wait_status(
        self, predicate: Callable[[dict[str, Any]], bool], timeout_s: float, what: str
    ) -> dict[str, Any]:
        deadline = time.monotonic() + timeout_s
        last: dict[str, Any] = {}
        while time.monotonic() < deadline:
            self.check_alive()
            last = self.request("status", timeout_s=1.0)
            if predicate(last):
                return last
            time.sleep(0.1)
        raise TimeoutError(
            f"waited {timeout_s} s for {what}; last status: {last}; {self._truth_tail()}"
        )

    def _truth_tail(self, seconds: float = 1.0) -> str:
        """What the simulator's truth says the arm did in the last ``seconds`` (for a failure
        message: the product's own view of it is in the status)."""
        try:
            truth = self.truth()
        except (OSError, ValueError) as exc:
            return f"no truth log: {exc}"
        t = truth["t_s"]
        if t.size == 0:
            return "the truth log is empty"
        recent = t >= t[-1] - seconds
        dq = np.stack([truth[f"dq{j + 1}"][recent] for j in range(6)], axis=1)
        q = np.stack([truth[f"q{j + 1}"][recent] for j in range(6)], axis=1)
        return (
            f"truth over the last {seconds} s (sim t {t[-1]:.2f} s, controller state "
            f"{truth['ctrl_state'][-1]:.0f}): max |dq| {np.round(np.abs(dq).max(0), 5).tolist()} "
            f"rad/s, q span {np.round(np.ptp(q, 0), 6).tolist()} rad, "
            f"hand force {np.round([truth[k][-1] for k in ('f_x', 'f_y', 'f_z')], 1).tolist()} N"
        )

    def start_teaching(self, timeout_s: float = 40.0, **fields: Any) -> dict[str, Any]:
        """Wait until the cell can start, send `start` (with ``fields``, e.g. ``guide``), wait
        for TEACHING."""
        self.wait_status(lambda s: s.get("can_start") is True, timeout_s, "cell ready to start")
        reply = self.request("start", **fields)
        if not reply.get("ok"):
            raise RuntimeError(f"start refused: {reply}")
        return self.wait_status(lambda s: s.get("state") == "teaching", 10.0, "teaching")

    def check_alive(self) -> None:
        for name, proc in (("sim", self.sim), ("gateway", self.gateway)):
            if proc is not None and proc.poll() is not None:
                log = (self.workdir / f"{name}.log").read_text()[-3000:]
                raise RuntimeError(f"{name} exited with {proc.returncode}:\n{log}")

    def child_pid(self, name: str) -> int:
        status = self.request("status")
        return int(status["processes"][name]["pid"])

    def stop(self) -> list[str]:
        """Stop the gateway (which stops its children) then the simulator; kill stragglers.
        Returns what had to be killed (empty when everything stopped as it should)."""
        killed = []
        if self._client is not None:
            self._client.close()
            self._client = None
        # One after the other, as a cell is switched off: the virtual controller outlives the
        # product's stop, so the CAN driver's exit BRAKE reaches it. (Signalled together, the
        # simulator closed the CAN hub under the stopping driver, whose every exit logged
        # "CAN socket closed by the peer" and "could not send the BRAKE request".)
        for name, proc in (("gateway", self.gateway), ("sim", self.sim)):
            if proc is None:
                continue
            if proc.poll() is None:
                proc.send_signal(signal.SIGTERM)
            try:
                proc.wait(timeout=10.0)
            except subprocess.TimeoutExpired:
                os.killpg(proc.pid, signal.SIGKILL)
                proc.wait()
                killed.append(f"{name} (pid {proc.pid}) ignored SIGTERM for 10 s")
        # The gateway's children live in their own sessions, and an orphan of a killed
        # gateway is nobody's child: find them by their config.
        stragglers = self.wait_gone(self.product_pids(), STOP_GRACE_S)
        killed += [f"pid {pid} still running: {cmd}" for pid, cmd in stragglers.items()]
        for f in self._logs:
            f.close()
        self._logs = []
        return killed

    def truth(self) -> dict[str, np.ndarray]:
        """The simulator's per-cycle truth log as columns."""
        with self.truth_log.open() as fh:
            rows = list(csv.reader(fh))
        if not rows:
            return {name: np.zeros(0) for name in truth_log_columns(6)}
        header, body = rows[0], rows[1:]
        if body and len(body[-1]) != len(header):
            body = body[:-1]  # last line may be cut if read while the simulator writes
        data = np.array(body, dtype=float) if body else np.zeros((0, len(header)))
        return {name: data[:, i] for i, name in enumerate(header)}

    def wait_teaching(self, seconds: float, timeout_s: float) -> dict[str, np.ndarray]:
        """Wait until the truth log holds ``seconds`` of teaching; returns the log.

        The log is read incrementally (:class:`TruthTail`): parsing the whole growing file four
        times a second took tens of ms of CPU each time from the product it was waiting for."""
        deadline = time.monotonic() + timeout_s
        tail = TruthTail(self.truth_log, ("t_s", "teaching"), keep=1)
        while time.monotonic() < deadline:
            self.check_alive()
            tail.update()
            first, last = tail.first_teaching_t_s, tail.last_teaching_t_s
            if first is not None and last is not None and last - first >= seconds:
                return self.truth()
            time.sleep(0.25)
        try:  # why: a fault's reason, or the state teaching ended in
            last: Any = self.request("status", timeout_s=1.0)
        except (OSError, RuntimeError, TimeoutError) as exc:
            last = f"no status: {exc}"
        raise TimeoutError(
            f"no {seconds} s of teaching within {timeout_s} s; status: {last}; {self._truth_tail()}"
        )

    def __enter__(self) -> Stack:
        return self

    def __exit__(self, exc_type: type[BaseException] | None, *exc: object) -> None:
        killed = self.stop()
        if killed and exc_type is None:
            raise RuntimeError(f"the stack did not stop cleanly: {'; '.join(killed)}")
