"""The compiled DBC codec (drivers/can/codec.py) against cantools, bit for bit: pure functions.

cantools stays the reference: for every message and every signal of both LTC DBCs, random
in-range values must encode to cantools' bytes and random payloads decode to cantools' values.
"""

from __future__ import annotations

import math
import zlib
from pathlib import Path

import cantools
import numpy as np
import pytest

from drivers.can.codec import MessageCodec, compile_message, compile_messages
from drivers.can.ltc_fd import DEFAULT_FD_DBC_PATH, LtcFdProtocol, frame_crc16
from drivers.can.ltc_frames import frame_crc
from drivers.can.ltc_protocol import DEFAULT_DBC_PATH, LtcProtocol
from gateway.errors import ConfigError, FrameError

DBCS = {"ltc_v1": DEFAULT_DBC_PATH, "ltc_fd_v1": DEFAULT_FD_DBC_PATH}
SAMPLES_PER_MESSAGE = 2000


def _load(path: Path):
    return cantools.database.load_file(str(path), strict=True)


_DBS = {name: _load(path) for name, path in DBCS.items()}
MESSAGES = [
    pytest.param(db_name, message.name, id=f"{db_name}:{message.name}")
    for db_name, db in _DBS.items()
    for message in db.messages
]


def _rng(*key: object) -> np.random.Generator:
    """A generator seeded by the test's own key: reproducible, different per message."""
    return np.random.default_rng(zlib.crc32(repr(key).encode()))


def _is_integer(sig) -> bool:
    return sig.conversion.scale == 1 and sig.conversion.offset == 0


def _raw_limits(sig) -> tuple[int, int]:
    if sig.is_signed:
        return -(1 << (sig.length - 1)), (1 << (sig.length - 1)) - 1
    return 0, (1 << sig.length) - 1


def _random_physical(sig, rng: np.random.Generator) -> int | float:
    """An in-range physical value: uniform, on the raw grid, or exactly half-way between two
    raw steps (where the rounding rule shows), or a range end."""
    lo, hi = sig.minimum, sig.maximum
    if _is_integer(sig):
        return int(rng.integers(int(lo), int(hi) + 1))
    scale, offset = sig.conversion.scale, sig.conversion.offset
    kind = rng.integers(0, 4)
    if kind == 0:
        value = float(rng.uniform(lo, hi))
    else:
        raw_lo = math.ceil((lo - offset) / scale)
        raw_hi = math.floor((hi - offset) / scale)
        raw = int(rng.integers(min(raw_lo, raw_hi), max(raw_lo, raw_hi) + 1))
        value = raw * scale + offset
        if kind == 2:
            value += scale / 2  # a tie: round() goes to the even raw value
        elif kind == 3:
            value = float(lo if rng.integers(0, 2) else hi)
    return float(min(max(value, lo), hi))


def _cantools_encode(message, values: dict) -> bytes:
    return bytes(message.encode(values, scaling=True, padding=False, strict=True))


# --- encode ---------------------------------------------------------------------------------
@pytest.mark.parametrize(("db_name", "message_name"), MESSAGES)
def test_encode_of_random_in_range_values_equals_cantools_bit_for_bit(db_name, message_name):
    message = _DBS[db_name].get_message_by_name(message_name)
    codec = compile_message(message)
    rng = _rng("encode", db_name, message_name)
    for _ in range(SAMPLES_PER_MESSAGE):
        values = {sig.name: _random_physical(sig, rng) for sig in message.signals}
        assert bytes(codec.encode_mapping(values)) == _cantools_encode(message, values), values


@pytest.mark.parametrize(("db_name", "message_name"), MESSAGES)
def test_range_ends_encode_and_one_step_beyond_is_refused_naming_frame_signal_value_unit(
    db_name, message_name
):
    message = _DBS[db_name].get_message_by_name(message_name)
    codec = compile_message(message)
    middle = {s.name: _random_physical(s, _rng("mid", s.name)) for s in message.signals}
    for sig in message.signals:
        for end in (sig.minimum, sig.maximum):
            values = {**middle, sig.name: end if _is_integer(sig) else float(end)}
            assert bytes(codec.encode_mapping(values)) == _cantools_encode(message, values)
        step = abs(sig.conversion.scale)
        unit = f" {sig.unit}" if sig.unit else ""
        for beyond in (sig.minimum - step, sig.maximum + step):
            beyond = int(beyond) if _is_integer(sig) else float(beyond)
            with pytest.raises(FrameError) as info:
                codec.encode_mapping({**middle, sig.name: beyond})
            text = str(info.value)
            assert text.startswith(f"{message.name} (0x{message.frame_id:03X}): ")
            assert f"{sig.name} = {beyond!r}{unit} outside its DBC range" in text


