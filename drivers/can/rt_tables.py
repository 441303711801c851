"""The tables the compiled LTC adapters are built from, and their golden vectors.

The compiled cycle (``drivers/can/rt``, issue 48) never reads a DBC: cantools stays the only
parser. :func:`ltc_tables` builds the Python adapter the registry names (``ltc_dbc`` for LTC-1,
``ltc_fd`` for LTC-1F), so the DBC is parsed and checked exactly as the Python driver does it,
and exports what its compiled codecs (:mod:`drivers.can.codec`) and the protocol know, as a
JSON-serialisable ``dict``; ``LtcAdapter::from_tables`` / ``LtcFdAdapter::from_tables``
(``drivers/can/rt/src/ltc_adapter.rs``, ``ltc_fd_adapter.rs``) take it as a ``serde_json::Value``.

Table format (``"format": 1``)::

    adapter, protocol, profile   "ltc_dbc", "LTC-1", "classic" (or "ltc_fd", "LTC-1F", "fd")
    dbc, dbc_version             the DBC's file name and VERSION (for diagnostics)
    n_joints, max_joints         configured joints; joints the DBC carries
    counter_modulus              the cycle counter wraps at this (Feedback.counter)
    command_counter_modulus      a command set's counter is the cycle's counter modulo this
    feedback_counter_modulus     (LTC-1 only) JOINT_FB.counter is the cycle's counter modulo this
    request_counter_modulus      HOST_REQUEST.counter wraps at this
    host_heartbeat_timeout_s     [s]
    heartbeat_nmt_state          NMT state the host's heartbeat carries (OPERATIONAL)
    cycle_frame_ids              ids of the controller's per-cycle frames
    messages: [{name, id, where, length [bytes], fd, brs, extended, kind, joint, node,
                crc: null | {algorithm: "crc8_sae_j1850" | "crc16_ccitt_false", bytes},
                signals: [{name, start_bit, length_bits, signed, conversion, scale, offset,
                           minimum, maximum, unit, raw_min, raw_max, decode_raw: [lo, hi],
                           encode_raw: null | [lo, hi], choices: null | [[value, name], ...]}]}]

``conversion`` is the cantools conversion that fixes the rounding (``identity``,
``linear_integer``, ``linear``); ``decode_raw`` the raw values decoding accepts (the DBC range
widened by half a step) and ``encode_raw`` those encoding produces from in-range values, both
as codec.py computes them. Signals are in the DBC's order, the order the codec checks them.
A bound given as an int stays an int (error texts print it so). Floats are JSON numbers where
serde_json's default parser (no ``float_roundtrip``) reads them back exactly, else their
``repr`` as a string (``"nan"``, ``"inf"``, ``"0.30000000000000004"``); the Rust side reads both.

Golden vectors: ``python -m drivers.can.rt_tables --golden
drivers/can/rt/tests/data/ltc_golden.json`` writes, for each adapter and a few joint counts, the
tables and what the Python adapter does with them: frames the controller would send (encoded
with LtcProtocol / LtcFdProtocol, plus damaged, foreign and fuzzed ones) fed one by one with
the cycles and stats that result, command sets (edge values, ties, values out of range),
request frames and the heartbeat. The Rust tests replay the file; ``tests/unit/
test_rt_tables.py`` fails when the committed file differs from what this module generates.
The fed frames and the command sets are made in :mod:`drivers.can.rt_tables_golden`.
"""

from __future__ import annotations

import argparse
import json
import random
import sys
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

from drivers.can.adapter import ADAPTER_GROUP, HostRequest
from drivers.can.codec import SignalLayout, _raw_bounds_for_encode
from drivers.can.ltc import LtcAdapter
from drivers.can.ltc_fd import LtcFdAdapter, crc16_of_frame
from drivers.can.ltc_frames import FrameSpec, NmtState, crc8_of_frame
from drivers.can.ltc_protocol import _load_dbc
from drivers.can.rt_json import _json_float
from drivers.can.rt_tables_golden import _commands, _frame_json, _ltc_fd_feed, _ltc_feed
from drivers.registry import load_adapter
from gateway.errors import ConfigError

__all__ = ["GOLDEN_CASES", "GOLDEN_PATH", "TABLES_FORMAT", "golden", "ltc_tables", "main"]

