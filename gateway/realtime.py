"""Where the product's processes run: CPUs, real-time priority, locked memory (``[realtime]``).

Each product process applies the cell config's ``[realtime]`` section to itself when it starts,
before it opens zenoh or CAN, so every thread it creates afterwards (zenoh's runtime threads
included) inherits it:

* ``cpu_affinity``: the CPUs every product process may run on (empty: any). On a cell PC keep
  one core for the rest of the machine; on a two-core machine running the virtual cell too,
  `leadthrough bench` and the test harness give the product one core and the simulator the
  other.
* ``sched_fifo_priority``: SCHED_FIFO priority of the processes on the cycle, the CAN driver
  and control (0: normal scheduling). Control's slow loop drops one below
  (:func:`below_the_cycle`). The supervisors, the gateway and the Modbus driver, run
  :data:`SUPERVISION_BELOW` below the cycle: not on it, but above everything at normal
  priority (:data:`SUPERVISION_PROCESSES`).
* ``mlockall``: lock the processes' memory (no page fault on the cycle).

The OS may refuse (no such CPU, no CAP_SYS_NICE or rtprio limit, no memlock limit): the
process then runs anyway, and the log and its health say what was not applied. The systemd
unit (``deploy/systemd``) grants the limits these need; the same settings belong there.
"""

from __future__ import annotations

import contextlib
import ctypes
import ctypes.util
import logging
import os
from collections.abc import Iterator
from dataclasses import dataclass
from typing import Any

from gateway.cell_section import CellSection
from gateway.config import from_mapping, require

log = logging.getLogger("leadthrough.realtime")

#: the processes on the controller cycle: the ones ``sched_fifo_priority`` raises
CYCLE_PROCESSES = ("can-driver", "control")
#: The processes that judge the cycle from outside it. The gateway faults the cell when the
#: CAN driver's state is 0.1 s old or the I/O state 0.25 s old ([gateway] joint_state_timeout_s,
#: io_timeout_s), and its zenoh router carries every message of a locked bus (each process a
#: client of it, gateway/bus.py), the cycle's included; the Modbus driver polls the enabling
#: device and the e-stop chain. At normal priority they wait behind the PC's other work: beside
#: four busy processes per CPU, `leadthrough bench --locked-bus --rates 250 --cycles 5000`
#: computed 5,005 of 5,024 and of 5,022 cycles with them at normal priority, 5,018 of 5,023 and
#: of 5,022 with them here; p99.9 2.2 and 2.1 ms against 1.5 and 1.6 ms (2026-12-01).
#: Their work is light (the gateway 0.47 ms and the Modbus driver 0.32 ms of CPU per 8 ms
#: cycle, `leadthrough bench --profile fd --rates 125`), and it cannot delay the cycle.
SUPERVISION_PROCESSES = ("gateway", "modbus-driver")
#: How far below ``sched_fifo_priority`` the supervisors run: under the cycle's threads (which
#: they must never delay) and under control's slow loop one below (:func:`below_the_cycle`).
#: The other order was tried (2026-12-07: the supervisors one below the cycle, the slow loop two
#: below) after a replay under `taskset -c 0 make test` faulted on "no fresh joint state" with
#: the gateway 0.69 s without the CPU while control adapted its model (every cycle had run). On
#: the emulated slowest machine (`python tests/slow_machine.py --as-slow-as 1.62 -- leadthrough
#: demo`) control's health then went silent (0.5 s) in 3 of 3 runs, 0-2.3 s into teaching; in
#: this order 2 of 2 runs taught 2.8 and 11.2 s before the CAN driver's speed monitor held the
#: arm. Kept; a burst of slow work (an adapted model built) can still hold the gateway off.
SUPERVISION_BELOW = 2
_MCL_CURRENT, _MCL_FUTURE = 1, 2


@dataclass(frozen=True)
class Realtime:
    """``[realtime]`` section of the cell config (module doc)."""

    cpu_affinity: tuple[int, ...] = ()
    sched_fifo_priority: int = 0
    mlockall: bool = False

    def __post_init__(self) -> None:
        where = "[realtime]"
        object.__setattr__(self, "cpu_affinity", tuple(self.cpu_affinity))
        require(
            all(isinstance(c, int) and c >= 0 for c in self.cpu_affinity)
            and len(set(self.cpu_affinity)) == len(self.cpu_affinity),
            f"{where}.cpu_affinity",
            f"{list(self.cpu_affinity)}: CPU numbers must be integers >= 0 and distinct",
        )
        require(
            isinstance(self.sched_fifo_priority, int)
            and (
                self.sched_fifo_priority == 0
                or 1 + SUPERVISION_BELOW <= self.sched_fifo_priority <= 99
            ),
            f"{where}.sched_fifo_priority",
            f"{self.sched_fifo_priority!r} outside {1 + SUPERVISION_BELOW}..99 (0 = normal "
            f"scheduling): the supervisors run {SUPERVISION_BELOW} below it, at 1 or more",
        )
        require(
            isinstance(self.mlockall, bool), f"{where}.mlockall", f"{self.mlockall!r} not a bool"
        )


def realtime_config_from(cell: dict[str, Any], where: str) -> Realtime:
    return from_mapping(Realtime, cell.get("realtime", {}), f"{where} [realtime]")


#: the ``[realtime]`` section of the cell config, registered in pyproject.toml; the gateway
#: checks it before it starts its children (each of them places itself by it)
CELL_SECTION = CellSection(
    "realtime",
    lambda path, raw: realtime_config_from(raw, str(path)),
    Realtime,
    order=6,
    checked_at_start=True,
)


