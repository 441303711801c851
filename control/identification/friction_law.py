"""The friction law's pieces: its families, their design matrices, and a friction's memory.

Shared by the friction term (:class:`.terms.FrictionTerm`, which builds its columns from them),
the loaded model (:class:`.model.IdentifiedModel`) and the run-time tables
(:mod:`control.rt_tables`):

- the families (:data:`FRICTION_MODELS`: Coulomb + viscous + offset, eq. (14), eq. (15)), the
  names of their coefficients (:data:`FRICTION_PARAM_NAMES`) and each family's design matrix
  of one joint (:func:`friction_basis`);
- a Stribeck rise of Gaussian shape beside the family's own (:func:`gaussian_stribeck`,
  coefficient :data:`STRIBECK_PARAM_NAMES`);
- a friction with memory: the direction of Dahl's model over the joint's travel
  (:func:`friction_direction`, stepped by the prefix scan :func:`linear_recurrence`), the
  travel weighted by the probability that the joint moves (:func:`rest_probability`, with
  which :meth:`.terms.Context.sample_mean` also takes every function of the velocity in
  expectation).
"""

from __future__ import annotations

import numpy as np
from scipy.special import expit

from control.model.friction import (
    EQ14_PARAM_NAMES,
    EQ15_PARAM_NAMES,
    eq14_basis,
    eq15_basis,
    smooth_sign,
)

FRICTION_MODELS = ("simple", "eq14", "eq15")
#: Simple friction per joint: ``τ_c s(dq) + τ_v dq + offset`` with the smooth sign of eq. (16).
SIMPLE_PARAM_NAMES = ("coulomb_nm", "viscous_nm_s_per_rad", "offset_nm")
FRICTION_PARAM_NAMES = {
    "simple": SIMPLE_PARAM_NAMES,
    "eq14": EQ14_PARAM_NAMES,
    "eq15": EQ15_PARAM_NAMES,
}
#: The coefficient of a friction's Gaussian Stribeck rise
#: (:attr:`.terms.FrictionTerm.stribeck_rad_s`).
STRIBECK_PARAM_NAMES = ("gauss_stribeck_nm",)


#: Log prior odds of a joint at rest against one moving at a velocity of its noise's size
#: (:func:`rest_probability`): rest and motion equally likely, motion spread evenly over a range
#: ``V`` about 10⁴ times the noise σ wide, ``ln(V / (σ √(2π)))`` ≈ 8. The band the joint counts
#: as resting in is ± σ √(2 × 8) = ± 4 σ: half as wide for odds a hundred times smaller, as
#: the band's edge moves with the square root of their log.
REST_LOG_ODDS = 8.0


def rest_probability(v: np.ndarray, sigma: float) -> np.ndarray:
    """Probability that a joint whose velocity reads ``v`` [rad/s] through white noise of std
    ``sigma`` [rad/s] is at rest: its reading's likelihood at rest, N(v; 0, σ²), against a
    moving joint's, weighed by :data:`REST_LOG_ODDS`: ``expit(L - v² / 2σ²)``, 1 at 0, ½ at
    ± 4 σ, 1.1 % at ± 5 σ, under 10⁻⁴ beyond ± 6 σ."""
    return expit(REST_LOG_ODDS - 0.5 * (np.asarray(v, dtype=float) / sigma) ** 2)


