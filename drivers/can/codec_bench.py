"""Micro-benchmark of one LTC control cycle's CAN coding: cantools against the compiled codec.

A cycle is what the host does every control period: decode the controller's feedback (LTC-1:
JOINT_FB_J1..J6 and CTRL_STATUS; LTC-1F: one CYCLE_FB) and encode the answer (LTC-1: six
JOINT_CMD_Jk with their CRC-8; LTC-1F: one CYCLE_CMD with its CRC-16).

Rows, fastest of ``--repeat`` runs of ``--cycles`` cycles each, in µs per cycle:

* ``cantools``: cantools' ``Message.decode``/``encode`` with the range checks and CRC LTC-1
  needs: the core of what ``LtcProtocol`` did before the compiled codec (end to end, with its
  value checks, frame tuples and ``can.Message``, that took about 170 µs per cycle on the
  development VM, where this row reads about 90 µs);
* ``compiled codec``: the same work on :mod:`drivers.can.codec`'s generated functions;
* ``LtcProtocol`` / ``LtcFdProtocol``: the protocols end to end, ``can.Message`` in and out;
* ``LtcAdapter`` / ``LtcFdAdapter``: what the CAN driver calls (cycle assembly, numpy arrays).

Run: ``python -m drivers.can.codec_bench [--cycles N] [--repeat R]``.
"""

from __future__ import annotations

import argparse
import time
from collections.abc import Callable

import cantools
import numpy as np

from drivers.can.codec import compile_message
from drivers.can.ltc import LtcAdapter
from drivers.can.ltc_fd import LtcFdAdapter, LtcFdProtocol
from drivers.can.ltc_frames import ControllerStatus, FaultCode, frame_crc
from drivers.can.ltc_protocol import DEFAULT_DBC_PATH, LtcProtocol
from gateway.errors import FrameError
from gateway.messages import ControllerState

JOINTS = 6
Q_RAD = [0.1, -0.2, 0.3, -0.4, 0.5, -0.6]
DQ_RAD_S = [0.01, 0.02, -0.03, 0.04, -0.05, 0.06]
CURRENT_A = [1.0, -2.0, 3.0, -4.0, 5.0, -6.0]
STATUS = ControllerStatus(4660, ControllerState.EXTERNAL, FaultCode.NONE, 0, False, True, 4000)


def _cantools_cycle() -> tuple[Callable[[], object], Callable[[], object]]:
    """LTC-1's cycle on cantools, with the checks LtcProtocol made on top of it."""
    db = cantools.database.load_file(str(DEFAULT_DBC_PATH), strict=True)
    proto = LtcProtocol(JOINTS)
    fb = [db.get_message_by_name(f"JOINT_FB_J{k}") for k in range(1, JOINTS + 1)]
    cmd = [db.get_message_by_name(f"JOINT_CMD_J{k}") for k in range(1, JOINTS + 1)]
    status = db.get_message_by_name("CTRL_STATUS")
    frames = [(m, bytes(f.data)) for m, f in zip([*fb, status], _feedback(proto), strict=True)]

    def decode() -> object:
        out = []
        for message, data in frames:
            values = message.decode(data, decode_choices=False, scaling=True)
            for sig in message.signals:
                v, tol = values[sig.name], abs(sig.scale) / 2
                if v < sig.minimum - tol or v > sig.maximum + tol:
                    raise FrameError(f"{message.name}: {sig.name} = {v} outside its range")
            out.append(values)
        return out

    def encode() -> object:
        out = []
        for k, message in enumerate(cmd):
            values = {
                "position_cmd": Q_RAD[k],
                "velocity_cmd": DQ_RAD_S[k],
                "hold": 0,
                "counter": 52,
                "crc": 0,
            }
            data = bytearray(message.encode(values, scaling=True, padding=False, strict=True))
            data[7] = frame_crc(message.frame_id, data[:7])
            out.append(data)
        return out

    return decode, encode


def _compiled_cycle() -> tuple[Callable[[], object], Callable[[], object]]:
    """The same work on the compiled codecs (no can.Message, no frame tuples)."""
    db = cantools.database.load_file(str(DEFAULT_DBC_PATH), strict=True)
    proto = LtcProtocol(JOINTS)
    names = [f"JOINT_FB_J{k}" for k in range(1, JOINTS + 1)] + ["CTRL_STATUS"]
    decoders = [compile_message(db.get_message_by_name(n)).decode for n in names]
    frames = list(zip(decoders, [bytes(f.data) for f in _feedback(proto)], strict=True))
    cmd = [compile_message(db.get_message_by_name(f"JOINT_CMD_J{k}")) for k in range(1, JOINTS + 1)]

    def decode() -> object:
        return [dec(data) for dec, data in frames]

    def encode() -> object:
        out = []
        for k, codec in enumerate(cmd):
            data = codec.encode(Q_RAD[k], DQ_RAD_S[k], 0, 52, 0)
            data[7] = frame_crc(codec.frame_id, data[:7])
            out.append(data)
        return out

    return decode, encode