@pytest.mark.parametrize(("db_name", "message_name"), MESSAGES)
@pytest.mark.parametrize("bad", [math.nan, math.inf, -math.inf])
def test_non_finite_values_are_refused_naming_the_signal(db_name, message_name, bad):
    message = _DBS[db_name].get_message_by_name(message_name)
    codec = compile_message(message)
    middle = {s.name: _random_physical(s, _rng("mid", s.name)) for s in message.signals}
    for sig in message.signals:
        with pytest.raises(FrameError, match=f"{sig.name} = {bad!r}.* is not finite"):
            codec.encode_mapping({**middle, sig.name: bad})


def test_unscaled_signals_need_integers_and_accept_integral_floats_bools_and_numpy():
    codec = compile_message(_DBS["ltc_v1"].get_message_by_name("CTRL_STATUS"))
    values = dict(
        cycle_counter=7,
        state=1,
        fault_code=0,
        missed_cycles=3,
        estop_active=False,
        servo_power=True,
        cycle_period_us=4000,
    )
    reference = codec.encode_mapping(values)
    variants = dict(cycle_counter=7.0, missed_cycles=np.uint8(3), cycle_period_us=np.int64(4000))
    assert codec.encode_mapping({**values, **variants}) == reference
    with pytest.raises(FrameError, match=r"cycle_period_us = 4000.5 us must be an integer"):
        codec.encode_mapping({**values, "cycle_period_us": 4000.5})
    with pytest.raises(FrameError, match=r"state = '1' is not a number"):
        codec.encode_mapping({**values, "state": "1"})


def test_scaled_signals_accept_ints_and_numpy_floats_like_python_floats():
    codec = compile_message(_DBS["ltc_v1"].get_message_by_name("JOINT_FB_J1"))
    reference = codec.encode(0.0, 1.0, -2.0, 9)
    assert codec.encode(0, 1, -2, 9) == reference
    assert codec.encode(np.float64(0.0), np.float32(1.0), np.int16(-2), np.uint8(9)) == reference


# --- decode ---------------------------------------------------------------------------------
def _in_range(message, decoded: dict) -> str | None:
    """The first signal today's LTC decode refused (value beyond its range ± half a step)."""
    for sig in message.signals:
        v, tol = decoded[sig.name], abs(sig.conversion.scale) / 2
        if (sig.minimum is not None and v < sig.minimum - tol) or (
            sig.maximum is not None and v > sig.maximum + tol
        ):
            return sig.name
    return None


@pytest.mark.parametrize(("db_name", "message_name"), MESSAGES)
def test_decode_of_random_payloads_equals_cantools_and_refuses_what_is_out_of_range(
    db_name, message_name
):
    message = _DBS[db_name].get_message_by_name(message_name)
    codec = compile_message(message)
    rng = _rng("decode", db_name, message_name)
    refused = accepted = 0
    for i in range(SAMPLES_PER_MESSAGE):
        if i % 4 == 0:  # any bytes at all, unused bits included
            data = rng.bytes(message.length)
        else:  # raw values mostly inside the range, so most payloads decode
            raw = {}
            for sig in message.signals:
                lo, hi = _raw_limits(sig)
                if rng.random() < 0.9 and sig.minimum is not None:
                    scale, offset = sig.conversion.scale, sig.conversion.offset
                    lo = max(lo, math.ceil((sig.minimum - offset) / scale))
                    hi = min(hi, math.floor((sig.maximum - offset) / scale))
                raw[sig.name] = int(rng.integers(lo, hi + 1))
            data = bytes(message.encode(raw, scaling=False, padding=False, strict=False))
        expected = message.decode(data, decode_choices=False, scaling=True)
        bad_signal = _in_range(message, expected)
        if bad_signal is None:
            got = codec.decode_mapping(data)
            assert got == expected
            assert [type(v) for v in got.values()] == [type(v) for v in expected.values()]
            accepted += 1
        else:
            with pytest.raises(FrameError, match=f"{bad_signal} = .* outside its range"):
                codec.decode(data)
            refused += 1
    assert accepted > SAMPLES_PER_MESSAGE // 2


