"""The golden vectors that hold the Python and the Rust CiA 402 cycle to the same bits, and
the command line that writes them or prints a cell's tables
(:mod:`drivers.can.rt_cia402_tables`).

Golden vectors: :func:`golden_vectors` runs the Python adapter over scripted frames (frames
in → its CycleFeedback and stats; commands and requests → its frames or its error) from the
tables of each scenario's start; the Rust test replays them (``cargo test -p
leadthrough-can-rt cia402``), tests/unit/test_rt_cia402.py checks the committed file is what
this code generates today. After a change of drivers/can/cia402.py's cycle, regenerate and
review the diff::

    python -m drivers.can.rt_cia402 --golden drivers/can/rt/tests/data/cia402_golden.json

One cell's tables (the statically configured layouts)::

    python -m drivers.can.rt_cia402 --tables deploy/config/sim_cell_cia402.toml
"""

from __future__ import annotations

import argparse
import json
import logging
import math
import struct
import sys
from collections.abc import Callable, Iterable, Sequence
from pathlib import Path
from typing import Any

import can
import numpy as np

from drivers.can.adapter import HostRequest
from drivers.can.cia402 import NMT_OPERATIONAL, Cia402Adapter
from drivers.can.cia402_states import DriveState
from drivers.can.config import Cia402Config
from drivers.can.rt_cia402_tables import (
    _float,
    cia402_tables,
    configure_statically,
    tables_from_config,
)
from gateway.errors import FrameError

REPO = Path(__file__).resolve().parents[2]
#: where the Rust test reads the golden vectors
GOLDEN_PATH = REPO / "drivers" / "can" / "rt" / "tests" / "data" / "cia402_golden.json"
#: the drives' EDS the golden vectors' layouts come from
EDS_PATH = REPO / "deploy" / "cia402" / "leadthrough_drive.eds"


def _frame_json(msg: can.Message) -> dict[str, Any]:
    return {
        "id": msg.arbitration_id,
        "data": bytes(msg.data).hex(),
        "ext": msg.is_extended_id,
        "rtr": msg.is_remote_frame,
        "err": msg.is_error_frame,
        "fd": msg.is_fd,
        "dlc": msg.dlc,
    }


def _message(id_: int, data: bytes = b"", **flags: bool) -> can.Message:
    return can.Message(
        arbitration_id=id_,
        data=data,
        is_extended_id=flags.get("ext", False),
        is_remote_frame=flags.get("rtr", False),
        is_error_frame=flags.get("err", False),
        is_fd=flags.get("fd", False),
        dlc=flags.get("dlc"),
    )


def _feedback_json(fb: Any) -> dict[str, Any] | None:
    if fb is None:
        return None
    return {
        "counter": fb.counter,
        "q": [_float(x) for x in fb.q_rad],
        "dq": [_float(x) for x in fb.dq_rad_s],
        "current": [_float(x) for x in fb.current_a],
        "controller_state": fb.controller_state.name,
        "estop": fb.estop_active,
        "servo_power": fb.servo_power,
        "fault": fb.fault,
        "period_s": _float(fb.cycle_period_s),
        "status": fb.status,
    }


class _Clock:
    """The Python adapter's clock, set to each fed frame's ``now`` (Rust: feed's argument)."""

    t = 0.0

    def __call__(self) -> float:
        return self.t


