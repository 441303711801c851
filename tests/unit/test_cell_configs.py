"""The shipped configs load and validate, and the simulator's truth stays private."""

import json
from pathlib import Path

import pytest
import tomli_w
from example_cell import EXAMPLE_MODEL

from control.cell_config import load_control_config
from control.process import ControlProcess
from drivers.can.config import load_can_config
from drivers.modbus.config import ModbusDriverConfig
from gateway.bus import BusConfig
from gateway.config import load_toml
from gateway.errors import ConfigError
from gateway.gateway_config import load_gateway_config
from sim_bridge.config import load_sim_config

REPO = Path(__file__).resolve().parents[2]
CELLS = [REPO / "deploy" / "config" / "cell.toml", REPO / "deploy" / "config" / "sim_cell.toml"]


@pytest.mark.parametrize("cell", CELLS, ids=lambda p: p.name)
def test_every_section_of_the_cell_configs_validates(cell):
    _ctl, bus = load_control_config(cell)
    can_cfg, _ = load_can_config(cell)
    assert can_cfg.joints == 6
    ModbusDriverConfig.from_cell_config(load_toml(cell), str(cell))
    load_gateway_config(cell)
    assert bus.endpoint.startswith("tcp/")


def test_production_and_virtual_cells_differ_only_in_transport():
    """... and where the taught programs and the adapted payload go (the cell PC's state
    folder, beside the virtual cell's config)."""
    prod, sim = (load_toml(p) for p in CELLS)
    kept = "model_adaptation_file"
    assert prod["control"].pop(kept) == "/var/lib/leadthrough/commissioning/adapted_payload.json"
    assert sim["control"].pop(kept) == "adapted_payload.json"
    assert prod["control"] == sim["control"]
    assert prod["gateway"].pop("program_dir") == "/var/lib/leadthrough/programs"
    assert sim["gateway"].pop("program_dir") == "programs"
    assert prod["gateway"] == sim["gateway"]
    assert prod["modbus"]["points"] == sim["modbus"]["points"]
    assert {k: v for k, v in prod["can"].items() if k != "transport"} == {
        k: v for k, v in sim["can"].items() if k != "transport"
    }
    assert prod["can"]["transport"]["interface"] == "socketcan"


def test_bad_cell_config_names_the_field(tmp_path):
    raw = load_toml(CELLS[1])
    raw["control"]["friction_compensation"] = 1.7
    path = tmp_path / "cell.toml"
    path.write_text(tomli_w.dumps(raw))
    with pytest.raises(ConfigError, match="friction_compensation"):
        load_control_config(path)
    raw["control"]["friction_compensation"] = 1.0
    raw["control"]["omega_rad_s_per_nm"] = [1.0, 2.0]
    raw["control"]["upsilon_i_per_s"] = [1.0, 2.0]
    path.write_text(tomli_w.dumps(raw))
    with pytest.raises(ConfigError, match="needs 6 values"):
        load_control_config(path)


def test_unknown_key_is_refused(tmp_path):
    raw = load_toml(CELLS[1])
    raw["gateway"]["joint_state_timout_s"] = 0.1  # typo
    path = tmp_path / "cell.toml"
    path.write_text(tomli_w.dumps(raw))
    with pytest.raises(ConfigError, match="joint_state_timout_s"):
        load_gateway_config(path)


def test_a_section_nobody_reads_is_refused_by_every_process(tmp_path):
    raw = load_toml(CELLS[1])
    raw["contorl"] = raw.pop("control")  # typo: its settings would quietly do nothing
    path = tmp_path / "cell.toml"
    path.write_text(tomli_w.dumps(raw))

    def modbus(p: Path) -> ModbusDriverConfig:
        return ModbusDriverConfig.from_cell_config(load_toml(p), str(p))

    for load in (load_gateway_config, load_control_config, load_can_config, modbus):
        with pytest.raises(ConfigError, match=r"unknown section\(s\) \['contorl'\]"):
            load(path)


def test_sim_truth_loads_and_is_read_only_by_sim_bridge():
    cfg = load_sim_config()
    assert len(cfg.inner_loop.kp_a_s_per_rad) == 6
    # The inner-loop gains are the vendor's secret: no product code may read the truth file.
    for pkg in ("control", "drivers", "gateway"):
        for py in (REPO / pkg).rglob("*.py"):
            text = py.read_text()
            assert "gr630st_truth" not in text, f"{py} refers to the simulator's truth"
            assert "sim_bridge.config" not in text, f"{py} imports the simulator's config"
            assert "ki_a_per_rad" not in text, f"{py} mentions the inner-loop gains"


