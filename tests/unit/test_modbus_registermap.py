"""Register map: encodings against hand-written registers, plausibility checks, config errors."""

from __future__ import annotations

import math
import tomllib

import pytest

from drivers.modbus.adapter import (
    RegisterMapAdapter,
    adapter_class,
    available_adapters,
    create_adapter,
)
from drivers.modbus.config import ModbusDriverConfig
from drivers.modbus.registermap import Point, RegisterMap, decode_point, encode_point
from gateway.config import from_mapping
from gateway.errors import ConfigError, ModbusReplyError
from sim_bridge.modbus_server import sim_modbus_section_toml, sim_register_points_toml


def reg(type_: str, byte_order: str = "big", word_order: str = "big", **kw) -> Point:
    return Point(
        "x", "input_registers", 10, type_, byte_order=byte_order, word_order=word_order, **kw
    )


# (type, engineering value, byte_order, word_order, registers as the device manual shows them)
CASES = [
    # float32 1.5 = 0x3FC00000
    ("float32", 1.5, "big", "big", [0x3FC0, 0x0000]),
    ("float32", 1.5, "big", "little", [0x0000, 0x3FC0]),
    ("float32", 1.5, "little", "big", [0xC03F, 0x0000]),
    ("float32", 1.5, "little", "little", [0x0000, 0xC03F]),
    # float32 -2.75 = 0xC0300000; 123.456 = 0x42F6E979 (all four bytes distinct)
    ("float32", -2.75, "big", "big", [0xC030, 0x0000]),
    ("float32", 123.45600128173828, "big", "big", [0x42F6, 0xE979]),
    ("float32", 123.45600128173828, "big", "little", [0xE979, 0x42F6]),
    ("float32", 123.45600128173828, "little", "big", [0xF642, 0x79E9]),
    ("float32", 123.45600128173828, "little", "little", [0x79E9, 0xF642]),
    # uint32 0x12345678
    ("uint32", 0x12345678, "big", "big", [0x1234, 0x5678]),
    ("uint32", 0x12345678, "big", "little", [0x5678, 0x1234]),
    ("uint32", 0x12345678, "little", "big", [0x3412, 0x7856]),
    ("uint32", 0x12345678, "little", "little", [0x7856, 0x3412]),
    ("uint32", 0xFFFFFFFF, "big", "big", [0xFFFF, 0xFFFF]),
    # int32 -123456 = 0xFFFE1DC0
    ("int32", -123456, "big", "big", [0xFFFE, 0x1DC0]),
    ("int32", -123456, "big", "little", [0x1DC0, 0xFFFE]),
    ("int32", -123456, "little", "big", [0xFEFF, 0xC01D]),
    ("int32", -123456, "little", "little", [0xC01D, 0xFEFF]),
    # 16-bit: word order does not apply
    ("int16", -2, "big", "big", [0xFFFE]),
    ("int16", -2, "little", "little", [0xFEFF]),
    ("int16", 0x1234, "little", "big", [0x3412]),
    ("uint16", 0x1234, "big", "little", [0x1234]),
    ("uint16", 65535, "big", "big", [0xFFFF]),
]


@pytest.mark.parametrize(("type_", "value", "byte_order", "word_order", "regs"), CASES)
def test_decode_and_encode_match_hand_written_registers(type_, value, byte_order, word_order, regs):
    p = reg(type_, byte_order, word_order)
    assert decode_point(p, regs) == value
    assert encode_point(p, value) == regs


def test_scale_and_offset_give_engineering_units():
    mbar = reg("uint16", scale=0.001)
    assert decode_point(mbar, [3250]) == pytest.approx(3.25)
    assert encode_point(mbar, 3.25) == [3250]
    # engineering = raw * scale + offset: a 4..20 mA input in µA → 0..10 bar
    ma = reg("int16", scale=10.0 / 16000.0, offset=-2.5)
    assert decode_point(ma, [12000]) == pytest.approx(5.0)
    assert encode_point(ma, 5.0) == [12000]
    # integers round to the nearest raw step
    assert encode_point(mbar, 1.23449) == [1234]