class Recorder:
    """One scenario: the Python adapter's answers to scripted steps, as the Rust test replays
    them (each step names its operation, its inputs, the answer and the stats after it)."""

    def __init__(self, adapter: Cia402Adapter, clock: _Clock) -> None:
        self.adapter, self.clock = adapter, clock
        self.steps: list[dict[str, Any]] = []
        self.tables: dict[str, Any] | None = None

    def begin(self) -> None:
        """Record from here: the scenario's tables are the adapter's now."""
        self.tables = cia402_tables(self.adapter)
        self.steps = []

    def _step(self, step: dict[str, Any]) -> None:
        step["stats"] = self.adapter.stats.as_dict()
        self.steps.append(step)

    def clock_frames(self) -> None:
        frames = self.adapter.clock_frames()
        self._step({"op": "clock", "frames": [_frame_json(f) for f in frames]})

    def feed(self, msg: can.Message, now: float) -> Any:
        self.clock.t = now
        fb = self.adapter.feed(msg)
        self._step(
            {
                "op": "feed",
                "now": _float(now),
                "frame": _frame_json(msg),
                "feedback": _feedback_json(fb),
            }
        )
        return fb

    def command(self, counter: int, q: Sequence[float], dq: Sequence[float], hold: bool) -> None:
        step: dict[str, Any] = {
            "op": "command",
            "counter": counter,
            "q": [_float(x) for x in q],
            "dq": [_float(x) for x in dq],
            "hold": hold,
        }
        try:
            frames = self.adapter.command_frames(counter, np.array(q), np.array(dq), hold)
            step["frames"] = [_frame_json(f) for f in frames]
        except (FrameError, struct.error) as exc:  # struct's: a target that rounds to 2^31
            step["error"] = str(exc)
            step["error_kind"] = "FrameError" if isinstance(exc, FrameError) else "struct.error"
        self._step(step)

    def request(self, request: HostRequest) -> None:
        frames = self.adapter.request_frames(request)
        self._step(
            {"op": "request", "request": request.name, "frames": [_frame_json(f) for f in frames]}
        )

    def heartbeat(self) -> None:
        self._step({"op": "heartbeat", "frame": _frame_json(self.adapter.heartbeat_frame())})

    def is_cycle_frame(self, msg: can.Message) -> None:
        result = self.adapter.is_cycle_frame(msg)
        self._step({"op": "is_cycle_frame", "frame": _frame_json(msg), "result": result})

    # helpers of the scenarios

    def cycle(
        self,
        statuswords: Sequence[int],
        position: Sequence[int],
        velocity: Sequence[int],
        current: Sequence[int],
        now: float,
        order: Iterable[int] | None = None,
    ) -> Any:
        """SYNC, then every drive's TPDO1 and TPDO2 (drives in ``order``); the last feedback."""
        self.clock_frames()
        fb = None
        for k in range(self.adapter.n_joints) if order is None else order:
            j = self.adapter._joints[k]
            tp1 = j.tpdo1.layout.pack(statuswords[k], position[k])
            tp2 = j.tpdo2.layout.pack(velocity[k], current[k], ~current[k])
            self.feed(_message(j.tpdo1.cob_id, tp1), now)
            fb = self.feed(_message(j.tpdo2.cob_id, tp2), now)
        return fb

    def scenario(self, name: str) -> dict[str, Any]:
        return {"name": name, "tables": self.tables, "steps": self.steps}


#: statuswords of the states (bit 9 remote, bit 4 voltage enabled where the drive sets it)
SW = {
    DriveState.NOT_READY_TO_SWITCH_ON: 0x0200,
    DriveState.SWITCH_ON_DISABLED: 0x0250,
    DriveState.READY_TO_SWITCH_ON: 0x0231,
    DriveState.SWITCHED_ON: 0x0233,
    DriveState.OPERATION_ENABLED: 0x0237,
    DriveState.QUICK_STOP_ACTIVE: 0x0217,
    DriveState.FAULT_REACTION_ACTIVE: 0x021F,
    DriveState.FAULT: 0x0218,
}


def _recorder(
    n: int, clock_period_s: float = 0.008, **cia402: Any
) -> tuple[Recorder, Cia402Adapter]:
    defaults: dict[str, Any] = {
        "eds": str(EDS_PATH),
        "gear_ratio": tuple(100.0 + 7.5 * k for k in range(n)),
        "rated_current_a": tuple(2.0 + 1.25 * k for k in range(n)),
        "cycle_period_s": clock_period_s,
    }
    cfg = Cia402Config(**{**defaults, **cia402})
    clock = _Clock()
    adapter = configure_statically(Cia402Adapter(n, cfg, clock=clock))
    return Recorder(adapter, clock), adapter


def _states(n: int, state: DriveState) -> list[int]:
    return [SW[state]] * n