def _feedback(proto: LtcProtocol | LtcFdProtocol) -> list:
    return proto.feedback_frames(STATUS, Q_RAD, DQ_RAD_S, CURRENT_A)


def _protocol_cycle(
    proto: LtcProtocol | LtcFdProtocol,
) -> tuple[Callable[[], object], Callable[[], object]]:
    frames = _feedback(proto)
    decode = proto.decode

    def decode_all() -> object:
        return [decode(f) for f in frames]

    if isinstance(proto, LtcFdProtocol):

        def encode() -> object:
            return proto.encode_command_set(4660, Q_RAD, DQ_RAD_S, False)
    else:

        def encode() -> object:
            return [
                proto.encode_command(k + 1, Q_RAD[k], DQ_RAD_S[k], False, 52) for k in range(JOINTS)
            ]

    return decode_all, encode


def _adapter_cycle(
    adapter: LtcAdapter | LtcFdAdapter,
) -> tuple[Callable[[], object], Callable[[], object]]:
    frames = _feedback(adapter.protocol)
    q, dq = np.array(Q_RAD), np.array(DQ_RAD_S)

    def feed() -> object:
        cycle = None
        for f in frames:
            cycle = adapter.feed(f)
        assert cycle is not None
        return cycle

    def answer() -> object:
        return adapter.command_frames(4660, q, dq, False)

    return feed, answer


def _time_per_call_s(fn: Callable[[], object], cycles: int, repeat: int) -> float:
    """Fastest of ``repeat`` runs, per call [s]: the least disturbed by other processes."""
    best = float("inf")
    for _ in range(repeat):
        t0 = time.perf_counter()
        for _ in range(cycles):
            fn()
        best = min(best, (time.perf_counter() - t0) / cycles)
    return best


def run(cycles: int, repeat: int) -> list[tuple[str, float, float]]:
    """(row, decode [µs], encode [µs]) per cycle for every row of the module docstring."""
    rows = {
        "LTC-1   cantools (7 decode, 6 encode)": _cantools_cycle(),
        "LTC-1   compiled codec (same work)": _compiled_cycle(),
        "LTC-1   LtcProtocol (can.Message in/out)": _protocol_cycle(LtcProtocol(JOINTS)),
        "LTC-1   LtcAdapter (feed, command_frames)": _adapter_cycle(LtcAdapter(JOINTS)),
        "LTC-1F  LtcFdProtocol (1 decode, 1 encode)": _protocol_cycle(LtcFdProtocol(JOINTS)),
        "LTC-1F  LtcFdAdapter (feed, command_frames)": _adapter_cycle(LtcFdAdapter(JOINTS)),
    }
    out = []
    for name, (decode, encode) in rows.items():
        decode(), encode()  # warm up, and fail before timing if anything is wrong
        out.append(
            (
                name,
                _time_per_call_s(decode, cycles, repeat) * 1e6,
                _time_per_call_s(encode, cycles, repeat) * 1e6,
            )
        )
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m drivers.can.codec_bench",
        description="Time one control cycle's CAN decoding and encoding, cantools against the "
        "compiled codec, in microseconds per cycle (fastest of several runs).",
    )
    parser.add_argument("--cycles", type=int, default=2000, help="cycles per run (default 2000)")
    parser.add_argument("--repeat", type=int, default=5, help="runs; the fastest counts (5)")
    args = parser.parse_args(argv)
    if args.cycles < 1 or args.repeat < 1:
        parser.error("--cycles and --repeat must be at least 1")
    results = run(args.cycles, args.repeat)
    reference = results[0][1] + results[0][2]
    print(f"{'µs per cycle':<46}{'decode':>9}{'encode':>9}{'total':>9}{'speed-up':>10}")
    for name, dec_us, enc_us in results:
        total = dec_us + enc_us
        print(f"{name:<46}{dec_us:9.1f}{enc_us:9.1f}{total:9.1f}{reference / total:9.1f}x")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