def test_bool_points_in_bit_and_register_tables():
    di = Point("en", "discrete_inputs", 0, "bool")
    assert decode_point(di, [True]) is True
    assert decode_point(di, [False]) is False
    assert encode_point(di, True) == [1]
    in_reg = Point("flag", "holding_registers", 5, "bool")
    assert decode_point(in_reg, [0]) is False
    assert decode_point(in_reg, [0x0100]) is True


@pytest.mark.parametrize(
    ("regs", "shown"),
    [([0x7FC0, 0x0000], "nan"), ([0x7F80, 0x0000], "inf"), ([0xFF80, 0x0000], "-inf")],
)
def test_non_finite_float_raises_naming_point_and_registers(regs, shown):
    p = Point("p2_bar", "input_registers", 0, "float32")
    with pytest.raises(ModbusReplyError, match="p2_bar") as err:
        decode_point(p, regs)
    assert f"0x{regs[0]:04X}" in str(err.value)
    assert shown in str(err.value)


def test_value_outside_plausibility_range_raises():
    p = Point("p3_bar", "input_registers", 2, "uint16", scale=0.001, min=0.0, max=12.0)
    assert decode_point(p, [12000]) == pytest.approx(12.0)
    with pytest.raises(ModbusReplyError, match=r"p3_bar.*0xFFFF.*65\.535"):
        decode_point(p, [0xFFFF])
    low = Point("t", "input_registers", 0, "int16", min=-5.0)
    with pytest.raises(ModbusReplyError, match="'t'"):
        decode_point(low, [0xFFF0])  # -16


def test_decode_refuses_wrong_register_count_and_non_words():
    p = reg("float32")
    with pytest.raises(ModbusReplyError, match="expected 2"):
        decode_point(p, [0x3FC0])
    with pytest.raises(ModbusReplyError, match="16-bit"):
        decode_point(reg("uint16"), [70000])


@pytest.mark.parametrize(
    ("point", "value", "match"),
    [
        (reg("float32"), math.nan, "refusing"),
        (reg("float32"), math.inf, "refusing"),
        (reg("float32"), 1e39, "float32"),
        (reg("uint16"), 65536, "uint16"),
        (reg("uint16"), -1, "uint16"),
        (reg("int16"), 32768, "int16"),
        (reg("int32"), 2**31, "int32"),
        (reg("uint32"), -0.6, "uint32"),
        (reg("uint16", scale=0.001), 65.6, "uint16"),
        (reg("float32", min=0.0, max=10.0), 10.5, "range"),
        (Point("en", "coils", 0, "bool"), 2, "bool"),
    ],
)
def test_encode_refuses_values_that_do_not_fit(point, value, match):
    with pytest.raises(ValueError, match=match):
        encode_point(point, value)


# Configuration errors ------------------------------------------------------------------------


def test_point_validation_names_the_field():
    with pytest.raises(ConfigError, match=r"point 'p'\.type.*'float64'"):
        Point("p", "input_registers", 0, "float64")
    with pytest.raises(ConfigError, match=r"point 'p'\.table"):
        Point("p", "inputs", 0, "uint16")
    with pytest.raises(ConfigError, match=r"point 'p'\.word_order"):
        Point("p", "input_registers", 0, "int32", word_order="middle")
    with pytest.raises(ConfigError, match=r"point 'p'\.address"):
        Point("p", "input_registers", 65535, "float32")
    with pytest.raises(ConfigError, match=r"point 'p'\.type.*bit tables"):
        Point("p", "discrete_inputs", 0, "uint16")
    with pytest.raises(ConfigError, match=r"min 5\.0 is greater than max 1\.0"):
        Point("p", "input_registers", 0, "uint16", min=5.0, max=1.0)
    with pytest.raises(ConfigError, match=r"point 'p'\.scale"):
        Point("p", "input_registers", 0, "uint16", scale=0.0)


