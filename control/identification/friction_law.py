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
  (:func:`friction_memory`, stepped by the prefix scan :func:`linear_recurrence`), the
  travel weighted by the probability that the joint moves (:func:`rest_probability`, with
  which :meth:`.terms.Context.sample_mean` also takes every function of the velocity in
  expectation, under prior odds of rest the motion's own velocities give,
  :func:`rest_log_odds`).
"""

from __future__ import annotations

import numpy as np
from scipy.special import erf, expit

from control.model.friction import (
    EQ14_PARAM_NAMES,
    EQ15_PARAM_NAMES,
    eq14_basis,
    eq15_basis,
    smooth_sign,
    stribeck_column,
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
#: (:func:`rest_probability`) where no motion is given to estimate them from
#: (:func:`rest_log_odds`): rest and motion equally likely, motion spread evenly over a range
#: ``V`` about 10⁴ times the noise σ wide, ``ln(V / (σ √(2π)))`` ≈ 8. The band the joint counts
#: as resting in is ± σ √(2 × 8) = ± 4 σ: half as wide for odds a hundred times smaller, as
#: the band's edge moves with the square root of their log.
REST_LOG_ODDS = 8.0

#: |v| / σ below which a sample is counted as possibly resting (:func:`rest_log_odds`): ± 2 σ
#: holds 95.4 % of a resting joint's readings.
REST_BAND_SIGMA = 2.0

#: |v| / σ band over which the moving joint's velocity density near 0 is read
#: (:func:`rest_log_odds`): from 5 σ a resting joint's readings are under 6 · 10⁻⁷ of its
#: samples, and to 10 σ the band is still near 0 on the motion's own scale.
MOVING_BAND_SIGMA = (5.0, 10.0)

#: Bound of the estimated log odds: at ± 20 the posterior is 0 or 1 to 2 · 10⁻⁹ at v = 0.
REST_LOG_ODDS_LIMIT = 20.0


def rest_log_odds(dq: np.ndarray, sigma: float) -> float:
    """The log prior odds :func:`rest_probability` weighs a reading with, estimated from the
    motion's own velocities ``dq`` (T,) read through noise of std ``sigma`` [rad/s]: how much
    of the time the joint rests, against how densely the moving joint's velocity lies near 0.

    The readings are a mixture: a share π at rest, N(0, σ²), and the moving rest of density
    ``m`` per unit of v/σ near 0 (read where no resting reading falls, |v| in
    :data:`MOVING_BAND_SIGMA` σ). The readings within ± :data:`REST_BAND_SIGMA` σ beyond the
    moving ones there are the resting share: π = (share within − m · 2 × 2) / 0.954. The odds
    that a reading at v rests are then π φ(v/σ) / m, so ``L = ln(π / (√(2π) m))``.

    A multi-sine that only crosses 0 gives π ≈ 0 and L well below 0: every reading moves, as
    it does (a fixed prior of rest-or-motion counted ± 4 σ around each crossing as rest and
    dropped the friction's sign there, which the joint had). A teaching motion that dwells
    gives π its share of dwelling and L above 0. Counts get half a sample each so that L
    stays finite; it is bounded by ± :data:`REST_LOG_ODDS_LIMIT`. Without noise or samples,
    :data:`REST_LOG_ODDS`."""
    v = np.abs(np.asarray(dq, dtype=float))
    v = v[np.isfinite(v)]
    if v.size == 0 or not (np.isfinite(sigma) and sigma > 0.0):
        return REST_LOG_ODDS
    z = v / sigma
    n = float(z.size)
    lo, hi = MOVING_BAND_SIGMA
    moving = (np.count_nonzero((z >= lo) & (z < hi)) + 0.5) / (n * 2.0 * (hi - lo))
    inside = np.count_nonzero(z < REST_BAND_SIGMA) / n
    share = (inside - moving * 2.0 * REST_BAND_SIGMA) / float(erf(REST_BAND_SIGMA / np.sqrt(2.0)))
    share = min(max(share, 0.5 / n), 1.0)
    odds = np.log(share / (np.sqrt(2.0 * np.pi) * moving))
    return float(np.clip(odds, -REST_LOG_ODDS_LIMIT, REST_LOG_ODDS_LIMIT))


def rest_log_odds_per_joint(dq: np.ndarray, sigma: np.ndarray | None) -> np.ndarray:
    """:func:`rest_log_odds` of every joint of one motion, velocities ``dq`` (T, n) with
    noise ``sigma`` (n,) (None: exact velocities), (n,)."""
    n = dq.shape[1]
    noise = np.zeros(n) if sigma is None else np.asarray(sigma, dtype=float)
    return np.array([rest_log_odds(dq[:, j], float(noise[j])) for j in range(n)])


def rest_probability(
    v: np.ndarray, sigma: float, log_odds: float | np.ndarray = REST_LOG_ODDS
) -> np.ndarray:
    """Probability that a joint whose velocity reads ``v`` [rad/s] through white noise of std
    ``sigma`` [rad/s] is at rest: its reading's likelihood at rest, N(v; 0, σ²), against a
    moving joint's, weighed by the prior ``log_odds`` (scalar or per reading,
    :func:`rest_log_odds`; by default
    :data:`REST_LOG_ODDS`): ``expit(L - v² / 2σ²)``; with L = 8, 1 at 0, ½ at ± 4 σ, 1.1 % at
    ± 5 σ, under 10⁻⁴ beyond ± 6 σ."""
    return expit(
        np.asarray(log_odds, dtype=float) - 0.5 * (np.asarray(v, dtype=float) / sigma) ** 2
    )


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


def friction_memory(
    q: np.ndarray,
    dq: np.ndarray,
    sigma: float,
    presliding_rad: float,
    start: float = 0.0,
    q_before: float | None = None,
    log_odds: float | np.ndarray = REST_LOG_ODDS,
    start_speed: float = 0.0,
) -> tuple[np.ndarray, np.ndarray]:
    """What a friction with memory holds, (z, w), each (T,): its direction z in [-1, 1] and
    its speed w [rad/s], both over the joint's travel x, with ``x_c`` = ``presliding_rad``.

    z is the state of Dahl's model (exponent 1), ``dz/dx = (1 - z sgn(dx)) / x_c``, the
    travel over which friction turns round after a reversal. Stepped exactly per sample (for
    travel of one sign, ``z → s + (z - s) exp(-|Δx| / x_c)``, s = sgn(Δx)), from z = ``start``
    before the first sample (0: a file says nothing of the joint's history; a caller cutting
    one motion into pieces carries the last piece's end, and with ``q_before``, the last
    piece's last position, the travel from there to ``q[0]``). The travel is the positions'
    difference weighted by the probability that the joint moves (1 - :func:`rest_probability`
    of ``dq`` under the velocity noise ``sigma`` and the prior ``log_odds``; all of it without
    noise): the positions of a resting joint wander by their noise, and Dahl's state driven by
    that wander would decay from ±1 towards 0 at every rest (a step against the direction
    moves z twice as far as a step with it). At rest z holds: the joint holds the friction
    torque of its last motion, as a gear's teeth stay loaded when the joint stops.
    Sliding steadily, z = sgn(dq): the friction of a memoryless law.

    w is the joint's speed |dq| over the same travel, ``dw/dx = (|dq| - w) / x_c`` (from
    ``start_speed``): sliding, the speed itself (x_c is a fraction of a milliradian); at rest
    it holds the speed of the last x_c of travel. The level a joint holds at rest is the one
    its contacts were loaded to over that travel: a bristle (LuGre) follows its steady level
    g(v) over x_c of travel, and a joint that decelerates to rest freezes at g of the speed it
    had there, the static level only if it crept the whole last x_c. Friction's Stribeck
    parts at rest are taken at w (:class:`.terms.FrictionTerm`)."""
    q = np.asarray(q, dtype=float)
    if q.size == 0:
        return np.zeros(0), np.zeros(0)
    dq = np.asarray(dq, dtype=float)
    dx = np.diff(q, prepend=q[0] if q_before is None else float(q_before))
    moving = np.ones_like(dx)
    if np.isfinite(sigma) and sigma > 0.0:
        moving = 1.0 - rest_probability(dq, sigma, log_odds)
        dx = dx * moving
    a = np.exp(-np.abs(dx) / presliding_rad)
    z = linear_recurrence(a, np.sign(dx) * (1.0 - a))
    w = linear_recurrence(a, np.abs(dq) * moving * (1.0 - a))
    if start or start_speed:
        kept = np.exp(-np.cumsum(np.abs(dx)) / presliding_rad)
        z = z + float(start) * kept
        w = w + float(start_speed) * kept
    return z, w


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


def qe_columns(kind: str, sign_width: float | None, direction: bool) -> tuple[int, ...] | None:
    """The columns of :func:`friction_basis` that depend on q_e, or None where every one does
    (eq. 15's sign tied to q_e). The others are the same for every q_e, so a search over q_e
    computes them once (:meth:`.terms.FrictionTerm.columns`). ``direction``: a direction with
    memory stands for the sign."""
    if kind == "eq15":
        return (0,) if sign_width is not None or direction else None
    if kind == "eq14":
        return (5,)
    if kind == "simple":
        return () if direction else (0,)
    raise ValueError(f"unknown friction model {kind!r}")


def qe_part(
    kind: str,
    dq: np.ndarray,
    q_e: float,
    sign_width: float | None = None,
    direction: np.ndarray | None = None,
) -> np.ndarray:
    """The columns :func:`qe_columns` names, (T, k): the same numbers as those columns of
    :func:`friction_basis`, by the same arithmetic."""
    if not (np.isfinite(q_e) and q_e > 0):
        raise ValueError(f"q_e_rad_s must be a finite number > 0, got {q_e!r}")
    v = np.atleast_1d(np.asarray(dq, dtype=float))
    if kind == "simple":
        return np.empty((v.size, 0)) if direction is not None else smooth_sign(v, q_e)[:, None]
    if direction is not None:
        sign = np.broadcast_to(np.asarray(direction, dtype=float), v.shape)
    elif kind == "eq15":
        if sign_width is None:
            raise ValueError("eq. (15) with its sign tied to q_e has no q_e part apart")
        sign = smooth_sign(v, sign_width)
    elif kind == "eq14":
        sign = np.sign(v)
    else:
        raise ValueError(f"unknown friction model {kind!r}")
    return stribeck_column(v, q_e, sign)[:, None]
