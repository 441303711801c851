"""What the LTC golden vectors feed the Python adapters and what those answer.

For :func:`drivers.can.rt_tables.golden`: frames the controller would send (encoded with
LtcProtocol / LtcFdProtocol, plus damaged, foreign and fuzzed ones) fed one by one with the
cycles and stats that result (:func:`_ltc_feed`, :func:`_ltc_fd_feed`), and command sets (edge
values, ties, values out of range) with the frames or the error they give (:func:`_commands`).
"""

from __future__ import annotations

import math
import random
from collections.abc import Sequence
from typing import Any

import can
import numpy as np

from drivers.can.adapter import AdapterStats, CanAdapter, CycleFeedback, HostRequest
from drivers.can.ltc import LtcAdapter
from drivers.can.ltc_fd import LtcFdAdapter, LtcFdProtocol
from drivers.can.ltc_frames import ControllerStatus, FaultCode, NmtState, frame_crc
from drivers.can.ltc_protocol import LtcProtocol
from drivers.can.rt_json import _json_float
from gateway.errors import FrameError
from gateway.messages import ControllerState


def _frame_json(msg: can.Message) -> dict[str, Any]:
    """A frame as the golden file holds it; flags only when set, the DLC only for RTR."""
    frame: dict[str, Any] = {"id": msg.arbitration_id, "data": bytes(msg.data).hex()}
    for key, flag in (
        ("ext", msg.is_extended_id),
        ("rtr", msg.is_remote_frame),
        ("err", msg.is_error_frame),
        ("fd", msg.is_fd),
        ("brs", msg.bitrate_switch),
    ):
        if flag:
            frame[key] = True
    if msg.is_remote_frame:
        frame["dlc"] = msg.dlc
    return frame


def _floats(values: Sequence[float] | np.ndarray) -> list[float | str]:
    return [_json_float(float(v)) for v in values]


def _feedback_json(fb: CycleFeedback | None) -> dict[str, Any] | None:
    if fb is None:
        return None
    return {
        "counter": int(fb.counter),
        "q": _floats(fb.q_rad),
        "dq": _floats(fb.dq_rad_s),
        "current": _floats(fb.current_a),
        "state": fb.controller_state.name,
        "estop": bool(fb.estop_active),
        "servo_power": bool(fb.servo_power),
        "fault": fb.fault,
        "period_s": _json_float(float(fb.cycle_period_s)),
    }


def _counts(stats: AdapterStats) -> list[int]:
    return [
        stats.frames,
        stats.unknown_frames,
        stats.bad_frames,
        stats.cycles,
        stats.incomplete_cycles,
        stats.corrupt_cycles,
    ]


class _Recorder:
    """Feeds frames to a Python adapter, recording each step: the frame, the cycle it returned,
    the stats counters and ``last_error`` when it changed."""

    def __init__(self, adapter: CanAdapter) -> None:
        self.adapter = adapter
        self.steps: list[dict[str, Any]] = []
        self._last_error = ""

    def feed(self, *msgs: can.Message) -> None:
        for msg in msgs:
            fb = self.adapter.feed(msg)
            step: dict[str, Any] = {
                "frame": _frame_json(msg),
                "feedback": _feedback_json(fb),
                "stats": _counts(self.adapter.stats),
            }
            if self.adapter.stats.last_error != self._last_error:
                self._last_error = step["last_error"] = self.adapter.stats.last_error
            self.steps.append(step)


def _msg(
    arbitration_id: int,
    data: bytes | bytearray = b"",
    *,
    ext: bool = False,
    rtr: bool = False,
    err: bool = False,
    fd: bool = False,
    dlc: int | None = None,
) -> can.Message:
    """A received frame as drivers/can/seqpacket.py builds it from a struct can(fd)_frame."""
    return can.Message(
        arbitration_id=arbitration_id,
        is_extended_id=ext,
        is_remote_frame=rtr,
        is_error_frame=err,
        is_fd=fd,
        bitrate_switch=fd,
        data=b"" if rtr else bytes(data),
        dlc=dlc if dlc is not None else len(data),
    )