def test_map_refuses_duplicate_names():
    points = [
        Point("a", "input_registers", 0, "uint16"),
        Point("a", "input_registers", 1, "uint16"),
    ]
    with pytest.raises(ConfigError, match="duplicate point name 'a'"):
        RegisterMap(points)


def test_map_refuses_overlapping_addresses_in_one_table():
    points = [
        Point("p2", "input_registers", 0, "float32"),  # occupies 0..1
        Point("p3", "input_registers", 1, "uint16"),
    ]
    with pytest.raises(ConfigError, match=r"'p2'.*'p3'.*overlap"):
        RegisterMap(points)
    # the same address in different tables is fine
    RegisterMap(
        [Point("a", "input_registers", 0, "uint16"), Point("b", "holding_registers", 0, "uint16")]
    )


def test_map_refuses_missing_required_points():
    with pytest.raises(ConfigError, match=r"missing required point\(s\) \['estop_ok'\]"):
        RegisterMap(
            [Point("enabling", "discrete_inputs", 0, "bool")], required=["enabling", "estop_ok"]
        )


def sim_cell() -> dict:
    return tomllib.loads(sim_modbus_section_toml(port=5020))


def test_driver_config_refuses_unknown_type_from_toml():
    cell = sim_cell()
    cell["modbus"]["points"][0]["type"] = "float64"
    with pytest.raises(ConfigError, match=r"point 'p2_bar'\.type: 'float64'"):
        ModbusDriverConfig.from_cell_config(cell, "cell.toml")


def test_driver_config_refuses_bad_fields():
    cell = sim_cell()
    cell["modbus"]["port"] = 0
    with pytest.raises(ConfigError, match=r"\[modbus\]\.port: 0"):
        ModbusDriverConfig.from_cell_config(cell)
    cell = sim_cell()
    cell["modbus"]["points"][1]["sclae"] = 0.001
    with pytest.raises(ConfigError, match="sclae"):
        ModbusDriverConfig.from_cell_config(cell)
    with pytest.raises(ConfigError, match="timeout_s"):
        from_mapping(ModbusDriverConfig, {"host": "h", "port": 502, "timeout_s": -1.0}, "[modbus]")
    with pytest.raises(ConfigError, match="no \\[modbus\\] section"):
        ModbusDriverConfig.from_cell_config({}, "cell.toml")


def test_adapter_refuses_missing_required_point():
    cell = sim_cell()
    cell["modbus"]["points"] = [p for p in cell["modbus"]["points"] if p["name"] != "estop_ok"]
    config = ModbusDriverConfig.from_cell_config(cell)
    with pytest.raises(ConfigError, match="estop_ok"):
        RegisterMapAdapter(config)


def test_adapter_refuses_read_only_setpoint_point():
    cell = sim_cell()
    for p in cell["modbus"]["points"]:
        if p["name"] == "p3_set_bar":
            p["table"] = "input_registers"
            p["address"] = 10
    with pytest.raises(ConfigError, match="'p3_set_bar' must be a numeric point in holding"):
        RegisterMapAdapter(ModbusDriverConfig.from_cell_config(cell))


def test_unknown_adapter_name_lists_available_ones():
    assert "register_map" in available_adapters()
    assert adapter_class("register_map") is RegisterMapAdapter
    with pytest.raises(ConfigError, match=r"unknown adapter 'acme'.*'register_map'"):
        adapter_class("acme")


# The virtual module's map and request grouping ------------------------------------------------


def test_sim_points_build_a_valid_adapter_without_connecting():
    config = ModbusDriverConfig.from_cell_config(sim_cell())
    adapter = create_adapter(config)
    assert isinstance(adapter, RegisterMapAdapter)
    assert [(g.table, g.address, g.count) for g in adapter.map.read_groups] == [
        ("input_registers", 0, 3),
        ("holding_registers", 0, 4),
        ("discrete_inputs", 0, 3),
    ]
    assert "[[modbus.points]]" in sim_register_points_toml()


