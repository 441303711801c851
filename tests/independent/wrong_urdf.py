"""The URDF a user hands analyze in the hard world (:mod:`.world`): wrong the way real ones are.

Per link of the generating arm: mass × U(0.8, 1.2); centre of mass moved by U(-2, 2) cm per
axis of the link frame; inertia about the centre of mass with its principal moments (about the
generating body's principal axes) × U(0.5, 1.5) each, redrawn until the moments are positive and
meet the triangle inequality (after :data:`REDRAWS` tries the largest is clipped to the sum of
the other two). The kinematics (joint origins, axes, limits) are exact. The generating URDF is
written beside it as ``truth_robot.urdf`` for the oracle only.
"""

from __future__ import annotations

from dataclasses import replace
from typing import Any

import numpy as np

from .family import FamilyArm, Link

MASS_FACTOR = (0.8, 1.2)
COM_SHIFT_M = 0.02
MOMENT_FACTOR = (0.5, 1.5)
REDRAWS = 100


def principal(link: Link) -> np.ndarray:
    """The principal moments [kg·m²] of ``link``'s inertia about its box axes."""
    return np.diag(link.rotation.T @ link.inertia @ link.rotation).copy()


def physical(moments: np.ndarray) -> bool:
    """Positive moments meeting the triangle inequality."""
    m = np.sort(moments)
    return bool(m[0] > 0 and m[0] + m[1] >= m[2])


def wrong_link(link: Link, rng: np.random.Generator) -> tuple[Link, dict[str, Any]]:
    mass_factor = float(rng.uniform(*MASS_FACTOR))
    shift = rng.uniform(-COM_SHIFT_M, COM_SHIFT_M, 3)
    true = principal(link)
    for _ in range(REDRAWS):
        factors = rng.uniform(*MOMENT_FACTOR, 3)
        moments = true * factors
        if physical(moments):
            break
    else:
        k = int(np.argmax(moments))
        moments[k] = moments.sum() - moments[k]
        factors = moments / true
    rot = link.rotation
    inertia = rot @ np.diag(moments) @ rot.T
    out = replace(
        link,
        mass=link.mass * mass_factor,
        com=link.com + shift,
        inertia=0.5 * (inertia + inertia.T),
    )
    record = {
        "mass_factor": mass_factor,
        "com_shift_m": shift.tolist(),
        "moment_factors": factors.tolist(),
    }
    return out, record


def wrong_arm(arm: FamilyArm, rng: np.random.Generator) -> tuple[FamilyArm, list[dict[str, Any]]]:
    """The arm with every link wrong (module docstring) and the per-link record."""
    pairs = [wrong_link(lk, rng) for lk in arm.links]
    return replace(arm, links=tuple(p[0] for p in pairs)), [p[1] for p in pairs]