def _like(msg: can.Message, data: bytes | bytearray | None = None, **flags: Any) -> can.Message:
    """``msg`` (its id and flags) with other data or flags."""
    kwargs: dict[str, Any] = {"ext": msg.is_extended_id, "fd": msg.is_fd}
    kwargs.update(flags)
    return _msg(msg.arbitration_id, bytes(msg.data) if data is None else data, **kwargs)


def _patched(msg: can.Message, byte: int, value: int) -> can.Message:
    data = bytearray(msg.data)
    data[byte] = value
    return _like(msg, data)


_Q, _DQ, _CUR = (-8.388608, 8.388607), (-3.2768, 3.2767), (-327.68, 327.67)


def _random_joints(rng: random.Random, m: int) -> tuple[list[float], list[float], list[float]]:
    """Joint values across the DBC ranges: uniform floats and, now and then, exact grid values."""

    def one(bounds: tuple[float, float], step: float) -> float:
        if rng.random() < 0.2:
            return round(rng.uniform(*bounds) / step) * step
        return rng.uniform(*bounds)

    return (
        [one(_Q, 1e-6) for _ in range(m)],
        [one(_DQ, 1e-4) for _ in range(m)],
        [one(_CUR, 1e-2) for _ in range(m)],
    )


def _random_status(rng: random.Random, counter: int) -> ControllerStatus:
    return ControllerStatus(
        cycle_counter=counter,
        state=rng.choice(list(ControllerState)),
        fault_code=rng.choice(list(FaultCode)),
        missed_cycles=rng.randrange(256),
        estop_active=rng.random() < 0.5,
        servo_power=rng.random() < 0.5,
        cycle_period_us=rng.choice([100, 1000, 2000, 4000, 65535, rng.randrange(100, 65536)]),
    )


#: Joint values at the ends of the ranges, zeros, one step, and half steps (rounding ties).
_EDGE_JOINTS = (
    [_Q[0], _Q[1], 0.0, -0.0, 1e-6, -1e-6],
    [_DQ[0], _DQ[1], 0.0, -0.0, 1e-4, -1e-4],
    [_CUR[0], _CUR[1], 0.0, -0.0, 0.01, -0.01],
)
_TIE_JOINTS = (
    [2.5e-6, 3.5e-6, -2.5e-6, 0.5e-6, 8.3886065, -8.3886075],
    [0.00015, 0.00025, -0.00015, 0.00005, 3.27665, -3.27675],
    [0.005, 0.015, -0.005, 0.025, 327.665, -327.675],
)


def _edge_sets(m: int) -> list[tuple[list[float], list[float], list[float]]]:
    return [
        (list(q[:m]), list(dq[:m]), list(cur[:m]))
        for q, dq, cur in (_EDGE_JOINTS, _TIE_JOINTS, tuple(v[::-1] for v in _EDGE_JOINTS))
    ]


def _mutations(rng: random.Random, msg: can.Message, known: Sequence[int]) -> can.Message:
    """One random damage to ``msg``: a flipped byte, another length, a flag, another id."""
    data = bytearray(msg.data)
    kind = rng.randrange(7)
    if kind == 0 and data:
        data[rng.randrange(len(data))] ^= 1 << rng.randrange(8)
        return _like(msg, data)
    if kind == 1:
        fd_lengths = [8, 12, 16, 20, 24, 32, 48, 64]
        length = rng.choice(fd_lengths) if msg.is_fd else rng.randrange(9)
        return _like(msg, (data + bytes(64))[:length])
    if kind == 2:
        return _like(msg, rtr=True, fd=False, dlc=min(len(data), 8))
    if kind == 3:
        return _like(msg, ext=True)
    if kind == 4:  # the other format: classic ↔ CAN FD, the length padded as on the wire
        if msg.is_fd:
            return _like(msg, data[:8], fd=False)
        return _like(msg, data, fd=True)
    if kind == 5:
        return _msg(rng.choice(known), data, fd=msg.is_fd)
    data[rng.randrange(len(data))] = rng.randrange(256) if data else 0
    return _like(msg, data)