def _scenario_walk() -> dict[str, Any]:
    """Three drives (node ids out of order) from power-up to operation enabled and back, with
    commands, a drive fault, a fault reset, a drive that drops out and the latch."""
    rec, a = _recorder(3, node_ids=(3, 1, 7), rated_current_a=(10.0, 2.0, 21.0),
                       gear_ratio=(100.0, 50.5, 147.0))  # fmt: skip
    rec.begin()
    S = DriveState
    pos, vel, cur = [1000, -2000, 123456789], [10, -20, 0], [500, -250, 1]
    rec.heartbeat()
    for k, nid in enumerate((3, 1, 7)):
        rec.feed(_message(0x700 + nid, b"\x00"), 0.001 * k)  # boot-up
    for nid in (3, 1, 7):
        rec.feed(_message(0x700 + nid, bytes([NMT_OPERATIONAL])), 0.01)
    rec.cycle(_states(3, S.NOT_READY_TO_SWITCH_ON), pos, vel, cur, 0.02)
    rec.request(HostRequest.BRAKE)
    rec.cycle(_states(3, S.SWITCH_ON_DISABLED), pos, vel, cur, 0.03)
    rec.request(HostRequest.SERVO_ON)
    for state in (S.READY_TO_SWITCH_ON, S.SWITCHED_ON, S.OPERATION_ENABLED):
        rec.cycle(_states(3, state), pos, vel, cur, 0.04)
        rec.request(HostRequest.SERVO_ON)
    # commands: a tie of the rounding, negative values, hold
    inc = [j.inc_per_rad for j in a._joints]
    rec.command(4, [0.1, -0.2, 2.5 / inc[2]], [0.5, -0.5, 1.5 / inc[2]], False)
    rec.command(4, [0.1, -0.2, 0.3], [0.5, -0.5, 0.3], True)
    rec.command(4, [0.0, -0.0, 1e-12], [-0.0, 0.0, -1e-12], False)
    for q, dq in (
        ([1e3, 0.0, 0.0], [0.0, 0.0, 0.0]),
        ([0.0, math.nan, 0.0], [0.0, 0.0, 0.0]),
        ([0.0, 0.0, 0.0], [0.0, 0.0, -math.inf]),
        ([0.0, 0.0, -(2**31 + 0.25) / inc[2]], [0.0, 0.0, 0.0]),
        ([0.0, 0.0, 0.0], [0.0, 0.0, 2.0**31 / inc[2]]),
        ([1.5e-7, 1e-4, 0.0], [0.0, 0.0, 1e300]),
        ([0.0, 0.0], [0.0, 0.0]),
        ([0.0, 0.0, 0.0, 0.0], [0.0, 0.0, 0.0]),
    ):
        rec.command(5, q, dq, False)
    # the joints before the one refused keep the targets of the refused set (as the Python)
    rec.request(HostRequest.SERVO_ON)
    # a target that rounds to 2^31: struct's error in Python (and that target kept as the last
    # sent, which the next request could not pack), a FrameError in Rust (the target not kept)
    rec.command(5, [0.3, 0.4, (2**31 - 0.25) / inc[2]], [0.0, 0.0, 0.0], False)
    rec.command(5, [0.0, 0.0, 0.0], [1e300, 0.0, 0.0], True)  # hold: the velocity is not sent
    rec.request(HostRequest.SERVO_ON)  # repeats the targets last sent
    # is_cycle_frame
    for msg in (
        _message(0x183),
        _message(0x281),
        _message(0x187, ext=True),
        _message(0x703),
        _message(0x083),
        _message(0x203),
        _message(0x080),
        _message(0x18183, ext=True),
    ):
        rec.is_cycle_frame(msg)
    # a cycle fed in another order, then a drive's EMCY and fault
    rec.cycle(_states(3, S.OPERATION_ENABLED), pos, vel, cur, 0.05, order=(2, 0, 1))
    rec.feed(_message(0x081, bytes([0x11, 0x86, 0x08, 0, 0, 0, 0, 0])), 0.05)  # EMCY 0x8611
    rec.feed(_message(0x083, bytes([0x10])), 0.05)  # a short EMCY: no code
    fault = [SW[S.OPERATION_ENABLED], SW[S.FAULT_REACTION_ACTIVE], SW[S.OPERATION_ENABLED]]
    rec.cycle(fault, pos, vel, cur, 0.06)
    rec.request(HostRequest.SERVO_ON)  # every drive towards BRAKE: one axis stopping stops all
    fault[1] = SW[S.FAULT]
    rec.cycle(fault, pos, vel, cur, 0.07)
    rec.request(HostRequest.RESET_FAULT)
    rec.feed(_message(0x081, bytes(8)), 0.07)  # EMCY error reset
    rec.cycle([SW[S.SWITCHED_ON], SW[S.SWITCH_ON_DISABLED], SW[S.SWITCHED_ON]], pos, vel, cur, 0.08)
    rec.request(HostRequest.SERVO_ON)
    for _ in range(3):
        rec.cycle(_states(3, S.OPERATION_ENABLED), pos, vel, cur, 0.09)
    # drive 3 drops to quick stop on its own: latched until RESET_FAULT
    qs = [SW[S.OPERATION_ENABLED], SW[S.OPERATION_ENABLED], SW[S.QUICK_STOP_ACTIVE]]
    rec.cycle(qs, pos, vel, cur, 0.10)
    rec.request(HostRequest.SERVO_ON)
    rec.cycle(_states(3, S.SWITCH_ON_DISABLED), pos, vel, cur, 0.11)
    rec.command(12, [0.1, 0.2, 0.3], [0.0, 0.0, 0.0], False)
    rec.request(HostRequest.RESET_FAULT)
    rec.cycle(_states(3, S.SWITCH_ON_DISABLED), pos, vel, cur, 0.12)
    # BRAKE from operation enabled: disable operation (5), then shutdown (6)
    rec.request(HostRequest.SERVO_ON)
    rec.cycle(_states(3, S.OPERATION_ENABLED), pos, vel, cur, 0.13)
    rec.request(HostRequest.BRAKE)
    rec.cycle(_states(3, S.SWITCHED_ON), pos, vel, cur, 0.14)
    rec.request(HostRequest.BRAKE)
    rec.cycle(_states(3, S.READY_TO_SWITCH_ON), pos, vel, cur, 0.15)
    rec.request(HostRequest.BRAKE)
    return rec.scenario("walk: power-up, servo on, commands, faults, latch, brake")


