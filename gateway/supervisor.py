"""`leadthrough gateway`: hosts the zenoh router, supervises the driver and control processes,
owns the lifecycle and answers operator requests.

Children are started as ``python -m gateway.cli <process> --config CELL --bus ENDPOINT``. A child
that exits is a fault (the robot is stopped) and is restarted after a back-off, so that `reset`
can bring the cell back once the cause is gone.
"""

from __future__ import annotations

import argparse
import ctypes
import json
import logging
import signal
import subprocess
import sys
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path

from gateway.bus import BusConfig, bus_config_from, open_router, undeclare_all
from gateway.config import from_mapping, load_toml, require
from gateway.errors import MessageError
from gateway.lifecycle import LifecycleMachine, Limits, Observations
from gateway.messages import (
    LIFECYCLE_RATE_HZ,
    IoState,
    JointState,
    Lifecycle,
    LifecycleMsg,
    decode_json,
    encode_json,
)

#: A static-load check older than this (at the control process's last health) does not count [s].
LOAD_CHECK_MAX_AGE_S = 0.5

log = logging.getLogger("leadthrough.gateway")

SUPERVISED = ("can-driver", "modbus-driver", "control")
TICK_S = 0.01
STOP_GRACE_S = 0.3  #: after announcing STOPPED on exit, before children are terminated
TERMINATE_TIMEOUT_S = 3.0
PR_SET_PDEATHSIG = 1


@dataclass(frozen=True)
class GatewayConfig:
    """``[gateway]`` section of the cell config."""

    joint_state_timeout_s: float = 0.1
    io_timeout_s: float = 0.25
    standstill_rad_s: float = 5e-4  #: teaching starts only below this joint speed [rad/s]
    standstill_s: float = 0.3  #: ... held for this long [s]
    health_timeout_s: float = 0.5  #: a child whose heartbeat is older is "silent"
    restart_backoff_s: float = 2.0
    processes: tuple[str, ...] = SUPERVISED

    def __post_init__(self) -> None:
        for p in self.processes:
            require(p in SUPERVISED, "[gateway].processes", f"{p!r} not one of {SUPERVISED}")


@dataclass
class Child:
    name: str
    argv: list[str]
    proc: subprocess.Popen | None = None
    started_s: float = 0.0
    restart_at_s: float | None = None
    exits: list[int] = field(default_factory=list)