def test_groups_merge_only_touching_points_and_respect_the_request_limit():
    points = [
        Point("a", "input_registers", 0, "float32"),
        Point("b", "input_registers", 2, "uint16"),
        Point("c", "input_registers", 4, "uint16"),  # gap at 3: new request
        *(Point(f"r{i}", "holding_registers", i, "uint16") for i in range(130)),
    ]
    groups = RegisterMap(points).read_groups
    assert [(g.table, g.address, g.count) for g in groups] == [
        ("input_registers", 0, 3),
        ("input_registers", 4, 1),
        ("holding_registers", 0, 125),
        ("holding_registers", 125, 5),
    ]


class FakeLink:
    """Answers reads from fixed tables and records every request."""

    def __init__(self, tables: dict[str, dict[int, int | bool]]) -> None:
        self.tables = tables
        self.calls: list[tuple] = []

    def _read(self, table: str, address: int, count: int) -> list:
        self.calls.append((table, address, count))
        return [self.tables[table][a] for a in range(address, address + count)]

    def read_input_registers(self, address, count):
        return self._read("input_registers", address, count)

    def read_holding_registers(self, address, count):
        return self._read("holding_registers", address, count)

    def read_discrete_inputs(self, address, count):
        return self._read("discrete_inputs", address, count)

    def read_coils(self, address, count):
        return self._read("coils", address, count)

    def write_registers(self, address, values):
        self.calls.append(("write_registers", address, list(values)))

    def write_coil(self, address, value):
        self.calls.append(("write_coil", address, value))


def test_adapter_reads_with_one_request_per_group_and_writes_setpoints_together():
    link = FakeLink(
        {
            "input_registers": {0: 0x4020, 1: 0x0000, 2: 3250},  # 2.5 bar, 3250 mbar
            "holding_registers": {0: 4200, 1: 0, 2: 5125, 3: 0},  # CDAB int32 mbar
            "discrete_inputs": {0: True, 1: False, 2: True},
        }
    )
    adapter = RegisterMapAdapter(ModbusDriverConfig.from_cell_config(sim_cell()), link=link)
    reading = adapter.read()
    assert reading.p2_bar == 2.5
    assert reading.p3_bar == pytest.approx(3.25)
    assert (reading.p2_set_bar, reading.p3_set_bar) == pytest.approx((4.2, 5.125))
    assert (reading.enabling, reading.estop_ok, reading.mark) == (True, False, True)
    assert len(link.calls) == 3

    link.calls.clear()
    adapter.write_setpoints(1.0, 7.0)
    assert link.calls == [("write_registers", 0, [1000, 0, 7000, 0])]

    link.calls.clear()
    with pytest.raises(ValueError, match="p3_set_bar"):
        adapter.write_setpoints(1.0, 13.0)  # above the point's max: nothing written
    assert link.calls == []


def test_the_mark_button_is_optional_and_must_be_a_bool():
    cell = sim_cell()
    cell["modbus"]["points"] = [p for p in cell["modbus"]["points"] if p["name"] != "mark"]
    link = FakeLink(
        {
            "input_registers": {0: 0x4020, 1: 0x0000, 2: 3250},
            "holding_registers": {0: 4200, 1: 0, 2: 5125, 3: 0},
            "discrete_inputs": {0: True, 1: True},
        }
    )
    adapter = RegisterMapAdapter(ModbusDriverConfig.from_cell_config(cell), link=link)
    assert adapter.read().mark is False
    cell["modbus"]["points"].append(
        {"name": "mark", "table": "input_registers", "address": 7, "type": "uint16"}
    )
    with pytest.raises(ConfigError, match="'mark' must have type 'bool'"):
        RegisterMapAdapter(ModbusDriverConfig.from_cell_config(cell), link=link)