def linear_recurrence(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``z_k = a_k z_(k-1) + b_k`` from ``z_(-1) = 0`` for every k, (T,): a prefix scan over
    the affine maps (log₂ T passes of whole-array products instead of a loop over T). With
    0 ≤ a ≤ 1 the products only shrink, so the scan is as accurate as the loop."""
    out = np.array(b, dtype=float, copy=True)
    mul = np.array(a, dtype=float, copy=True)
    shift = 1
    while shift < out.size:
        # each right side is evaluated whole before it is assigned
        out[shift:] = mul[shift:] * out[:-shift] + out[shift:]
        mul[shift:] = mul[shift:] * mul[:-shift]
        shift *= 2
    return out


def friction_direction(
    q: np.ndarray,
    dq: np.ndarray,
    sigma: float,
    presliding_rad: float,
    start: float = 0.0,
    q_before: float | None = None,
) -> np.ndarray:
    """The direction of a friction with memory, (T,) in [-1, 1]: the state z of Dahl's model
    (exponent 1) driven by the joint's travel, ``dz/dx = (1 - z sgn(dx)) / x_c`` with ``x_c``
    = ``presliding_rad`` the travel over which friction turns round after a reversal.

    Stepped exactly per sample (for travel of one sign, ``z → s + (z - s) exp(-|Δx| / x_c)``,
    s = sgn(Δx)), from z = ``start`` before the first sample (0: a file says nothing of the
    joint's history; a caller cutting one motion into pieces carries the last piece's end, and
    with ``q_before``, the last piece's last position, the travel from there to ``q[0]``).
    The travel is the positions' difference weighted by the probability that the joint moves
    (1 - :func:`rest_probability` of ``dq`` under the velocity noise ``sigma``; all of it
    without noise): the positions of a resting joint wander by their noise, and Dahl's state
    driven by that wander would decay from ±1 towards 0 at every rest (a step against the
    direction moves z twice as far as a step with it). At rest z holds: the joint holds the
    friction torque of its last motion, as a gear's teeth stay loaded when the joint stops.
    Sliding steadily, z = sgn(dq): the friction of a memoryless law."""
    q = np.asarray(q, dtype=float)
    if q.size == 0:
        return np.zeros(0)
    dx = np.diff(q, prepend=q[0] if q_before is None else float(q_before))
    if np.isfinite(sigma) and sigma > 0.0:
        dx = dx * (1.0 - rest_probability(dq, sigma))
    a = np.exp(-np.abs(dx) / presliding_rad)
    z = linear_recurrence(a, np.sign(dx) * (1.0 - a))
    if start:
        z = z + float(start) * np.exp(-np.cumsum(np.abs(dx)) / presliding_rad)
    return z


def gaussian_stribeck(
    dq: np.ndarray, v_s: float, direction: np.ndarray | None = None
) -> np.ndarray:
    """A Stribeck rise of Gaussian shape, ``exp(-(dq / v_s)²)`` times the direction of motion
    (``direction``, a friction's memory; None: sgn(dq)): the column of
    :attr:`.terms.FrictionTerm.stribeck_rad_s` and of the ``stribeck`` effect."""
    sign = np.sign(dq) if direction is None else direction
    return np.exp(-((dq / v_s) ** 2)) * sign


def friction_basis(
    kind: str,
    q: np.ndarray,
    dq: np.ndarray,
    q_e: float,
    gear_ratio: float,
    sign_width: float | None = None,
    direction: np.ndarray | None = None,
) -> np.ndarray:
    """Friction design matrix of one joint, (T, m), columns :data:`FRICTION_PARAM_NAMES`.

    ``eq15`` and ``eq14`` are :func:`control.model.friction.eq15_basis` / ``eq14_basis``
    (``sign_width``, eq. 15's own sign width, only for ``eq15``); ``simple`` is Coulomb
    ``s(dq) = tanh(dq / 2 q_e)``, viscous ``dq`` and a constant offset. ``direction`` (T,),
    when given, stands for the sign of the velocity in every column that carries it (a
    friction with memory, :class:`.terms.FrictionTerm`).
    """
    if sign_width is not None and kind != "eq15":
        raise ValueError(f"friction {kind!r} has no separate sign width")
    if kind == "eq15":
        return eq15_basis(q, dq, q_e, gear_ratio, sign_width, direction)
    if kind == "eq14":
        return eq14_basis(q, dq, q_e, direction)
    if kind == "simple":
        s = smooth_sign(dq, q_e) if direction is None else direction
        return np.column_stack([s, dq, np.ones_like(dq)])
    raise ValueError(f"unknown friction model {kind!r}")