def _cell_with_inner_loop(tmp_path, estimate: object, keep_lists: bool = False) -> Path:
    raw = load_toml(CELLS[1])
    if keep_lists:
        raw["control"].update(omega_rad_s_per_nm=[1.0] * 6, upsilon_i_per_s=[1.0] * 6)
    raw["control"]["model"] = str(EXAMPLE_MODEL)
    raw["control"]["inner_loop"] = "ident/inner_loop.json"
    (tmp_path / "ident").mkdir(exist_ok=True)
    (tmp_path / "ident" / "inner_loop.json").write_text(json.dumps(estimate))
    path = tmp_path / "cell.toml"
    path.write_text(tomli_w.dumps(raw))
    return path


def test_the_outer_loop_gains_can_come_from_the_identified_inner_loop(tmp_path):
    omega = [1e-4, 5e-5, 1e-4, 7e-3, 9e-3, 3e-2]
    upsilon = [30.0, 31.0, 32.0, 33.0, 34.0, 35.0]
    path = _cell_with_inner_loop(
        tmp_path, {"omega_rad_s_per_nm": omega, "upsilon_i_per_s": upsilon}
    )
    cfg, _bus = load_control_config(path)
    assert list(cfg.omega_rad_s_per_nm) == omega and list(cfg.upsilon_i_per_s) == upsilon
    assert cfg.inner_loop == tmp_path / "ident" / "inner_loop.json"


@pytest.mark.parametrize(
    ("estimate", "keep_lists", "match"),
    [
        ({"omega_rad_s_per_nm": [1.0] * 6, "upsilon_i_per_s": [1.0] * 6}, True, "not both"),
        ({"omega_rad_s_per_nm": [1.0] * 5, "upsilon_i_per_s": [1.0] * 6}, False, "6 values"),
        ({"omega_rad_s_per_nm": [1.0] * 6, "upsilon_i_per_s": [1.0] * 5 + [-1]}, False, "> 0"),
        ({"omega_rad_s_per_nm": [1.0] * 6}, False, "upsilon_i_per_s"),
        ([1, 2], False, "omega_rad_s_per_nm"),
    ],
)
def test_a_bad_inner_loop_estimate_names_the_file_and_the_key(
    tmp_path, estimate, keep_lists, match
):
    path = _cell_with_inner_loop(tmp_path, estimate, keep_lists)
    with pytest.raises(ConfigError, match=match):
        load_control_config(path)


def test_a_shipped_cell_is_not_commissioned_and_says_what_to_run(tmp_path):
    """The shipped configs carry no model and no loop gains (nothing of any robot's truth):
    the control process starts, identifies, and refuses teaching through its load check."""
    for cell in CELLS:
        cfg, _ = load_control_config(cell)
        assert cfg.model is None and cfg.omega_rad_s_per_nm == ()
        assert "leadthrough identify" in (cfg.uncommissioned or "")
    cfg, _ = load_control_config(CELLS[1])
    proc = ControlProcess(cfg, BusConfig(endpoint="tcp/127.0.0.1:1"))
    assert proc.ctl is None and proc.n == 6


@pytest.mark.parametrize(
    ("control", "match"),
    [
        ({"omega_rad_s_per_nm": [1.0] * 6}, "both or neither"),
        ({"upsilon_i_per_s": [1.0] * 6}, "both or neither"),
        ({"omega_rad_s_per_nm": [1.0] * 6, "upsilon_i_per_s": [1.0] * 6}, None),
    ],
)
def test_half_a_commissioning_is_refused_or_named(tmp_path, control, match):
    raw = load_toml(CELLS[1])
    raw["control"].update(control)
    path = tmp_path / "cell.toml"
    path.write_text(tomli_w.dumps(raw))
    if match:
        with pytest.raises(ConfigError, match=match):
            load_control_config(path)
        return
    cfg, _ = load_control_config(path)  # gains without a model: still not commissioned
    assert cfg.uncommissioned is not None and "model" in cfg.uncommissioned


def test_inner_loop_without_max_offset_names_the_missing_key(tmp_path):
    path = _cell_with_inner_loop(
        tmp_path, {"omega_rad_s_per_nm": [1.0] * 6, "upsilon_i_per_s": [1.0] * 6}
    )
    raw = load_toml(path)
    del raw["control"]["max_offset_rad"]
    path.write_text(tomli_w.dumps(raw))
    with pytest.raises(ConfigError, match="max_offset_rad"):
        load_control_config(path)


def test_the_production_bus_is_locked_and_the_install_script_knows_every_identity():
    """The cell PC's bus needs credentials (gateway/bus_security.py); the virtual cell's is
    open. deploy/install.sh writes a password for each identity the access list names."""
    import re

    from gateway.bus import bus_config_from
    from gateway.bus_security import IDENTITIES

    prod, sim = (bus_config_from(load_toml(p), str(p)) for p in CELLS)
    assert prod.locked and prod.credentials_file == "/etc/leadthrough/bus.credentials"
    assert not sim.locked
    script = (REPO / "deploy" / "install.sh").read_text()
    listed = re.search(r'^IDENTITIES="([^"]*)"', script, re.MULTILINE)
    assert listed is not None and tuple(listed.group(1).split()) == IDENTITIES
