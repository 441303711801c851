"""``[can]`` config validation and the adapter registry."""

from __future__ import annotations

import tomllib
from pathlib import Path

import pytest

from drivers.can.adapter import ADAPTER_GROUP, CanAdapter
from drivers.can.config import CanDriverConfig, load_can_config
from drivers.can.ltc import LtcAdapter
from drivers.registry import available, load_adapter
from gateway.config import from_mapping
from gateway.errors import ConfigError

REPO = Path(__file__).resolve().parents[2]
SOCKETCAN = {"interface": "socketcan", "channel": "can1", "fd": True}
#: a remote virtual controller's socketcand server: not spoken by the CAN driver, which speaks
#: only socketcan and seqpacket (drivers/can/rt/src/can_socket.rs)
SOCKETCAND = {"interface": "socketcand", "channel": "vcan0", "host": "127.0.0.1", "port": 29536}
ONLY_TWO = r"transport.interface: '{}': .*'socketcan'.*'seqpacket'"
SEQPACKET = {"interface": "seqpacket", "channel": "@leadthrough-test"}
#: the virtual CiA 402 cell's drives, as its config describes them
CIA402_TABLE = {
    **tomllib.loads((REPO / "deploy/config/sim_cell_cia402.toml").read_text())["can"]["cia402"],
    "eds": str(REPO / "deploy" / "cia402" / "leadthrough_drive.eds"),
}


def test_defaults_are_production_socketcan():
    cfg = CanDriverConfig()
    assert cfg.adapter == "ltc_dbc" and cfg.joints == 6
    assert cfg.transport == {"interface": "socketcan", "channel": "can0"}
    assert (cfg.deadline_s, cfg.lifecycle_timeout_s, cfg.io_timeout_s) == (0.010, 0.25, 0.25)
    assert (cfg.controller_timeout_s, cfg.heartbeat_period_s) == (0.1, 0.1)
    assert cfg.max_following_error_rad == (0.05,) * 6
    assert cfg.max_velocity_rad_s == (1.0,) * 6


def test_from_toml_table_with_per_joint_lists():
    cfg = from_mapping(
        CanDriverConfig,
        {
            "joints": 3,
            "transport": SOCKETCAN,
            "max_following_error_rad": [0.03, 0.03, 0.1],
            "max_velocity_rad_s": 2,
        },
        "cell.toml [can]",
    )
    assert cfg.max_following_error_rad == (0.03, 0.03, 0.1)
    assert cfg.max_velocity_rad_s == (2.0, 2.0, 2.0)
    assert cfg.transport == SOCKETCAN


