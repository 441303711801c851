"""Rest hold: the weightless arm stays where the operator leaves it, despite model error.

Zero-moment mode asks the drives for the model's torque and nothing else, so a static model
error δ (the gravity of a payload estimated from a short run, a few tenths of a per cent of
the load) is a torque nobody balances: the arm creeps at δ over the damping, about a
millimetre in 5 s at the tool for 0.2 N·m on a wrist joint. A real gearbox's stiction would
hold it; the model's friction compensation takes exactly that stiction away.

This module gives the arm a stiction of its own, bounded by what the model does not know.
Per joint, an elasto-plastic element (the Dahl / "reset integrator" friction model) between
the joint and an anchor:

    τ_h = clip(k (a - q), ±band),   k = band / deflection,

whose anchor slides with the joint whenever the clip is active, so the element never pushes
more than ``band``. A static error below the band deflects the arm by at most δ/k (less than
``deflection``) and it stays, however long. A push above the band moves the arm, against a
constant ``band`` (a Coulomb friction the operator pays; the product has no way to tell a
hand that pushes less than the model's error from the error itself), and when the push
falls below the band the arm stops. τ_h has no step.

``band`` per joint is what the model does not know: ``rms_factor`` × the model's held-out RMS
on that joint (``heldout_rms_nm`` of an identified ``model.json``), at least the configured
floor. The operator pays it as that Coulomb friction whenever a joint moves; a band of 2 RMS
on the GR630ST's J2 is about 2 N·m, a newton at the tool, and all six joints together cost
about 2-4 N of mean force on teach-bench's raster path.
"""

from __future__ import annotations

import math
from collections.abc import Sequence


class RestHold:
    """The elasto-plastic hold of the module docstring, on plain floats (one call per cycle)."""

    def __init__(self, band_nm: Sequence[float], deflection_rad: float) -> None:
        if not (math.isfinite(deflection_rad) and deflection_rad > 0):
            raise ValueError(f"rest hold deflection {deflection_rad} must be > 0")
        if not all(math.isfinite(b) and b >= 0 for b in band_nm):
            raise ValueError(f"rest hold band {list(band_nm)} must be >= 0 per joint")
        self.band_nm = [float(b) for b in band_nm]
        self.deflection_rad = deflection_rad
        self._anchor: list[float] | None = None

    @property
    def active(self) -> bool:
        return any(b > 0 for b in self.band_nm)

    def reset(self) -> None:
        """Start afresh: the next step anchors every joint where it is (τ_h = 0)."""
        self._anchor = None

    def torque_nm(self, q: Sequence[float]) -> list[float]:
        """τ_h per joint [N·m] at the joint positions ``q`` [rad] (rate-independent: the
        element depends on the path of q, not on time)."""
        if self._anchor is None:
            self._anchor = [float(v) for v in q]
        anchor, limit = self._anchor, self.deflection_rad
        out = []
        for j, (qj, band) in enumerate(zip(q, self.band_nm, strict=True)):
            gap = anchor[j] - qj
            if gap > limit:  # the element slips: the anchor follows the joint
                gap = limit
                anchor[j] = qj + limit
            elif gap < -limit:
                gap = -limit
                anchor[j] = qj - limit
            out.append(band * gap / limit)
        return out


def hold_band_nm(
    floor_nm: Sequence[float], rms_factor: float, heldout_rms_nm: Sequence[float] | None
) -> list[float]:
    """Per joint: ``rms_factor`` × the model's held-out RMS, at least ``floor_nm`` [N·m]."""
    if heldout_rms_nm is None:
        return [float(f) for f in floor_nm]
    if len(heldout_rms_nm) != len(floor_nm):
        raise ValueError(
            f"model held-out RMS has {len(heldout_rms_nm)} joints, not {len(floor_nm)}"
        )
    return [
        max(float(f), rms_factor * float(r)) for f, r in zip(floor_nm, heldout_rms_nm, strict=True)
    ]