@pytest.mark.parametrize(("db_name", "message_name"), MESSAGES)
def test_decode_accepts_half_a_step_beyond_the_range_and_refuses_one_step(db_name, message_name):
    message = _DBS[db_name].get_message_by_name(message_name)
    codec = compile_message(message)
    middle = {s.name: _random_physical(s, _rng("mid", s.name)) for s in message.signals}
    for sig in message.signals:
        scale, offset = sig.conversion.scale, sig.conversion.offset
        field_lo, field_hi = _raw_limits(sig)
        raw_min = round((sig.minimum - offset) / scale)
        raw_max = round((sig.maximum - offset) / scale)
        base = message.encode(middle, scaling=True, strict=True)
        raws = message.decode(base, decode_choices=False, scaling=False)
        for raw, ok in (
            (raw_min, True),
            (raw_max, True),
            (raw_min - 1, False),
            (raw_max + 1, False),
        ):
            if not field_lo <= raw <= field_hi:
                continue  # the field cannot hold it: nothing to refuse
            data = bytes(message.encode({**raws, sig.name: raw}, scaling=False, strict=False))
            if ok:
                assert codec.decode_mapping(data) == message.decode(data, decode_choices=False)
            else:
                with pytest.raises(FrameError, match=f"{sig.name} = .* outside its range"):
                    codec.decode(data)


def test_decode_refuses_a_payload_of_the_wrong_length():
    codec = compile_message(_DBS["ltc_v1"].get_message_by_name("JOINT_FB_J2"))
    with pytest.raises(FrameError, match=r"JOINT_FB_J2 \(0x182\): 7 data bytes, expected 8"):
        codec.decode(bytes(7))


# --- the protocols' frames (CRC, rolling counter) -------------------------------------------
def test_ltc1_command_frames_equal_cantools_with_frame_crc_and_rolling_counter():
    proto = LtcProtocol(6)
    db = _DBS["ltc_v1"]
    rng = _rng("ltc1 commands")
    for i in range(SAMPLES_PER_MESSAGE):
        joint = i % 6 + 1
        message = db.get_message_by_name(f"JOINT_CMD_J{joint}")
        sigs = {s.name: s for s in message.signals}
        q = _random_physical(sigs["position_cmd"], rng)
        dq = _random_physical(sigs["velocity_cmd"], rng)
        hold, counter = bool(rng.integers(0, 2)), i & 0xFF
        values = dict(position_cmd=q, velocity_cmd=dq, hold=int(hold), counter=counter, crc=0)
        expected = bytearray(_cantools_encode(message, values))
        expected[7] = frame_crc(message.frame_id, expected[:7])
        assert bytes(proto.encode_command(joint, q, dq, hold, counter).data) == bytes(expected)


def test_ltc1f_command_sets_equal_cantools_with_frame_crc16_and_rolling_counter():
    proto = LtcFdProtocol(6)
    message = _DBS["ltc_fd_v1"].get_message_by_name("CYCLE_CMD")
    sigs = {s.name: s for s in message.signals}
    rng = _rng("ltc1f commands")
    for i in range(SAMPLES_PER_MESSAGE):
        q = [_random_physical(sigs[f"position_cmd_j{k}"], rng) for k in range(1, 7)]
        dq = [_random_physical(sigs[f"velocity_cmd_j{k}"], rng) for k in range(1, 7)]
        hold, counter = bool(rng.integers(0, 2)), (i * 257) & 0xFFFF
        values = {"counter": counter, "hold": int(hold), "crc": 0}
        for k in range(6):
            values[f"position_cmd_j{k + 1}"] = q[k]
            values[f"velocity_cmd_j{k + 1}"] = dq[k]
        expected = bytearray(_cantools_encode(message, values))
        expected[46:48] = frame_crc16(message.frame_id, expected[:46]).to_bytes(2, "little")
        msg = proto.encode_command_set(counter, q, dq, hold)
        assert bytes(msg.data) == bytes(expected)


# --- code generation details ----------------------------------------------------------------
def test_encoder_and_decoder_bind_signals_by_name_in_any_order():
    codec = compile_message(_DBS["ltc_v1"].get_message_by_name("JOINT_FB_J1"))
    reverse = codec.encoder(("counter", "current", "velocity", "position"))
    assert reverse(7, 1.5, -0.25, 0.5) == codec.encode(0.5, -0.25, 1.5, 7)
    pick = codec.decoder(("counter", "position"))
    assert pick(codec.encode(0.5, -0.25, 1.5, 7)) == (7, 0.5)
    with pytest.raises(ConfigError, match=r"must name every signal; missing \['counter'\]"):
        codec.encoder(("position", "velocity", "current"))
    with pytest.raises(ConfigError, match="unknown signal 'torque'"):
        codec.decoder(("torque",))
    with pytest.raises(ConfigError, match="names a signal twice"):
        codec.decoder(("position", "position"))


def test_compile_messages_compiles_a_whole_dbc_and_names_a_missing_message():
    codecs = compile_messages(_DBS["ltc_fd_v1"])
    assert set(codecs) == {m.name for m in _DBS["ltc_fd_v1"].messages}
    assert all(isinstance(c, MessageCodec) for c in codecs.values())
    assert codecs["CYCLE_FB"].is_fd and codecs["CYCLE_FB"].length == 64
    with pytest.raises(ConfigError, match="message NOPE missing"):
        compile_messages(_DBS["ltc_fd_v1"], ["NOPE"])


