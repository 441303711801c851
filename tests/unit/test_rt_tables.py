"""The compiled LTC adapters' tables and golden vectors (drivers/can/rt_tables.py).

The Rust crate (drivers/can/rt) replays drivers/can/rt/tests/data/ltc_golden.json; these tests
make sure that file is what the Python adapters and the DBCs produce today, so the compiled
adapters cannot drift from them unnoticed.
"""

from __future__ import annotations

import json
import math

import pytest

from drivers.can.ltc_protocol import LtcProtocol
from drivers.can.rt_json import _json_float
from drivers.can.rt_tables import GOLDEN_PATH, dumps, ltc_tables, main
from gateway.errors import ConfigError

REGENERATE = "python -m drivers.can.rt_tables --golden drivers/can/rt/tests/data/ltc_golden.json"


def test_the_committed_golden_vectors_are_what_python_generates_today(tmp_path):
    path = tmp_path / "golden.json"
    assert main(["--golden", str(path)]) == 0
    written, committed = path.read_text(), GOLDEN_PATH.read_text()
    same = written == committed
    if not same:
        lines = zip(written.splitlines(), committed.splitlines(), strict=False)
        first = next((k for k, (a, b) in enumerate(lines, 1) if a != b), None)
        pytest.fail(f"{GOLDEN_PATH} is stale (first difference at line {first}): {REGENERATE}")


@pytest.mark.parametrize("adapter", ["ltc_dbc", "ltc_fd"])
@pytest.mark.parametrize("n_joints", [1, 6])
def test_tables_are_json_and_survive_a_round_trip(adapter, n_joints):
    tables = ltc_tables(adapter, n_joints)
    text = json.dumps(tables, allow_nan=False)
    assert json.loads(text) == tables
    assert json.loads(dumps(tables)) == tables
    assert (tables["adapter"], tables["n_joints"], tables["max_joints"]) == (adapter, n_joints, 6)


def test_tables_carry_the_dbc_layout_the_crcs_and_the_counters():
    tables = ltc_tables("ltc_dbc", 6)
    messages = {m["name"]: m for m in tables["messages"]}
    assert len(messages) == 16  # request, 2 heartbeats, status, 6 feedback, 6 command
    proto = LtcProtocol(6)
    assert messages["CTRL_STATUS"]["id"] == proto.status_id
    assert tables["cycle_frame_ids"] == sorted(proto.cycle_frame_ids)
    position = messages["JOINT_CMD_J3"]["signals"][0]
    assert position["name"] == "position_cmd"
    assert (position["start_bit"], position["length_bits"], position["signed"]) == (0, 24, True)
    assert (position["scale"], position["minimum"], position["maximum"]) == (
        1e-6,
        -8.388608,
        8.388607,
    )
    assert position["decode_raw"] == position["encode_raw"] == [-8388608, 8388607]
    assert messages["JOINT_CMD_J3"]["crc"] == {"algorithm": "crc8_sae_j1850", "bytes": 1}
    assert messages["JOINT_FB_J3"]["crc"] is None
    period = messages["CTRL_STATUS"]["signals"][-1]
    assert (period["name"], period["decode_raw"]) == ("cycle_period_us", [100, 65535])
    assert (tables["counter_modulus"], tables["command_counter_modulus"]) == (65536, 256)
    assert (tables["feedback_counter_modulus"], tables["request_counter_modulus"]) == (256, 256)

    fd = {m["name"]: m for m in ltc_tables("ltc_fd", 2)["messages"]}
    assert fd["CYCLE_CMD"]["crc"] == {"algorithm": "crc16_ccitt_false", "bytes": 2}
    assert (fd["CYCLE_CMD"]["fd"], fd["CYCLE_CMD"]["brs"], fd["CYCLE_CMD"]["length"]) == (
        True,
        True,
        48,
    )
    assert (fd["HOST_REQUEST"]["fd"], fd["CYCLE_FB"]["length"]) == (False, 64)


def test_other_adapters_and_joint_counts_are_refused():
    with pytest.raises(ConfigError, match="not an LTC adapter"):
        ltc_tables("cia402", 6)
    with pytest.raises(ConfigError):
        ltc_tables("no_such_adapter", 6)
    with pytest.raises(ConfigError, match=r"carries 1\.\.6 joints, not 7"):
        ltc_tables("ltc_fd", 7)


@pytest.mark.parametrize(
    ("value", "as_json"),
    [
        (1e-6, 1e-6),
        (-8.388608, -8.388608),
        (-0.0, -0.0),
        (123456789012345.6, 123456789012345.6),  # 16 digits, significand < 2**53
        (0.30000000000000004, "0.30000000000000004"),  # significand > 2**53
        (1e-300, "1e-300"),  # exponent beyond ±22
        (math.nan, "nan"),
        (-math.inf, "-inf"),
    ],
)
def test_floats_are_numbers_only_where_serde_json_reads_them_back_exactly(value, as_json):
    got = _json_float(value)
    assert type(got) is type(as_json)
    if isinstance(as_json, float):
        assert math.copysign(1, got) == math.copysign(1, as_json) and got == as_json
    else:
        assert got == as_json
        assert math.isnan(value) or float(got) == value
