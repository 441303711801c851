"""An example commissioned cell for the tests below the whole stack: the virtual cell's config
(deploy/config/sim_cell.toml) with ``[control] model`` set to :data:`EXAMPLE_MODEL` and ω / Υ_I
of round, made-up sizes, as if `leadthrough identify` had written them. None of it is a plant's
truth; the whole-stack tests teach with what identification measured on their plant."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import tomli_w

from control.cell_config import load_control_config
from control.config import ControlConfig
from gateway.config import load_toml
from sim_bridge.harness import SIM_CELL

EXAMPLE_MODEL = Path(__file__).with_name("data") / "example_model.toml"
#: ω = 1/(K K_p) [rad/s per N·m] and Υ_I = K_I/K_p [1/s] of an example drive set
EXAMPLE_OMEGA = [1e-4, 5e-5, 1e-4, 5e-3, 1e-2, 3e-2]
EXAMPLE_UPSILON = [30.0] * 6
#: the admittance law alone, for tests whose fake drives carry the model's torque only: engaged
#: on the first state, no engagement probe (b is the residual at rest), no stick zone, no
#: start-up dither
ADMITTANCE_ALONE = {"strategy": "admittance", "engage_rest_states": 0,
                    "admittance_probe_speed_rad_s": 0.0, "admittance_stick_zone": 0.0,
                    "admittance_dither": 0.0}  # fmt: skip


def example_cell(folder: Path, **control: object) -> Path:
    """Write ``folder/cell.toml``: the virtual cell's config, commissioned with the example
    model and gains (``control`` overrides keys of ``[control]``); returns its path."""
    raw = load_toml(SIM_CELL)
    example = {
        "model": str(EXAMPLE_MODEL),
        "omega_rad_s_per_nm": EXAMPLE_OMEGA,
        "upsilon_i_per_s": EXAMPLE_UPSILON,
    }
    raw["control"].update({**example, **control})
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / "cell.toml"
    path.write_text(tomli_w.dumps(raw))
    return path


def example_control(folder: Path, **settings: object) -> ControlConfig:
    """The ``[control]`` config of :func:`example_cell` written into ``folder``, with
    ``settings`` replacing its fields (checked as the config's own are)."""
    return dataclasses.replace(load_control_config(example_cell(folder))[0], **settings)