def _scenario_frames() -> dict[str, Any]:
    """Bad, corrupt, unknown, missing and late frames; heartbeats late and NMT states."""
    rec, _ = _recorder(2, producer_heartbeat_s=0.05)
    rec.begin()
    S = DriveState
    pos, vel, cur = [0, 1 << 20], [-(1 << 30), (1 << 31) - 1], [-32768, 32767]
    oe = _states(2, S.OPERATION_ENABLED)
    for nid in (1, 2):
        rec.feed(_message(0x700 + nid, bytes([NMT_OPERATIONAL])), 1.0)
    rec.cycle(oe, pos, vel, cur, 1.0)
    # a short TPDO1 corrupts its cycle, even once the drive sent it again
    rec.clock_frames()
    rec.feed(_message(0x181, b"\x37\x02\x00"), 1.01)
    for k in range(2):
        rec.feed(_message(0x181 + k, struct.pack("<Hl", oe[k], pos[k])), 1.01)
    for k in range(2):
        rec.feed(_message(0x281 + k, struct.pack("<lhh", vel[k], cur[k], 0)), 1.01)
    # a long TPDO2, an FD TPDO1 and frames the protocol refuses or does not know
    rec.clock_frames()
    rec.feed(_message(0x282, bytes(64), fd=True), 1.02)
    rec.feed(_message(0x181, bytes(12), fd=True), 1.02)
    rec.feed(_message(0x281, bytes(0)), 1.02)
    rec.feed(_message(0x181, ext=True), 1.02)
    rec.feed(_message(0x181, rtr=True, dlc=6), 1.02)
    rec.feed(_message(0x4, bytes(8), err=True), 1.02)
    rec.feed(_message(0x7FF), 1.02)
    rec.feed(_message(0x080), 1.02)  # a SYNC of another producer
    rec.feed(_message(0x201, bytes(6)), 1.02)  # an RPDO
    # a drive that never answers: the next SYNC counts the cycle incomplete
    rec.clock_frames()
    rec.feed(_message(0x181, struct.pack("<Hl", oe[0], pos[0])), 1.03)
    rec.feed(_message(0x281, struct.pack("<lhh", vel[0], cur[0], 0)), 1.03)
    rec.clock_frames()
    rec.clock_frames()  # nothing since the last SYNC: not incomplete
    # a TPDO sent twice: the last counts
    rec.feed(_message(0x181, struct.pack("<Hl", oe[0], 5)), 1.04)
    rec.feed(_message(0x181, struct.pack("<Hl", oe[0], 7)), 1.04)
    for k in range(2):
        rec.feed(_message(0x281 + k, struct.pack("<lhh", vel[k], cur[k], 0)), 1.04)
    rec.feed(_message(0x182, struct.pack("<Hl", oe[1], pos[1])), 1.04)
    # frames after the cycle completed: they wait for the next
    rec.feed(_message(0x181, struct.pack("<Hl", oe[0], 9)), 1.05)
    rec.cycle(oe, pos, vel, cur, 1.05)
    # heartbeats: drive 2 late (> 3 × 50 ms), drive 1 pre-operational, then stopped, then none
    rec.feed(_message(0x701, bytes([NMT_OPERATIONAL])), 1.10)
    rec.cycle(oe, pos, vel, cur, 1.15)
    rec.cycle(oe, pos, vel, cur, 1.1500001)
    rec.feed(_message(0x701, bytes([0x7F])), 1.2)
    rec.feed(_message(0x702, bytes([0x85])), 1.2)  # the toggle bit is not part of the state
    rec.cycle(oe, pos, vel, cur, 1.2)
    rec.feed(_message(0x701, bytes([0x04])), 1.21)
    rec.feed(_message(0x702, b""), 1.21)  # no state byte: as if none had come
    rec.cycle(oe, pos, vel, cur, 1.25)
    rec.cycle(oe, pos, vel, cur, 1.5)
    rec.feed(_message(0x701, bytes([NMT_OPERATIONAL, 0xFF])), 1.5)
    rec.cycle(oe, pos, vel, cur, 1.5)
    # every statusword coding of the standard, and the unusual ones
    for sw in (0x0000, 0x0040, 0x0021, 0x0023, 0x0027, 0x0007, 0x000F, 0x0008, 0x002F, 0x0061,
               0x006F, 0xFFFF, 0x0260, 0x0031, 0x0011):  # fmt: skip
        rec.cycle([sw, SW[S.SWITCH_ON_DISABLED]], pos, vel, cur, 1.5)
    rec.request(HostRequest.SERVO_ON)
    rec.request(HostRequest.RESET_FAULT)
    return rec.scenario("frames: bad, corrupt, unknown, incomplete; heartbeats; statuswords")


