"""The checks of the taught-path planning (:mod:`control.taught_path` and the modules it
uses): finite numbers, joint arrays of the right shape, positive limits, poses within the
robot description's joint limits. Each raises ValueError naming what is wrong."""

from __future__ import annotations

import math

import numpy as np

from gateway.robot.description import RobotDescription


def _finite_array(value: object, name: str) -> np.ndarray:
    try:
        arr = np.array(value, dtype=float)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{name} must be numbers: {exc}") from None
    bad = np.argwhere(~np.isfinite(arr))
    if bad.size:
        where = ", ".join(str(int(i)) for i in bad[0])
        raise ValueError(f"{name} has a non-finite value {arr[tuple(bad[0])]} at [{where}]")
    return arr


def _joint_array(value: object, n: int, name: str) -> np.ndarray:
    arr = _finite_array(value, name)
    if arr.ndim != 2 or arr.shape[1] != n:
        raise ValueError(f"{name} must be (T, {n}) joint positions, got shape {arr.shape}")
    return arr


def _per_joint(value: object, n: int, name: str) -> np.ndarray:
    arr = _finite_array(value, name)
    try:
        arr = np.broadcast_to(arr, (n,)).copy()
    except ValueError:
        raise ValueError(f"{name} must be one value or {n}, got shape {arr.shape}") from None
    if np.any(arr <= 0):
        raise ValueError(f"{name} must be > 0, got {arr.tolist()}")
    return arr


def _require_positive(value: float, name: str) -> None:
    number = isinstance(value, int | float | np.integer | np.floating) and not isinstance(
        value, bool
    )
    if not (number and math.isfinite(value) and value > 0):
        raise ValueError(f"{name} must be a finite number > 0, got {value!r}")


def _check_within_limits(
    desc: RobotDescription, q: np.ndarray, t: np.ndarray | None = None
) -> None:
    """Raise ValueError naming the first sample and joint of q (T, n) outside the limits."""
    lower, upper = desc.lower_rad, desc.upper_rad
    bad = np.argwhere((q < lower) | (q > upper))
    if bad.size:
        i, j = (int(v) for v in bad[0])
        when = f" (t = {t[i]:.3f} s)" if t is not None else ""
        raise ValueError(
            f"sample {i}{when}: joint {desc.joints[j].name} at {q[i, j]:.4f} rad is outside "
            f"its limits [{lower[j]:.4f}, {upper[j]:.4f}] rad on {desc.name}; the taught path "
            "does not fit this robot"
        )