class Gateway:
    def __init__(self, cell_path: Path, bus: BusConfig, cfg: GatewayConfig, spawn: bool = True):
        self.cell_path = cell_path
        self.bus = bus
        self.keys = bus.keys
        self.cfg = cfg
        self.machine = LifecycleMachine(
            Limits(
                cfg.joint_state_timeout_s,
                cfg.io_timeout_s,
                cfg.standstill_rad_s,
                cfg.standstill_s,
            )
        )
        self.lock = threading.Lock()
        self.stop_event = threading.Event()
        self.spawn = spawn
        self.joint_state: JointState | None = None
        self._joint_state_raw: tuple[bytes, float] | None = None
        self._moving_s: float | None = None  #: last time a joint moved faster than standstill
        self.joint_state_rx_s: float | None = None
        self.io: IoState | None = None
        self.io_rx_s: float | None = None
        self.health_rx_s: dict[str, float] = {}
        #: the control process's static-load check (control/load_check.py) as last reported
        self.load_check: dict | None = None
        self.children: dict[str, Child] = {}
        self.session = None
        self._decls: list = []
        self._last_pub_s = 0.0
        self._last_seq = -1
        self._dead: tuple[str, ...] = ()  #: children not running, as of the last tick

    # --- processes ----------------------------------------------------------------------
    def _argv(self, name: str) -> list[str]:
        return [sys.executable, "-m", "gateway.cli", name, "--config", str(self.cell_path),
                "--bus", self.bus.endpoint]  # fmt: skip

    def _start_child(self, child: Child) -> None:
        log.info("starting %s", child.name)
        # Same process group as the gateway (a terminal's Ctrl-C or a killpg reaches them all),
        # and the kernel sends SIGTERM if the gateway itself dies.
        child.proc = subprocess.Popen(child.argv, preexec_fn=_die_with_parent)
        child.started_s = time.monotonic()
        child.restart_at_s = None

    def _poll_children(self, now: float) -> list[str]:
        dead = []
        for child in self.children.values():
            if child.proc is not None and child.proc.poll() is not None:
                code = child.proc.returncode
                child.exits.append(code)
                child.proc = None
                child.restart_at_s = now + self.cfg.restart_backoff_s
                log.error("%s exited with code %s; restarting in %.1f s", child.name, code,
                          self.cfg.restart_backoff_s)  # fmt: skip
                with self.lock:
                    self.machine.fault(f"process {child.name} exited (code {code})")
            if child.proc is None:
                if child.restart_at_s is not None and now >= child.restart_at_s:
                    self._start_child(child)
                else:
                    dead.append(child.name)
        return dead

    def _stop_children(self) -> None:
        for child in self.children.values():
            if child.proc is not None and child.proc.poll() is None:
                child.proc.send_signal(signal.SIGTERM)
        deadline = time.monotonic() + TERMINATE_TIMEOUT_S
        for child in self.children.values():
            if child.proc is None:
                continue
            try:
                child.proc.wait(max(0.0, deadline - time.monotonic()))
            except subprocess.TimeoutExpired:
                log.error("%s did not stop; killing it", child.name)
                child.proc.kill()
                child.proc.wait()

    # --- bus ------------------------------------------------------------------------------
    def _on_state(self, sample) -> None:
        # Arrives every controller cycle: keep the bytes; the 100 Hz tick decodes the latest.
        raw = sample.payload.to_bytes()
        with self.lock:
            self._joint_state_raw = (raw, time.monotonic())

    def _decode_latest_state(self) -> None:
        """Decode the newest joint state (call with the lock held)."""
        item, self._joint_state_raw = self._joint_state_raw, None
        if item is None:
            return
        try:
            st = JointState.from_bytes(item[0])
        except MessageError as exc:
            log.warning("ignored joint state: %s", exc)
            return
        self.joint_state, self.joint_state_rx_s = st, item[1]
        if float(abs(st.dq_rad_s).max()) > self.cfg.standstill_rad_s or self._moving_s is None:
            self._moving_s = item[1]

    def _on_io(self, sample) -> None:
        try:
            io = IoState.from_bytes(sample.payload.to_bytes())
        except MessageError as exc:
            log.warning("ignored I/O state: %s", exc)
            return
        with self.lock:
            self.io, self.io_rx_s = io, time.monotonic()

    def _on_health(self, sample) -> None:
        name = str(sample.key_expr).rsplit("/", 1)[-1]
        load_check = None
        if name == "control":
            try:
                load_check = decode_json(sample.payload.to_bytes(), "control health").get(
                    "load_check"
                )
            except MessageError as exc:
                log.warning("control health unreadable: %s", exc)
        with self.lock:
            self.health_rx_s[name] = time.monotonic()
            if name == "control":
                self.load_check = load_check if isinstance(load_check, dict) else None

    def observations(self, now: float, dead: tuple[str, ...] = ()) -> Observations:
        st, io = self.joint_state, self.io
        stale = []
        for name in self.children:
            key = name.replace("-", "_")
            child = self.children[name]
            rx = self.health_rx_s.get(key)
            booting = child.proc is not None and now - child.started_s < 10.0 and rx is None
            if (
                child.proc is not None
                and not booting
                and (rx is None or now - rx > self.cfg.health_timeout_s)
            ):
                stale.append(name)
        return Observations(
            joint_state_age_s=None
            if self.joint_state_rx_s is None
            else now - self.joint_state_rx_s,
            io_age_s=None if self.io_rx_s is None else now - self.io_rx_s,
            controller_state=None if st is None else st.controller_state,
            enabling=bool(io and io.enabling),
            estop_ok=bool(io.estop_ok) if io else True,
            dead_processes=dead,
            stale_processes=tuple(stale),
            max_speed_rad_s=None if st is None else float(abs(st.dq_rad_s).max()),
            still_for_s=0.0 if self._moving_s is None else now - self._moving_s,
            load_problem=self._load_problem(),
        )

    def _load_problem(self) -> str | None:
        """Why the static-load check does not allow teaching (None: it passed, and recently)."""
        check = self.load_check
        if check is None:
            return "no static-load check from the control process yet (servo on, arm at rest)"
        age = check.get("age_s")
        if not isinstance(age, int | float) or age > LOAD_CHECK_MAX_AGE_S:
            return f"the control process's static-load check is {age} s old"
        if check.get("ok") is not True:
            return str(check.get("message", "static-load check failed"))
        return None

    def status(self, now: float) -> dict:
        obs = self.observations(now, self._dead)
        st = self.joint_state
        return {
            "state": self.machine.state.name.lower(),
            "reason": self.machine.reason,
            "seq": self.machine.seq,
            "can_start": not self.machine.link_problems(obs),
            "problems": self.machine.link_problems(obs),
            "controller_state": None if st is None else st.controller_state.name.lower(),
            "enabling": obs.enabling,
            "estop_ok": obs.estop_ok,
            "load_problem": obs.load_problem,
            "joint_state_age_s": obs.joint_state_age_s,
            "io_age_s": obs.io_age_s,
            "processes": {
                n: {
                    "running": c.proc is not None,
                    "pid": None if c.proc is None else c.proc.pid,
                    "exits": c.exits,
                }
                for n, c in self.children.items()
            },
            "q_rad": None if st is None else [round(float(v), 6) for v in st.q_rad],
        }

    def _on_experiment(self, sample) -> None:
        try:
            msg = decode_json(sample.payload.to_bytes(), "experiment")
            plan_id, state = str(msg["plan_id"]), str(msg["state"])
        except (MessageError, KeyError) as exc:
            log.warning("ignored experiment message: %s", exc)
            return
        if state in ("done", "failed"):
            with self.lock:
                self.machine.plan_finished(plan_id, state == "done", str(msg.get("reason", "")))

    def _on_request(self, query) -> None:
        now = time.monotonic()
        try:
            req = decode_json(query.payload.to_bytes() if query.payload else b"", "request")
            command = str(req.get("command", ""))
            plan = req.get("plan")
            if command == "identify" and not (isinstance(plan, dict) and plan.get("plan_id")):
                raise MessageError("identify needs a 'plan' object with a 'plan_id'")
        except MessageError as exc:
            reply = {"ok": False, "message": str(exc)}
        else:
            with self.lock:
                self._decode_latest_state()
                obs = self.observations(now, self._dead)
                if command == "identify":
                    ok, message = self.machine.identify(plan, obs)
                else:
                    ok, message = self.machine.command(command, obs)
                reply = {"ok": ok, "message": message, **self.status(now)}
            log.info("operator %s → %s: %s", command, "ok" if ok else "refused", message)
        query.reply(query.key_expr, encode_json(reply))

    def _publish_lifecycle(self, now: float) -> None:
        m = self.machine
        if m.seq != self._last_seq or now - self._last_pub_s >= 1.0 / LIFECYCLE_RATE_HZ:
            extra = {"plan": m.plan} if m.state == Lifecycle.IDENTIFYING and m.plan else {}
            msg = LifecycleMsg(m.state, m.seq, now, m.reason, extra)
            self.session.put(self.keys.lifecycle, msg.to_bytes())
            if m.seq != self._last_seq:
                log.info("lifecycle → %s (%s)", m.state.name, m.reason)
            self._last_pub_s, self._last_seq = now, m.seq

    # --- main -----------------------------------------------------------------------------
    def open(self) -> None:
        self.session = open_router(self.bus)
        s = self.session
        self._decls = [
            s.declare_subscriber(self.keys.joint_state, self._on_state),
            s.declare_subscriber(self.keys.io_state, self._on_io),
            s.declare_subscriber(self.keys.health_all, self._on_health),
            s.declare_subscriber(self.keys.experiment, self._on_experiment),
            s.declare_queryable(self.keys.request, self._on_request),
        ]
        if self.spawn:
            for name in self.cfg.processes:
                child = Child(name, self._argv(name))
                self.children[name] = child
                self._start_child(child)

    def run(self) -> None:
        while not self.stop_event.wait(TICK_S):
            now = time.monotonic()
            dead = tuple(self._poll_children(now))
            with self.lock:
                self._decode_latest_state()
                self._dead = dead
                before = self.machine.state
                self.machine.update(self.observations(now, dead))
                if before != self.machine.state and self.machine.state == Lifecycle.FAULT:
                    log.error("FAULT: %s", self.machine.reason)
                self._publish_lifecycle(now)

    def close(self) -> None:
        try:
            if self.session is not None:
                with self.lock:
                    if self.machine.state != Lifecycle.FAULT:
                        self.machine.command("stop", self.observations(time.monotonic()))
                    self._publish_lifecycle(time.monotonic())
                time.sleep(STOP_GRACE_S)  # let the drivers brake before they are stopped
        finally:
            self._stop_children()
            undeclare_all(self._decls)
            self._decls = []
            if self.session is not None:
                self.session.close()
                self.session = None

    def stop(self) -> None:
        self.stop_event.set()