def _scenario_csv_handover() -> dict[str, Any]:
    """CSV mode, one drive, a host node id of its own; recorded from the middle of a run (a
    cycle half in, a latch, the counter about to wrap): the tables carry the state on."""
    rec, a = _recorder(1, mode="csv", node_ids=(42,), host_node_id=5, clock_period_s=0.004,
                       consumer_heartbeat_s=0.02, producer_heartbeat_s=0.1)  # fmt: skip
    S = DriveState
    rec.feed(_message(0x700 + 42, bytes([NMT_OPERATIONAL])), 10.0)
    rec.request(HostRequest.SERVO_ON)
    rec.cycle([SW[S.OPERATION_ENABLED]], [77], [3], [-4], 10.0)
    rec.command(1, [0.25], [-1.0], False)
    rec.cycle([SW[S.SWITCH_ON_DISABLED]], [77], [3], [-4], 10.01)  # latches
    a._sync_count = 65534
    rec.clock_frames()
    rec.feed(_message(0x1AA, struct.pack("<Hl", SW[S.SWITCH_ON_DISABLED], 80)), 10.02)
    rec.begin()
    rec.feed(_message(0x2AA, struct.pack("<lhh", 1, 2, 3)), 10.02)
    rec.heartbeat()
    rec.request(HostRequest.SERVO_ON)
    rec.command(65535, [0.5], [2.0], False)
    rec.cycle([SW[S.SWITCH_ON_DISABLED]], [81], [3], [-4], 10.2)  # wraps to 0; heartbeat late
    rec.request(HostRequest.RESET_FAULT)
    rec.cycle([SW[S.SWITCH_ON_DISABLED]], [81], [3], [-4], 10.21)
    rec.clock_frames()
    rec.feed(_message(0x1AA, b"\x50\x02\x00\x00\x00\x00\x00"), 10.22)  # 7 bytes
    return rec.scenario("csv handover: mid-cycle tables, latch, counter wrap")


def _scenario_sixteen() -> dict[str, Any]:
    """The most drives the adapter carries, all in fault with an EMCY: the longest fault text."""
    ids = tuple(range(101, 117))
    rec, _ = _recorder(16, node_ids=ids)
    rec.begin()
    S = DriveState
    n = 16
    for k, nid in enumerate(ids):
        rec.feed(_message(0x80 + nid, struct.pack("<HB5x", 0xFF00 + k, 0x81)), 0.5)
        rec.feed(_message(0x700 + nid, bytes([NMT_OPERATIONAL])), 0.5)
    pos = [(-1) ** k * (k << 24) for k in range(n)]
    rec.cycle(_states(n, S.FAULT), pos, [k - 8 for k in range(n)], [100 * k for k in range(n)], 1)
    rec.request(HostRequest.RESET_FAULT)
    rec.cycle(_states(n, S.SWITCH_ON_DISABLED), pos, [0] * n, [0] * n, 1.1)
    rec.request(HostRequest.SERVO_ON)
    rec.command(3, [0.01 * k for k in range(n)], [-0.1 * k for k in range(n)], False)
    return rec.scenario("sixteen drives in fault")