# Layouts our DBCs do not use, but the codec claims to support: odd bit positions and lengths,
# integer scale (cantools' divmod rounding), offsets, a negative scale, 64-bit fields, no range.
EXOTIC_DBC = """VERSION ""
NS_ :
BS_:
BU_: A B
BO_ 100 EXOTIC: 20 A
 SG_ odd3 : 3|5@1+ (1,0) [0|31] "" B
 SG_ temp : 8|8@1+ (1,-40) [-40|215] "degC" B
 SG_ twice : 16|7@1- (2,0) [-128|126] "mm" B
 SG_ flipped : 23|12@1+ (-0.5,100) [-1947.5|100] "V" B
 SG_ half_off : 35|13@1- (0.25,0.125) [-1023.875|1023.875] "" B
 SG_ wide : 48|64@1- (1,0) [-9223372036854775808|9223372036854775807] "" B
 SG_ unbounded : 112|9@1+ (0.1,0) [0|0] "" B
 SG_ top : 121|39@1+ (0.001,0) [0|549755813.887] "s" B
"""


def test_exotic_little_endian_layouts_equal_cantools_bit_for_bit():
    db = cantools.database.load_string(EXOTIC_DBC, "dbc", strict=True)
    message = db.get_message_by_name("EXOTIC")
    codec = compile_message(message)
    rng = _rng("exotic")
    unbounded = message.get_signal_by_name("unbounded")
    assert unbounded.minimum is None and unbounded.maximum is None
    for i in range(SAMPLES_PER_MESSAGE):
        values = {}
        for sig in message.signals:
            if sig is unbounded:
                values[sig.name] = int(rng.integers(0, 512)) * 0.1
            elif sig.name == "wide":
                values[sig.name] = int(rng.integers(-(1 << 63), (1 << 63) - 1, dtype=np.int64))
            else:
                values[sig.name] = _random_physical(sig, rng)
        assert bytes(codec.encode_mapping(values)) == _cantools_encode(message, values), values
        data = rng.bytes(message.length) if i % 2 else _cantools_encode(message, values)
        expected = message.decode(data, decode_choices=False, scaling=True)
        bad_signal = _in_range(message, expected)
        if bad_signal is None:
            assert codec.decode_mapping(data) == expected
        else:
            with pytest.raises(FrameError, match=f"{bad_signal} = "):
                codec.decode(data)
    with pytest.raises(FrameError, match=r"unbounded = 51.2 is raw 512, outside the 9-bit"):
        codec.encode_mapping({**values, "unbounded": 51.2})


def _one_message_dbc(signals: str, extra: str = "", length: int = 8) -> str:
    return f"""VERSION ""
NS_ :
BS_:
BU_: A B
BO_ 291 TINY: {length} A
{signals}
{extra}
"""


@pytest.mark.parametrize(
    ("signals", "extra", "complaint"),
    [
        (' SG_ motorola : 7|16@0+ (1,0) [0|65535] "" B', "", r"TINY\.motorola: big-endian"),
        (
            ' SG_ ieee : 0|32@1- (1,0) [0|0] "" B',
            "SIG_VALTYPE_ 291 ieee : 1;",
            r"TINY\.ieee: float \(IEEE\) signals are not supported",
        ),
        (
            ' SG_ mux M : 0|8@1+ (1,0) [0|1] "" B\n SG_ a m0 : 8|8@1+ (1,0) [0|255] "" B',
            "",
            r"TINY\.mux: multiplexed signals are not supported",
        ),
    ],
    ids=["big_endian", "float", "multiplexed"],
)
def test_unsupported_dbc_features_are_refused_naming_message_and_signal(signals, extra, complaint):
    db = cantools.database.load_string(_one_message_dbc(signals, extra), "dbc", strict=True)
    with pytest.raises(ConfigError, match=complaint):
        compile_message(db.get_message_by_name("TINY"))


def test_a_range_no_raw_value_can_reach_is_refused():
    dbc = _one_message_dbc(' SG_ far : 0|8@1+ (1,0) [300|400] "" B')
    db = cantools.database.load_string(dbc, "dbc", strict=False)
    with pytest.raises(ConfigError, match=r"TINY\.far: no 8-bit raw value lies in the DBC range"):
        compile_message(db.get_message_by_name("TINY"))


def test_generated_code_is_readable_for_debugging():
    codec = compile_message(_DBS["ltc_v1"].get_message_by_name("JOINT_CMD_J1"))
    assert "round(v0 / 1e-06)" in codec.encode.source
    assert "_from_bytes(data, 'little')" in codec.decode.source