@pytest.mark.parametrize(
    ("table", "message"),
    [
        ({"deadline_s": 0.0}, r"\[can\].deadline_s: 0.0 s outside"),
        ({"deadline_s": "soon"}, "expected a number"),
        ({"joints": 0}, r"\[can\].joints: 0 outside 1..16"),
        ({"max_following_error_rad": [0.1, 0.1]}, "has 2 values for 6 joints"),
        ({"max_velocity_rad_s": [1, 1, 1, 1, 1, -1]}, r"max_velocity_rad_s\[5\]: -1.0"),
        ({"heartbeat_period_s": 2.0}, "heartbeat_period_s"),
        ({"transport": {"channel": "can0"}}, "transport.interface"),
        ({"transport": {"interface": "socketcan"}}, "transport.channel"),
        ({"transport": {**SOCKETCAN, "bitrate": [1]}}, "transport.bitrate"),
        ({"transport": SOCKETCAND}, ONLY_TWO.format("socketcand")),
        ({"transport": {"interface": "virtual", "channel": "x"}}, ONLY_TWO.format("virtual")),
        ({"transport": {"interface": 7, "channel": "can0"}}, r"transport.interface: 7: "),
        ({"deadline": 0.01}, "unknown key"),
        ({"answer_by_period_fraction": 1.5}, r"answer_by_period_fraction: 1.5 outside \(0, 1\]"),
        ({"current_zero_cycles": -1}, r"current_zero_cycles: -1 not a whole number of cycles"),
        ({"current_zero_settle_cycles": 2.5}, "expected an integer"),
        ({"lost_cycle_answer": "brake"}, r"lost_cycle_answer: 'brake' is neither"),
        ({"lost_cycles_max_consecutive": -1}, "lost_cycles_max_consecutive"),
        ({"hand_guiding_max_speed_m_s": 2.0}, "hand_guiding_max_speed_m_s"),
        # a real controller (socketcan, the default) never waits for an answer
        ({"lockstep_answer_wait_s": 0.1}, r"lockstep_answer_wait_s: 0.1 s needs the lock-step"),
        (
            {"lockstep_answer_wait_s": 0.3, "transport": SEQPACKET},
            r"lockstep_answer_wait_s: 0.3 s outside 0..0.2",
        ),
        ({"lockstep_answer_wait_s": -0.1, "transport": SEQPACKET}, "lockstep_answer_wait_s"),
        (
            {
                "lockstep_answer_wait_s": 0.1,
                "transport": SEQPACKET,
                "adapter": "cia402",
                "cia402": CIA402_TABLE,
            },
            r"lockstep_answer_wait_s: CiA 402 drives are clocked by the host's SYNC",
        ),
        # start-up writes only in the manufacturer-specific area: the profile's are the adapter's
        (
            {"adapter": "cia402", "cia402": {**CIA402_TABLE, "startup_sdo": [[0x6007, 0, 0]]}},
            r"startup_sdo\[0\]: 0x6007 sub 0 is not an object of the manufacturer-specific area",
        ),
        (
            {"adapter": "cia402", "cia402": {**CIA402_TABLE, "startup_sdo": [[0x2010, 256, 1]]}},
            r"startup_sdo\[0\]: 0x2010 sub 256 is not",
        ),
        (
            {"adapter": "cia402", "cia402": {**CIA402_TABLE, "startup_sdo": [[0x2010, 1]]}},
            r"startup_sdo\[0\]: expected 3 values, got 2",
        ),
    ],
)
def test_bad_values_are_refused_with_field_and_reason(table, message):
    with pytest.raises(ConfigError, match=message):
        from_mapping(CanDriverConfig, table, "cell.toml [can]")


def test_a_lock_step_answer_wait_is_taken_for_the_virtual_controller():
    cfg = from_mapping(
        CanDriverConfig, {"lockstep_answer_wait_s": 0.2, "transport": SEQPACKET}, "cell.toml [can]"
    )
    assert cfg.lockstep_answer_wait_s == 0.2
    assert CanDriverConfig().lockstep_answer_wait_s == 0.0  # the default: a real controller


def test_the_virtual_cell_config_loads():
    can_cfg, bus_cfg = load_can_config(REPO / "deploy" / "config" / "sim_cell.toml")
    assert can_cfg.transport["interface"] == "seqpacket"
    assert bus_cfg.key_prefix == "lt"


def test_missing_file_is_a_config_error(tmp_path):
    with pytest.raises(ConfigError, match="not found"):
        load_can_config(tmp_path / "nope.toml")


def test_registry_finds_the_builtin_adapter_lazily():
    cls = load_adapter(ADAPTER_GROUP, "ltc_dbc")
    assert cls is LtcAdapter and issubclass(cls, CanAdapter)
    assert "ltc_dbc" in available(ADAPTER_GROUP)


def test_unknown_adapter_lists_the_available_ones():
    with pytest.raises(ConfigError, match=r"unknown adapter 'acme'.*available: \[.*'ltc_dbc'"):
        load_adapter(ADAPTER_GROUP, "acme")
    with pytest.raises(ConfigError, match=r"available: \[\]"):
        load_adapter("leadthrough.no_such_group", "x")
