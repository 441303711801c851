"""Static-load check: does the model carry what the arm carries, before it is made weightless?

A zero-moment controller makes the arm weigh exactly what the model says. If the arm carries a
load the model lacks (a spray gun mounted after the model was made, a wrong model file, wrong
cylinder pressures), teaching would let the difference fall: on the virtual cell an 8 kg gun the
declared model did not know dropped the tool 1.6 m in 2 s before the controller faulted.

The check needs no motion. At rest with servo power on, the vendor loop holds the arm, so the
motor torque K·i is the static load g(q) − T_cyl(q, p) up to the joint's static friction, which
may take any value up to its breakaway torque. A joint whose measured torque differs from the
model's by more than that breakaway (the model's friction just off zero speed) plus a configured
margin fails the check, and the gateway does not start teaching (identification, which only
plays position commands, stays allowed: it is how the model gets fixed).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from control.declared_model import DeclaredModel

#: Speeds at which the model's friction is evaluated to find its breakaway torque [rad/s].
BREAKAWAY_SPEEDS_RAD_S = (0.002, 0.005, 0.01, 0.02, 0.05)
#: Only a joint state slower than this counts as "at rest" for the check [rad/s].
REST_RAD_S = 2e-3


@dataclass(frozen=True)
class LoadCheck:
    """Verdict of one check; joint values per joint [N·m], ``joint`` the worst (1-based)."""

    ok: bool
    joint: int
    measured_nm: tuple[float, ...]
    model_nm: tuple[float, ...]
    tolerance_nm: tuple[float, ...]
    message: str

    def to_json(self) -> dict[str, Any]:
        return {
            "ok": self.ok,
            "joint": self.joint,
            "measured_nm": [round(v, 2) for v in self.measured_nm],
            "model_nm": [round(v, 2) for v in self.model_nm],
            "tolerance_nm": [round(v, 2) for v in self.tolerance_nm],
            "message": self.message,
        }


def friction_levels_nm(
    model: DeclaredModel, q_rad: np.ndarray, speeds_rad_s: Sequence[float]
) -> np.ndarray:
    """Largest |friction| of the model at ``q_rad`` over ``±speeds_rad_s``, per joint [N·m];
    NaN everywhere where the model is undefined. In the model's per-cycle form
    (``cycle_torques_nm``: 0.08 ms a speed on an identified model, where ``friction_nm`` took
    1.1 ms): it runs in the control process's cycle callback, at every engagement and every
    static-load check."""
    n = model.n
    pressures = model.desc.nominal_pressures_bar.tolist()  # only the static part sees them
    out = np.zeros(n)
    for v in speeds_rad_s:
        for sign in (1.0, -1.0):
            try:
                _, friction = model.cycle_torques_nm(q_rad, [sign * v] * n, pressures)
            except (ValueError, ArithmeticError):
                return np.full(n, np.nan)
            out = np.maximum(out, np.abs(friction))
    return out


def breakaway_nm(model: DeclaredModel, q_rad: np.ndarray) -> np.ndarray:
    """Largest |friction| of the model just off zero speed, per joint [N·m]."""
    return friction_levels_nm(model, q_rad, BREAKAWAY_SPEEDS_RAD_S)


def static_load_check(
    model: DeclaredModel,
    q_rad: np.ndarray,
    current_a: np.ndarray,
    p_bar: np.ndarray,
    margin_nm: Sequence[float],
) -> LoadCheck:
    """Compare the held arm's motor torque with the model's static load (module docstring)."""
    measured = model.motor_torque_nm(current_a)
    try:  # g(q) - T_cyl(q, p), in the per-cycle form (friction_levels_nm)
        static, _ = model.cycle_torques_nm(q_rad, [0.0] * model.n, np.asarray(p_bar).tolist())
        expected = np.array(static)
    except (ValueError, ArithmeticError):
        expected = np.full(model.n, np.nan)
    margin = np.asarray(margin_nm, dtype=float) if len(margin_nm) else np.zeros(model.n)
    tolerance = breakaway_nm(model, q_rad) + margin
    excess = np.abs(measured - expected) - tolerance
    if not np.all(np.isfinite(excess)):
        j = int(np.flatnonzero(~np.isfinite(excess))[0])
        return LoadCheck(False, j + 1, tuple(measured), tuple(expected), tuple(tolerance),
                         f"joint {j + 1}: static-load check got a non-finite value")  # fmt: skip
    j = int(np.argmax(excess))
    ok = bool(excess[j] <= 0.0)
    if ok:
        message = "the arm's static load matches the model"
    else:
        message = (
            f"joint {j + 1} holds {measured[j]:.1f} N·m at rest but the model expects "
            f"{expected[j]:.1f} N·m (± {tolerance[j]:.1f} N·m of friction and margin): the arm "
            f"carries a load the model lacks (a tool or payload?); identify it "
            f"(`leadthrough identify`) or correct the model before teaching"
        )
    return LoadCheck(ok, j + 1, tuple(measured), tuple(expected), tuple(tolerance), message)
