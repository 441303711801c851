"""The assist cylinders' force, measured: one scale per cylinder, fitted with the arm.

The analysis adds the description's cylinder torque ``T_k(q, p)`` (eqs. 10/12 from the
measured pressures, :func:`.fit.remove_cylinders`) to the motor torque and fits the arm without
cylinders. The description's cylinder is a datasheet's: a bore, a linkage (the GR630ST's J3
piston diameter is an assumption) and the drive's torque constant that turns its current into
the torque it balances are each a few percent off, and the error ``(1 - s_k) T_k`` is a torque
proportional to the pressure with the linkage's shape in the joint angle. The rigid-body model
has no column of that shape (J3's lever acts as ``cos q3``, the arm's gravity on J3 as
``cos(q2 + q3)``, ``sin(q2 + q3)``), so it stays in the residual; on a drawn plant whose
cylinders were 10–20 % stronger than described it was about twice the noise floor on J2 and
J3 while the fitted friction bent to stand in for it.

Its column is the description's own torque ``T_k`` on the cylinder's joint: fitted jointly with
rigid body and friction (the friction family's search included), coefficient ``b_k``, the
cylinder acts with ``s_k = 1 - b_k`` times the described torque. Each cylinder's scale is kept
only when

- it lowers the held-out (contiguous K-fold) error of its joint on the training files: where
  the joint's range is narrow the cylinder's column is nearly the arm's own gravity on it, the
  fit may split the two anyhow, and a split that does worse on the blocks it did not see is
  not a measurement; and
- its ``s_k`` lies within :data:`SCALE_RANGE`: the scale carries the bore's area, the
  linkage and the torque constant, each a tolerance; a cylinder twice or half as strong as
  described is a wrong description, which the report names instead of fitting around it.

Kept, the cylinder's piston diameter becomes ``d_k sqrt(s_k)`` (the torque is proportional to
the piston's area, so this scales it by ``s_k`` at every angle and pressure): the model file
carries those diameters, and the control process's cylinder torque, pressure schedule and
model adaptation use them (:func:`control.model.cylinders.with_measured_cylinders`).
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from gateway.robot.description import RobotDescription

#: The fit's group of cylinder columns (:class:`.lsq.BlockLS`), those of
#: :func:`.fit.cylinder_columns`.
GROUP = "cylinders"
#: Plausible force scales of a described cylinder (module docstring).
SCALE_RANGE = (0.5, 2.0)


def contribution(cols: dict[int, np.ndarray], coef: np.ndarray, n: int) -> np.ndarray:
    """``Σ_k b_k T_k`` per joint, (T, n) [N·m]: what the coefficients ``coef`` (c,) of the
    :data:`GROUP` columns ``cols`` predict."""
    rows = next(iter(cols.values())).shape[0]
    out = np.zeros((rows, n))
    for j, c in cols.items():
        out[:, j] = c @ coef
    return out


@dataclass(frozen=True)
class Calibration:
    """The outcome for each described cylinder (the description's order): its joint (0-based),
    fitted force scale (1: as described), the description's piston diameter [m], whether the
    model uses the scale and why (module docstring), and the held-out RMS per joint on the
    training files with and without the cylinder columns."""

    joints: tuple[int, ...]
    scale: tuple[float, ...]
    nominal_diameter_m: tuple[float, ...]
    kept: tuple[bool, ...]
    reasons: tuple[str, ...]
    heldout_rms_nm: dict[str, list[float]]

    @property
    def coef(self) -> np.ndarray:
        """The :data:`GROUP` coefficients the target is corrected by (zero where not kept)."""
        return np.array([1.0 - s if k else 0.0 for s, k in zip(self.scale, self.kept, strict=True)])

    @property
    def any_kept(self) -> bool:
        return any(self.kept)

    def over_gain(self, gain: np.ndarray) -> Calibration:
        """The calibration in physical units under a torque channel that reads ``gain`` ×
        the motor torque (:mod:`.chain`, per joint).

        The scale was fitted on the channel's reading (the target is reading + scale ×
        described torque), but the channel's gain multiplies the whole motor torque, the
        cylinders' share included: reading = gain × (rigid − cylinder). The cylinder's
        physical torque is therefore scale / gain × the described one (1 / gain for a cylinder
        left as described): a model whose control reads the drives through the chain
        (``DeclaredModel.torque_per_amp_nm``) and adds the cylinder at its channel scale was
        off by (1 − 1 / gain) × its torque (plant seed 1: gain 0.92, 10 and 21 N·m on J2, J3
        in the replay's residual). Joints whose gain is 1 keep their entry as it is."""
        g = np.asarray(gain, dtype=float)
        scale, kept, reasons = [], [], []
        for j, s, k, why in zip(self.joints, self.scale, self.kept, self.reasons, strict=True):
            if g[j] == 1.0:
                scale.append(s)
                kept.append(k)
                reasons.append(why)
                continue
            scale.append((s if k else 1.0) / float(g[j]))
            kept.append(True)
            reasons.append(f"{why}; over the torque channel's gain {g[j]:.4g} on J{j + 1}")
        return replace(self, scale=tuple(scale), kept=tuple(kept), reasons=tuple(reasons))

    def diameters_m(self) -> list[float]:
        """The piston diameter [m] of each cylinder in the model."""
        return [
            d * float(np.sqrt(s)) if k else d
            for s, d, k in zip(self.scale, self.nominal_diameter_m, self.kept, strict=True)
        ]

    def to_json(self) -> dict[str, Any]:
        return {
            "heldout_rms_training_folds_nm": self.heldout_rms_nm,
            "cylinders": [
                {
                    "joint_index": j,
                    "torque_scale": s,
                    "kept": k,
                    "reason": why,
                    "described_piston_diameter_m": d,
                    "piston_diameter_m": dm,
                }
                for j, s, d, k, why, dm in zip(
                    self.joints,
                    self.scale,
                    self.nominal_diameter_m,
                    self.kept,
                    self.reasons,
                    self.diameters_m(),
                    strict=True,
                )
            ],
        }


def judge(
    desc: RobotDescription,
    coef: np.ndarray,
    cv_rms_with: np.ndarray,
    cv_rms_without: np.ndarray,
) -> Calibration:
    """The :class:`Calibration` of the fitted coefficients ``coef`` (c,) (cylinders in the
    description's order), given the held-out RMS per joint on the training files with and
    without the cylinder columns: each cylinder on its own joint's figures (module
    docstring)."""
    lo, hi = SCALE_RANGE
    joints, scale, diam, kept, reasons = [], [], [], [], []
    for spec, b in zip(desc.cylinders, coef, strict=True):
        j, s = spec.joint_index, float(1.0 - b)
        with_rms, without_rms = float(cv_rms_with[j]), float(cv_rms_without[j])
        ok = False
        if not (np.isfinite(s) and lo <= s <= hi):
            why = (
                f"force scale {s:.3g} outside the plausible [{lo:g}, {hi:g}]: the described "
                "cylinder is wrong (bore, linkage or sign), not off by a tolerance; as described"
            )
        elif not with_rms < without_rms:
            why = (
                f"does not lower J{j + 1}'s held-out error on the training files "
                f"({without_rms:.4g} -> {with_rms:.4g} N·m); as described"
            )
        else:
            ok = True
            why = (
                f"lowers J{j + 1}'s held-out error on the training files by "
                f"{100 * (1 - with_rms / without_rms):.1f} % ({without_rms:.4g} -> "
                f"{with_rms:.4g} N·m)"
            )
        joints.append(j)
        scale.append(s)
        diam.append(float(spec.piston_diameter_m))
        kept.append(ok)
        reasons.append(why)
    figures = {"with": cv_rms_with.tolist(), "without": cv_rms_without.tolist()}
    return Calibration(
        tuple(joints), tuple(scale), tuple(diam), tuple(kept), tuple(reasons), figures
    )