def load_gateway_config(cell_path: Path) -> tuple[GatewayConfig, BusConfig]:
    raw = load_toml(cell_path)
    cfg = from_mapping(GatewayConfig, raw.get("gateway", {}), f"{cell_path} [gateway]")
    bus = bus_config_from(raw, str(cell_path))
    return cfg, bus


def configure_parser(p: argparse.ArgumentParser) -> None:
    p.description = (
        "Run the gateway: the zenoh router, the CAN driver, the Modbus driver and the control "
        "process, and the lifecycle (stopped → ready → teaching, fault). The robot stays "
        "braked until an operator sends `leadthrough start` and holds the enabling device."
    )
    p.add_argument("--config", type=Path, required=True, help="cell config TOML")
    p.add_argument("--bus", default=None, help="zenoh endpoint to listen on (overrides config)")
    p.add_argument("--no-spawn", action="store_true", help="do not start the child processes")


def cli_main(args: argparse.Namespace) -> int:
    cfg, bus = load_gateway_config(args.config)
    gw = Gateway(args.config.resolve(), bus.with_overrides(args.bus), cfg, spawn=not args.no_spawn)
    signal.signal(signal.SIGTERM, lambda *_: gw.stop())
    signal.signal(signal.SIGINT, lambda *_: gw.stop())
    gw.open()
    try:
        gw.run()
    finally:
        gw.close()
    return 0


def operator_request(bus: BusConfig, command: str, timeout_s: float = 3.0, **fields) -> dict:
    """Send an operator command (plus ``fields``, e.g. ``plan``) and return the JSON reply."""
    from gateway.bus import open_client

    session = open_client(bus)
    try:
        payload = json.dumps({"command": command, **fields}).encode()
        for reply in session.get(bus.keys.request, payload=payload, timeout=timeout_s):
            if reply.ok is not None:
                return decode_json(reply.ok.payload.to_bytes(), "gateway reply")
        return {
            "ok": False,
            "message": f"no gateway answered on {bus.endpoint} within {timeout_s} s",
        }
    finally:
        session.close()


def _die_with_parent() -> None:
    """In the child, before exec: ask Linux to SIGTERM us when the gateway dies."""
    try:
        libc = ctypes.CDLL("libc.so.6", use_errno=True)
        libc.prctl(PR_SET_PDEATHSIG, signal.SIGTERM)
    except OSError:
        pass  # not Linux: the gateway's own shutdown path still stops the children