def _scenario_stop_start() -> dict[str, Any]:
    """A stop and a start within a cycle (cia402.HOST_DISABLE_CYCLES): the drives' answer to
    the BRAKE arrives after the SERVO_ON and is no drop-out; one three cycles later is."""
    rec, _ = _recorder(2)
    rec.begin()
    S = DriveState
    pos, vel, cur = [10, -10], [0, 0], [0, 0]
    oe = _states(2, S.OPERATION_ENABLED)
    rec.request(HostRequest.SERVO_ON)
    for state in (S.READY_TO_SWITCH_ON, S.SWITCHED_ON, S.OPERATION_ENABLED, S.OPERATION_ENABLED):
        rec.cycle(_states(2, state), pos, vel, cur, 0.01)
    rec.request(HostRequest.BRAKE)
    rec.request(HostRequest.SERVO_ON)
    rec.cycle(oe, pos, vel, cur, 0.02)  # the BRAKE not acted on yet
    rec.cycle(_states(2, S.SWITCHED_ON), pos, vel, cur, 0.03)  # ... now: obeying, no latch
    rec.request(HostRequest.SERVO_ON)
    for _ in range(3):
        rec.cycle(oe, pos, vel, cur, 0.04)
    rec.cycle([SW[S.OPERATION_ENABLED], SW[S.SWITCH_ON_DISABLED]], pos, vel, cur, 0.05)  # latched
    rec.request(HostRequest.SERVO_ON)
    return rec.scenario("stop and start within a cycle: the BRAKE's answer is no drop-out")


SCENARIOS: tuple[Callable[[], dict[str, Any]], ...] = (
    _scenario_walk,
    _scenario_frames,
    _scenario_csv_handover,
    _scenario_sixteen,
    _scenario_stop_start,
)


def golden_vectors() -> dict[str, Any]:
    """The golden vectors as the Python adapter answers today (module docstring)."""
    adapter_log = logging.getLogger("drivers.can.cia402")
    level = adapter_log.level
    adapter_log.setLevel(logging.CRITICAL)  # the latches the scenarios provoke on purpose
    try:
        scenarios = [make() for make in SCENARIOS]
    finally:
        adapter_log.setLevel(level)
    return {
        "generator": "python -m drivers.can.rt_cia402 --golden PATH (drivers/can/rt_cia402.py)",
        "scenarios": scenarios,
    }


def _dumps(obj: Any, indent: str, width: int) -> str:
    flat = json.dumps(obj, allow_nan=False)
    if len(indent) + len(flat) <= width or not isinstance(obj, dict | list) or not obj:
        return flat
    inner = indent + " "
    if isinstance(obj, dict):
        items = [f"{inner}{json.dumps(k)}: {_dumps(v, inner, width)}" for k, v in obj.items()]
        return "{\n" + ",\n".join(items) + f"\n{indent}}}"
    items = [inner + _dumps(v, inner, width) for v in obj]
    return "[\n" + ",\n".join(items) + f"\n{indent}]"


def dumps(obj: Any, width: int = 100) -> str:
    """The committed form: JSON whose values stand on one line where they fit ``width``
    characters, keys in order, one trailing newline."""
    return _dumps(obj, "", width) + "\n"


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m drivers.can.rt_cia402",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    what = parser.add_mutually_exclusive_group(required=True)
    what.add_argument("--golden", type=Path, metavar="PATH", help="write the golden vectors")
    what.add_argument("--tables", type=Path, metavar="CELL_TOML", help="print a cell's tables")
    args = parser.parse_args(argv)
    if args.golden is not None:
        args.golden.write_text(dumps(golden_vectors()))
        print(f"wrote {args.golden}")
        return 0
    from drivers.can.config import load_can_config

    can_cfg, _ = load_can_config(args.tables)
    if can_cfg.adapter != "cia402":
        print(f"{args.tables}: [can].adapter is {can_cfg.adapter!r}, not 'cia402'", file=sys.stderr)
        return 2
    sys.stdout.write(dumps(tables_from_config(can_cfg)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
