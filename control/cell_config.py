"""The control process's settings from the cell config: :func:`load_control_config` reads
``[control]`` (control/config.py) and ``[bus]``, with ω and Υ_I from the ``inner_loop``
estimate (`leadthrough identify`) where ``[control]`` names one.
"""

from __future__ import annotations

from pathlib import Path

from control.config import ControlConfig
from control.identification.inner_loop import read_outer_loop_gains
from gateway.bus import BusConfig, bus_config_from
from gateway.cell_section import CellSection
from gateway.config import from_mapping, load_toml, resolve_path
from gateway.errors import ConfigError


def load_control_config(cell_path: str | Path) -> tuple[ControlConfig, BusConfig]:
    """The cell config's ``[control]`` and ``[bus]``. With ``[control].inner_loop``, ω and Υ_I
    come from that estimate (`leadthrough identify`) and may not also be written out."""
    raw = load_toml(cell_path)
    bus = bus_config_from(raw, str(cell_path))  # first: it refuses an unknown section
    section = dict(raw.get("control", {}))
    where = f"{cell_path} [control]"
    if section.get("inner_loop"):
        written = [k for k in ("omega_rad_s_per_nm", "upsilon_i_per_s") if k in section]
        if written:
            raise ConfigError(f"{where}: give {written} or inner_loop, not both")
        source = resolve_path(cell_path, section["inner_loop"])
        if "max_offset_rad" in section:  # else from_mapping names the missing key
            n = len(section["max_offset_rad"])
            omega, upsilon, delay = read_outer_loop_gains(source, n)
            section.update(omega_rad_s_per_nm=omega, upsilon_i_per_s=upsilon)
            if "command_delay_cycles" not in section:
                section["command_delay_cycles"] = delay
        section["inner_loop"] = str(source)
    cfg = from_mapping(ControlConfig, section, where)
    for key in ("model", "model_adaptation_file"):
        if getattr(cfg, key) is not None:
            cfg = ControlConfig(**{**cfg.__dict__, key: resolve_path(cell_path, getattr(cfg, key))})
    return cfg, bus


#: the ``[control]`` section of the cell config, registered in pyproject.toml (checked by the
#: control process when it starts, not by the gateway)
CELL_SECTION = CellSection(
    "control", lambda path, raw: load_control_config(path), ControlConfig, order=5
)