def _ltc_feed(adapter: LtcAdapter, rng: random.Random) -> list[dict[str, Any]]:
    """LTC-1: complete cycles, then every way §3 and §8 lose one, then fuzzed cycles."""
    rec = _Recorder(adapter)
    host = adapter.protocol
    ctrl = LtcProtocol(host.max_joints, host.dbc_path)  # the controller may have more joints
    n, m = adapter.n_joints, ctrl.max_joints

    def cycle(
        counter: int, joints: tuple[list[float], list[float], list[float]] | None = None
    ) -> list[can.Message]:
        q, dq, cur = joints if joints is not None else _random_joints(rng, m)
        return ctrl.feedback_frames(_random_status(rng, counter), q, dq, cur)

    cmd = host.encode_command(1, 0.1, -0.25, False, 0x2A)
    request = host.encode_request(HostRequest.SERVO_ON, 7)
    foreign = [
        _msg(0x123, b"\x01\x02"),
        _msg(0x7FF, bytes(8)),
        _msg(0x1ABCDE, bytes(8), ext=True),
        _msg(0x180, bytes(64), fd=True),  # LTC-1F's ids mean nothing here
        _msg(0x200, bytes(48), fd=True),
    ]
    rec.feed(host.encode_heartbeat("CTRL", NmtState.OPERATIONAL), *foreign)
    for counter in (0, 1, 2, 255, 256, 257, 511, 0x1234, 32767, 32768, 65534, 65535):
        rec.feed(*cycle(counter))
    for joints in _edge_sets(m):
        rec.feed(*cycle(rng.randrange(65536), joints))

    # incomplete: a joint missing, a joint from the cycle before, no feedback at all
    frames = cycle(100)
    rec.feed(*frames[: n - 1], *frames[n:])
    frames = cycle(101)
    stale = ctrl.encode_feedback(n, 0.0, 0.0, 0.0, 100)
    rec.feed(*frames[: n - 1], stale, *frames[n:])
    rec.feed(frames[-1])
    # duplicates: the latest frame of a joint counts
    frames = cycle(102)
    rec.feed(ctrl.encode_feedback(1, 1.0, 1.0, 1.0, 101), *frames)
    frames = cycle(103)
    rec.feed(*frames[:-1], ctrl.encode_feedback(1, 1.0, 1.0, 1.0, 102), frames[-1])

    # a bad per-cycle frame (or an error frame) loses its cycle; the next one is fine
    bad_feedback = [
        lambda f: _like(f, bytes(f.data)[:7]),
        lambda f: _like(f, rtr=True, dlc=8),
        lambda f: _like(f, ext=True),
        lambda f: _like(f, fd=True),
        lambda f: _msg(0x40, bytes(8), err=True),
        lambda f: _msg(0x4, bytes(8), err=True, ext=True),
    ]
    for damage in bad_feedback:
        frames = cycle(rng.randrange(65536))
        k = rng.randrange(n)
        rec.feed(*frames[:k], damage(frames[k]), *frames[k + 1 :])
        rec.feed(*cycle(rng.randrange(65536)))
    bad_status = [
        lambda s: _patched(s, 2, 4),  # state out of range
        lambda s: _patched(s, 3, 7),  # fault_code out of range
        lambda s: _patched(_patched(s, 6, 99), 7, 0),  # cycle_period_us below 100
        lambda s: _like(s, bytes(s.data)[:6]),
        lambda s: _like(s, rtr=True, dlc=8),
        lambda s: _like(s, ext=True),
        lambda s: _like(s, fd=True),
    ]
    for damage in bad_status:
        frames = cycle(rng.randrange(65536))
        rec.feed(*frames[:-1], damage(frames[-1]))
        rec.feed(frames[-1])  # the joints' frames went with the bad status: incomplete
        rec.feed(*cycle(rng.randrange(65536)))

    # frames that are not the controller's per-cycle ones neither help nor hurt a cycle
    data7 = bytes([3, 7, 0, 0, 0, 0, 0])  # HOST_REQUEST 3: out of range, with a good CRC
    others = [
        _patched(request, 7, request.data[7] ^ 0xFF),  # CRC
        _msg(request.arbitration_id, data7 + bytes([frame_crc(request.arbitration_id, data7)])),
        request,
        _patched(host.encode_heartbeat("CTRL", NmtState.BOOT), 0, 1),  # not an NMT state
        _patched(host.encode_heartbeat("HOST", NmtState.BOOT), 0, 200),  # out of range
        _msg(host.heartbeat_id("HOST"), b"\x05\x00"),
        _like(host.encode_heartbeat("CTRL"), fd=True),
        _patched(cmd, 7, cmd.data[7] ^ 0x01),
        cmd,
        *foreign,
    ]
    frames = cycle(200)
    rec.feed(*frames[:1], *others, *frames[1:])

    # a smaller arm: the extra joints' frames are ignored, but a bad one is a bad cycle frame
    if n < m:
        frames = cycle(300)
        rec.feed(*frames[:n], ctrl.encode_feedback(m, 0.5, 0.5, 0.5, 17), frames[-1])
        frames = cycle(301)
        extra = frames[n]
        rec.feed(*frames[:n], _like(extra, bytes(extra.data)[:5]), frames[-1])

    # fuzz: cycles with one frame damaged, dropped, or a stray frame added
    known = sorted({*host._by_id, 0x180, 0x200, 0x7FF})
    for _ in range(30):
        frames = cycle(rng.randrange(65536))
        k = rng.randrange(len(frames))
        action = rng.randrange(4)
        if action == 0:
            frames[k] = _mutations(rng, frames[k], known)
        elif action == 1:
            del frames[k]
        elif action == 2:
            frames.insert(k, _mutations(rng, rng.choice([cmd, request, *others]), known))
        rec.feed(*frames)
    return rec.steps


