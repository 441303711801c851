"""The registry of cell-config sections (gateway/cell_section.py): pyproject.toml's entry points
``leadthrough.cell_sections``, from which the config check, its JSON Schema, the gateway's
check at start and the refusal of an unknown section all come."""

from __future__ import annotations

import re
import tomllib
from importlib.metadata import EntryPoint
from pathlib import Path

import pytest
import tomli_w

from gateway.cell_section import GROUP, cell_sections, section_names
from gateway.cli import main
from gateway.config import load_toml
from gateway.config_check import check_cell, gateway_start_sections
from gateway.errors import ConfigError

REPO = Path(__file__).resolve().parents[2]
SHIPPED = sorted((REPO / "deploy" / "config").glob("*.toml"))
SIM_CELL = REPO / "deploy" / "config" / "sim_cell.toml"
#: a table the shipped config offers commented out (cell.toml: "Uncomment to set ...")
_OFFERED = re.compile(r"^#\s*\[(\w+)\]\s*$", re.MULTILINE)


def test_the_registry_lists_exactly_the_sections_the_shipped_configs_use_or_offer():
    used = set()
    for path in SHIPPED:
        text = path.read_text()
        used |= set(tomllib.loads(text)) | set(_OFFERED.findall(text))
    assert len(SHIPPED) == 3 and "ros2" in used  # [ros2]: offered in cell.toml, commented out
    assert sorted(section_names()) == sorted(used)
    assert [s.name for s in cell_sections()] and {s.name for s in cell_sections()} == used


def test_the_check_reports_the_sections_in_their_order_whatever_order_pip_installed_them():
    # entry_points.txt lists a group sorted by name; the report kept its order before the registry
    assert list(check_cell(SIM_CELL)) == [
        "bus", "gateway", "can", "modbus", "control", "realtime", "ros2"
    ]  # fmt: skip
    assert gateway_start_sections() == ("can", "modbus", "realtime")


@pytest.mark.parametrize("section", cell_sections(), ids=lambda s: s.name)
def test_every_sections_loader_reads_the_shipped_configs_into_its_config_class(section):
    for path in SHIPPED:
        loaded = section.loader(path, load_toml(path))
        config = loaded[0] if isinstance(loaded, tuple) else loaded  # some hand [bus] back too
        assert isinstance(config, section.config_class), (path.name, type(config))


@pytest.mark.parametrize("section", cell_sections(), ids=lambda s: s.name)
def test_every_sections_loader_refuses_a_bad_key_naming_file_section_and_key(section, tmp_path):
    raw = load_toml(SIM_CELL)
    raw.setdefault(section.name, {})["no_such_key"] = 1
    path = tmp_path / "cell.toml"
    path.write_text(tomli_w.dumps(raw))
    with pytest.raises(ConfigError) as refused:
        section.loader(path, load_toml(path))
    message = str(refused.value)
    assert str(path) in message and f"[{section.name}]" in message, message
    assert "no_such_key" in message, message


def _entry(name: str, value: str) -> EntryPoint:
    return EntryPoint(name=name, value=value, group=GROUP)


@pytest.mark.parametrize(
    ("name", "value", "why"),
    [
        ("can", "drivers.can.no_such_module:CELL_SECTION", "ModuleNotFoundError"),
        ("can", "drivers.can.config:NO_SUCH_SECTION", "cannot be loaded"),
        ("can", "drivers.can.config:CanDriverConfig", "not a CellSection"),
        ("modbus", "drivers.can.config:CELL_SECTION", "declares the section [can]"),
    ],
)
def test_a_broken_entry_point_is_a_config_error_naming_it(name, value, why):
    with pytest.raises(ConfigError) as refused:
        cell_sections([_entry("bus", "gateway.bus:CELL_SECTION"), _entry(name, value)])
    message = str(refused.value)
    assert f"{name} = {value!r}" in message and GROUP in message and why in message, message


def test_a_section_registered_twice_or_none_registered_is_a_config_error():
    twice = [_entry("bus", "gateway.bus:CELL_SECTION")] * 2
    with pytest.raises(ConfigError, match=r"\[bus\] is registered twice"):
        cell_sections(twice)
    for read in (cell_sections, section_names):
        with pytest.raises(ConfigError, match="not installed"):
            read([])


def test_sections_come_by_their_own_order_not_the_entry_points():
    found = [_entry(n, f"gateway.{m}:CELL_SECTION") for n, m in (("ros2", "ros2"), ("bus", "bus"))]
    found.insert(1, _entry("realtime", "gateway.realtime:CELL_SECTION"))
    assert [s.name for s in cell_sections(found)] == ["bus", "realtime", "ros2"]
    assert section_names(found) == ("ros2", "realtime", "bus")  # names only: no order to read


def _install_broken_section(site: Path, monkeypatch: pytest.MonkeyPatch) -> str:
    """A second distribution on sys.path that registers a section whose module is missing."""
    info = site / "broken_cell_section-0.dist-info"
    info.mkdir()
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: broken-cell-section\nVersion: 0\n")
    value = "no_such_package.config:CELL_SECTION"
    (info / "entry_points.txt").write_text(f"[{GROUP}]\npaint = {value}\n")
    monkeypatch.syspath_prepend(str(site))
    return value


def test_the_config_commands_name_a_broken_entry_point_in_one_line(tmp_path, monkeypatch, capsys):
    value = _install_broken_section(tmp_path, monkeypatch)
    assert "paint" in section_names()
    assert main(["config", "check", str(SIM_CELL)]) == 78
    assert main(["config", "schema"]) == 78
    captured = capsys.readouterr()
    lines = captured.err.strip().splitlines()
    assert captured.out == "" and len(lines) == 2, captured.err  # one line each, no traceback
    for line in lines:
        assert line.startswith("leadthrough config: configuration refused: "), line
        assert f"paint = {value!r}" in line and "ModuleNotFoundError" in line, line


def test_the_gateway_refuses_to_start_on_a_broken_entry_point_naming_it(
    tmp_path, monkeypatch, caplog
):
    import argparse
    import logging

    from gateway.supervisor import cli_main

    value = _install_broken_section(tmp_path, monkeypatch)
    args = argparse.Namespace(config=SIM_CELL, bus=None, no_spawn=False)
    with caplog.at_level(logging.ERROR):
        assert cli_main(args) == 78  # before any zenoh session or child process
    assert any(f"paint = {value!r}" in r.getMessage() for r in caplog.records), caplog.text


def test_a_section_is_known_to_every_process_once_registered(tmp_path, monkeypatch):
    from gateway.bus import check_cell_sections

    with pytest.raises(ConfigError, match=r"unknown section\(s\) \['paint'\]: .*'\[ros2\]'"):
        check_cell_sections({"paint": {}}, "cell.toml")
    _install_broken_section(tmp_path, monkeypatch)
    check_cell_sections({"paint": {}}, "cell.toml")  # its name is enough: nothing is imported


def test_the_configuration_doc_says_where_each_registered_section_is_described():
    text = (REPO / "docs" / "configuration.md").read_text()
    assert [name for name in section_names() if f"`[{name}]`" not in text] == []