#: Version of the table layout; the Rust side refuses any other.
TABLES_FORMAT = 1
#: Where the Rust tests read the golden vectors.
GOLDEN_PATH = Path(__file__).with_name("rt") / "tests" / "data" / "ltc_golden.json"
#: (adapter, joints) of the golden cases: both profiles, the full arm and a smaller one.
GOLDEN_CASES: tuple[tuple[str, int], ...] = (
    ("ltc_dbc", 6),
    ("ltc_dbc", 3),
    ("ltc_fd", 6),
    ("ltc_fd", 2),
)

_CRCS: dict[str, Callable[[int], Callable[[bytes], int]]] = {
    "crc8_sae_j1850": crc8_of_frame,
    "crc16_ccitt_false": crc16_of_frame,
}


# --- tables ---------------------------------------------------------------------------------
def _json_number(value: int | float | None) -> int | float | str | None:
    """An int stays an int (bools become ints), a float goes through :func:`_json_float`."""
    if value is None or isinstance(value, int):
        return None if value is None else int(value)
    return _json_float(float(value))


def _adapter(adapter_name: str, n_joints: int) -> LtcAdapter | LtcFdAdapter:
    cls = load_adapter(ADAPTER_GROUP, adapter_name)
    if not (isinstance(cls, type) and issubclass(cls, LtcAdapter | LtcFdAdapter)):
        raise ConfigError(
            f"CAN adapter {adapter_name!r} is not an LTC adapter (ltc_dbc, ltc_fd): "
            "it has no compiled tables"
        )
    return cls(n_joints=n_joints)


def _crc_table(spec: FrameSpec) -> dict[str, Any] | None:
    """Which of the LTC CRCs ``spec`` carries, found by computing both on probe payloads."""
    if spec.crc is None:
        return None
    probes = [bytes(spec.length), bytes([0xFF] * spec.length), bytes(range(spec.length))]
    for algorithm, of_frame in _CRCS.items():
        crc = of_frame(spec.frame_id)
        if all(crc(p) == spec.crc(p) for p in probes):
            return {"algorithm": algorithm, "bytes": spec.crc_bytes}
    raise ConfigError(f"{spec.where}: its CRC is none of {sorted(_CRCS)}")


def _signal_table(sig: SignalLayout, accepted: tuple[int, int], choices: Any) -> dict[str, Any]:
    encode_raw = _raw_bounds_for_encode(sig)
    return {
        "name": sig.name,
        "start_bit": sig.start_bit,
        "length_bits": sig.length_bits,
        "signed": sig.is_signed,
        "conversion": sig.conversion,
        "scale": _json_number(sig.scale),
        "offset": _json_number(sig.offset),
        "minimum": _json_number(sig.minimum),
        "maximum": _json_number(sig.maximum),
        "unit": sig.unit,
        "raw_min": sig.raw_min,
        "raw_max": sig.raw_max,
        "decode_raw": list(accepted),
        "encode_raw": None if encode_raw is None else list(encode_raw),
        "choices": None if not choices else [[int(k), str(v)] for k, v in choices.items()],
    }


def _message_table(db: Any, spec: FrameSpec) -> dict[str, Any]:
    codec = spec.codec
    message = db.get_message_by_name(spec.name)
    signals = []
    for sig, accepted in zip(codec.signals, codec._accept, strict=True):
        assert accepted is not None  # MessageCodec refuses a signal without one
        choices = message.get_signal_by_name(sig.name).choices
        signals.append(_signal_table(sig, accepted, choices))
    return {
        "name": spec.name,
        "id": spec.frame_id,
        "where": spec.where,
        "length": spec.length,
        "fd": spec.is_fd,
        "brs": spec.bitrate_switch,
        "extended": codec.is_extended_frame,
        "kind": spec.kind,
        "joint": spec.joint,
        "node": spec.node,
        "crc": _crc_table(spec),
        "signals": signals,
    }