def _ltc_fd_feed(adapter: LtcFdAdapter, rng: random.Random) -> list[dict[str, Any]]:
    """LTC-1F: valid CYCLE_FBs, every way §8 and §10.1 refuse one, then fuzzed frames."""
    rec = _Recorder(adapter)
    host = adapter.protocol
    ctrl = LtcFdProtocol(host.max_joints, host.dbc_path)  # joints beyond n are not sent as 0
    m = ctrl.max_joints

    def cycle(
        counter: int, joints: tuple[list[float], list[float], list[float]] | None = None
    ) -> can.Message:
        q, dq, cur = joints if joints is not None else _random_joints(rng, m)
        return ctrl.encode_cycle(_random_status(rng, counter), q, dq, cur)

    cmd = host.encode_command_set(0x1234, [0.1] * host.n_joints, [-0.25] * host.n_joints, False)
    request = host.encode_request(HostRequest.RESET_FAULT, 255)
    foreign = [
        _msg(0x10, bytes(8)),  # LTC-1's ids mean nothing here
        _msg(0x181, bytes(8)),
        _msg(0x201, bytes(8)),
        _msg(0x1ABCDE, bytes(8), ext=True),
        _msg(0x555, bytes(64), fd=True),
    ]
    rec.feed(host.encode_heartbeat("CTRL", NmtState.PRE_OPERATIONAL), *foreign)
    for counter in (0, 1, 255, 256, 0x1234, 32767, 32768, 65535):
        rec.feed(cycle(counter))
    for joints in _edge_sets(m):
        rec.feed(cycle(rng.randrange(65536), joints))
    good = cycle(77)
    damaged = [
        _patched(good, 2, 4),  # state out of range
        _patched(good, 3, 7),  # fault_code out of range
        _patched(_patched(good, 6, 99), 7, 0),  # cycle_period_us below 100
        _like(good, bytes(good.data)[:48]),
        _like(good, bytes(good.data)[:8], fd=False),
        _like(good, rtr=True, fd=False, dlc=8),
        _like(good, ext=True),
        _msg(0x40, bytes(8), err=True),
        _patched(cmd, 47, cmd.data[47] ^ 0x80),  # CRC
        _like(cmd, bytes(cmd.data)[:32]),
        cmd,
        _patched(request, 7, request.data[7] ^ 0x10),
        _like(request, fd=True),
        request,
        _patched(host.encode_heartbeat("HOST"), 0, 3),
        *foreign,
    ]
    for msg in damaged:
        rec.feed(msg, good)
    known = sorted({*host._by_id, 0x10, 0x181, 0x7FF})
    for _ in range(100):
        msg = cycle(rng.randrange(65536))
        if rng.random() < 0.7:
            msg = _mutations(rng, rng.choice([msg, msg, msg, cmd, request]), known)
        rec.feed(msg)
    return rec.steps