def apply_scheduling(
    cpu_affinity: tuple[int, ...], fifo_priority: int, lock_memory: bool, what: str
) -> dict[str, Any]:
    """Apply CPU affinity, SCHED_FIFO priority and mlockall to the calling thread (and the
    threads it creates afterwards); returns what took effect, or why not. A refusal is a
    warning naming ``what`` and the setting: the caller runs on, unplaced."""
    report: dict[str, Any] = {}
    if cpu_affinity:
        try:
            os.sched_setaffinity(0, cpu_affinity)
            report["cpu_affinity"] = sorted(os.sched_getaffinity(0))
        except OSError as exc:  # no such CPU, or outside this process's cpuset
            report["cpu_affinity"] = f"not applied: {exc}"
            log.warning("%s: cpu_affinity %s not applied (%s); it runs on any CPU",
                        what, list(cpu_affinity), exc)  # fmt: skip
    if fifo_priority:
        try:
            os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(fifo_priority))
            report["sched_fifo_priority"] = fifo_priority
        except OSError as exc:  # PermissionError: no CAP_SYS_NICE and no rtprio limit
            report["sched_fifo_priority"] = f"not applied: {exc}"
            log.warning("%s: sched_fifo_priority %d not applied (%s); it runs with normal "
                        "priority (grant CAP_SYS_NICE or an rtprio limit)",
                        what, fifo_priority, exc)  # fmt: skip
    if lock_memory:
        report["mlockall"] = _mlockall(what)
    if report:
        log.info("%s scheduling: %s", what, report)
    return report


def _mlockall(what: str) -> bool | str:
    libc_name = ctypes.util.find_library("c")
    try:
        libc = ctypes.CDLL(libc_name or "libc.so.6", use_errno=True)
        if libc.mlockall(_MCL_CURRENT | _MCL_FUTURE) == 0:
            return True
        err = ctypes.get_errno()
        why = f"{os.strerror(err)} (raise LimitMEMLOCK or grant CAP_IPC_LOCK)"
    except (OSError, AttributeError) as exc:
        why = str(exc)
    log.warning("%s: mlockall not applied: %s", what, why)
    return f"not applied: {why}"


@contextlib.contextmanager
def normal_priority_children() -> Iterator[None]:
    """Within the block the calling thread runs at normal priority, so a process it starts
    there (a plan builder's worker) does not inherit SCHED_FIFO: at the cycle's priority a
    CPU-bound child would hold a shared core until it blocked (a replay's planning starved the
    CAN driver into "no fresh joint state", 2026-11-29). The thread's policy comes back after
    it. SCHED_RESET_ON_FORK would do it for children but also for the threads created later
    (zenoh's), which must inherit the cycle's priority. Not ``Popen(preexec_fn=...)`` as the
    gateway does (:func:`normal_priority_after_fork`): a ``preexec_fn`` makes Python fork the
    whole control process (page tables of a few hundred MB, locked by ``mlockall``) instead of
    the ``vfork`` it uses otherwise, on the core the cycle shares."""
    policy = os.sched_getscheduler(0)
    if policy not in (os.SCHED_FIFO, os.SCHED_RR):
        yield
        return
    param = os.sched_getparam(0)
    os.sched_setscheduler(0, os.SCHED_OTHER, os.sched_param(0))
    try:
        yield
    finally:
        os.sched_setscheduler(0, policy, param)


def below_the_cycle(what: str) -> int | None:
    """The calling thread one SCHED_FIFO priority below the one it has (None: it is not at
    SCHED_FIFO, nothing changed; else the new priority), for a process on the cycle whose
    cycle runs on other threads, created before at the cycle's priority, while this one does
    the slow work: at equal SCHED_FIFO priority a thread runs until it blocks, so on a shared
    core the control process's slow loop (an adapted model built, telemetry encoded) can hold
    the CAN driver off its cycle. (A demo under `taskset -c 0` faulted on "no fresh joint state
    from the CAN driver" 2.3 s into teaching, 2026-11-30; that fault was not reproduced alone
    and not traced to this loop.) One below, the CAN driver and the
    process's own cycle threads preempt it, and it still runs before the processes at normal
    priority, so it holds the interpreter's lock no longer than it did."""
    if os.sched_getscheduler(0) != os.SCHED_FIFO:
        return None
    priority = max(os.sched_getparam(0).sched_priority - 1, 1)
    os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(priority))
    log.info("%s: its slow loop runs at SCHED_FIFO %d, below the cycle's threads", what, priority)
    return priority


def fifo_priority(cfg: Realtime, process: str) -> int:
    """The SCHED_FIFO priority ``process`` (its subcommand name) runs at (0: normal)."""
    if not cfg.sched_fifo_priority:
        return 0
    if process in CYCLE_PROCESSES:
        return cfg.sched_fifo_priority
    if process in SUPERVISION_PROCESSES:
        return cfg.sched_fifo_priority - SUPERVISION_BELOW
    return 0


def apply_realtime(cfg: Realtime, process: str) -> dict[str, Any]:
    """Place the calling product process (``process``: its subcommand name) by ``cfg``."""
    fifo = fifo_priority(cfg, process)
    return apply_scheduling(cfg.cpu_affinity, fifo, cfg.mlockall, f"[realtime] {process}")


def normal_priority_after_fork() -> None:
    """In a child between fork and exec (``subprocess.Popen(preexec_fn=...)``): normal
    scheduling, so a process the gateway starts (control importing and building its model)
    does not inherit the supervisors' SCHED_FIFO priority; each child places itself by
    ``[realtime]`` once it is built. Only a system call: nothing that could take a lock."""
    if os.sched_getscheduler(0) in (os.SCHED_FIFO, os.SCHED_RR):
        os.sched_setscheduler(0, os.SCHED_OTHER, os.sched_param(0))