def ltc_tables(adapter_name: str, n_joints: int) -> dict[str, Any]:
    """Everything the compiled adapter ``adapter_name`` needs for ``n_joints`` joints.

    Built from the Python adapter of that registry name, so from the same DBC, with the same
    checks (ConfigError for a bad DBC, an unknown adapter, a joint count out of range).
    """
    adapter = _adapter(adapter_name, n_joints)
    protocol = adapter.protocol
    db = _load_dbc(str(protocol.dbc_path.resolve()))
    specs = list(protocol._by_id.values())
    by_name = {s.name: s for s in specs}
    request_counter = by_name["HOST_REQUEST"].codec.signals
    counter = next(s for s in request_counter if s.name == "counter")
    tables: dict[str, Any] = {
        "format": TABLES_FORMAT,
        "adapter": adapter.name,
        "protocol": protocol.protocol_name,
        "profile": protocol.profile,
        "dbc": protocol.dbc_path.name,
        "dbc_version": db.version,
        "n_joints": adapter.n_joints,
        "max_joints": protocol.max_joints,
        "counter_modulus": adapter.counter_modulus,
        "command_counter_modulus": protocol.command_counter_modulus,
        # ltc.py masks with 0xFF: the field is a byte wide (checked by the golden vectors)
        "request_counter_modulus": counter.raw_max + 1,
        "host_heartbeat_timeout_s": _json_float(float(adapter.host_heartbeat_timeout_s)),
        "heartbeat_nmt_state": int(NmtState.OPERATIONAL),
        "cycle_frame_ids": sorted(protocol.cycle_frame_ids),
        "messages": [_message_table(db, s) for s in specs],
    }
    if protocol.profile == "classic":
        fb = next(s for s in by_name["JOINT_FB_J1"].codec.signals if s.name == "counter")
        tables["feedback_counter_modulus"] = fb.raw_max + 1  # ltc.py: "& 0xFF", the low byte
    return tables


# --- golden vectors -------------------------------------------------------------------------
def _golden_case(adapter_name: str, n_joints: int) -> dict[str, Any]:
    rng = random.Random(f"{adapter_name}/{n_joints}")
    adapter = _adapter(adapter_name, n_joints)
    if isinstance(adapter, LtcAdapter):
        feed = _ltc_feed(adapter, rng)
    else:
        feed = _ltc_fd_feed(adapter, rng)
    commands = _commands(adapter, rng)
    fresh = _adapter(adapter_name, n_joints)  # the request counter starts at 0
    requests = [HostRequest(k % 3) for k in range(257)]
    return {
        "adapter": adapter_name,
        "n_joints": n_joints,
        "tables": ltc_tables(adapter_name, n_joints),
        "feed": feed,
        "commands": commands,
        "requests": [[r.name, _frame_json(fresh.request_frames(r)[0])] for r in requests],
        "heartbeat": _frame_json(fresh.heartbeat_frame()),
    }


def golden() -> dict[str, Any]:
    """The golden vectors of every :data:`GOLDEN_CASES` case (deterministic: seeded)."""
    return {
        "about": "generated by python -m drivers.can.rt_tables --golden; do not edit",
        "format": TABLES_FORMAT,
        "cases": [_golden_case(name, n) for name, n in GOLDEN_CASES],
    }


def _depth(value: Any) -> int:
    if isinstance(value, dict):
        return 1 + max(map(_depth, value.values()), default=0)
    if isinstance(value, list):
        return 1 + max(map(_depth, value), default=0)
    return 0


def dumps(value: Any, indent: str = "") -> str:
    """JSON with a line per record (a signal, a fed frame, a command set): reviewable diffs."""
    flat = json.dumps(value, allow_nan=False, separators=(",", ":"))
    short = len(indent) + len(flat) <= 100
    if short or not value or not isinstance(value, dict | list):
        return flat
    if isinstance(value, dict) and _depth(value) <= 3:
        return flat
    inner = indent + " "
    if isinstance(value, dict):
        items = [f"{inner}{json.dumps(k)}:{dumps(v, inner)}" for k, v in value.items()]
        return "{\n" + ",\n".join(items) + "\n" + indent + "}"
    items = [inner + dumps(v, inner) for v in value]
    return "[\n" + ",\n".join(items) + "\n" + indent + "]"


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m drivers.can.rt_tables",
        description="Print the compiled LTC adapter's tables, or write its golden vectors.",
    )
    parser.add_argument("--adapter", default="ltc_dbc", help="registry name (ltc_dbc, ltc_fd)")
    parser.add_argument("--joints", type=int, default=6)
    parser.add_argument("--golden", type=Path, metavar="PATH", help="write golden vectors")
    args = parser.parse_args(argv)
    if args.golden is not None:
        args.golden.parent.mkdir(parents=True, exist_ok=True)
        args.golden.write_text(dumps(golden()) + "\n")
        return 0
    sys.stdout.write(dumps(ltc_tables(args.adapter, args.joints)) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