def _command_cases(rng: random.Random, n: int) -> list[tuple[int, list[float], list[float], bool]]:
    """(counter, q, dq, hold): counters across the wraps, random, edge and tie values, values
    out of range (first failing joint and signal named), wrong lengths."""
    cases = []
    for counter in (0, 1, 255, 256, 0x1234, 65535, 65536, 70000, (1 << 32) - 1):
        q, dq, _ = _random_joints(rng, n)
        cases.append((counter, q, dq, rng.random() < 0.5))
    for _ in range(30):
        q, dq, _ = _random_joints(rng, n)
        cases.append((rng.randrange(1 << 32), q, dq, rng.random() < 0.5))
    for q, dq, _ in _edge_sets(6):
        cases.append((rng.randrange(65536), q[:n], dq[:n], False))
    for value in (0.1, -0.25, 1e-7, -4.9e-7, 5e-7, 1.5e-6, 8.3886074, -8.3886084):
        cases.append((42, [value] * n, [value / 3] * n, True))
    bad_q = (8.3886071, -8.3886081, 9.0, 1e300, math.nan, math.inf, -math.inf)
    bad_dq = (3.27671, -3.2769, 3.27675, -4.0, math.nan, math.inf)
    for value in bad_q:
        q, dq, _ = _random_joints(rng, n)
        q[rng.randrange(n)] = value
        cases.append((7, q, dq, False))
    for value in bad_dq:
        q, dq, _ = _random_joints(rng, n)
        dq[rng.randrange(n)] = value
        cases.append((7, q, dq, True))
    q, dq, _ = _random_joints(rng, n)
    q[-1], dq[0] = math.nan, 5.0  # the first joint's velocity fails first
    cases.append((8, q, dq, False))
    q, dq, _ = _random_joints(rng, n + 1)
    cases += [(9, q, dq[:n], False), (9, q[:n], dq, False), (9, q[: n - 1], dq[: n - 1], False)]
    return cases


def _commands(adapter: CanAdapter, rng: random.Random) -> list[dict[str, Any]]:
    out = []
    for counter, q, dq, hold in _command_cases(rng, adapter.n_joints):
        case: dict[str, Any] = {
            "counter": counter,
            "q": _floats(q),
            "dq": _floats(dq),
            "hold": hold,
        }
        try:
            frames = adapter.command_frames(counter, np.array(q), np.array(dq), hold)
        except FrameError as exc:
            case["error"] = str(exc)
        else:
            case["frames"] = [_frame_json(f) for f in frames]
        out.append(case)
    return out
