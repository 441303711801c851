"""Joint friction models of the paper, Section 3.1.1: eq. (14) and eq. (15) with (16)-(17).

Eq. (15) as printed is not physically sound: its static term ``τ_s sgn(i_c) S⁻¹(dq)`` with
``S⁻¹ = exp(-dq/q_e)`` (eq. 17) grows without bound for negative velocity, the static and
Coulomb terms follow two different signs (current and velocity), and the viscous terms are
gated by the sigmoid ``S(dq)`` so they vanish in one direction. Our reading, per joint::

    τ_f = [τ_s exp(-|dq|/q_e) + τ_c + f1 sin(q/R) + f2 cos(q/R) + f3 sin(2q/R) + f4 cos(2q/R)] s(dq)
          + (f5 sin q + f6 cos q) s(dq) + τ_v1 dq + τ_v2 dq |dq|

with the smooth sign ``s(dq) = 2 S(dq) - 1 = tanh(dq / (2 q_e))`` built from eq. (16). Every
term is odd in dq (friction opposes motion in both directions), τ_f is continuous (and zero)
at dq = 0, and for fixed q_e it is linear in the ten coefficients, which
:func:`eq15_basis` exposes for identification. ``sgn(i_c)`` is replaced by the velocity sign:
the model is evaluated on measured motion, and at rest the smooth sign gives zero.
The paper uses one q_e for the sigmoid of eq. (16) and the decay of eq. (17); a fitted model
may give the sign its own width ``q_sgn`` (``s(dq) = tanh(dq / (2 q_sgn))``, q_sgn = q_e when
not given): a drive's sign change is often much sharper than its Stribeck decay, and tying the
two makes the decay absorb the sign's shape (identification then reads the difference as a
spurious Stribeck effect).
R is the joint's gear ratio, as the paper writes (``q/R``); note that over a joint's range
``q/R`` stays small, so the f2 and f4 columns are nearly collinear with the Coulomb column.

Eq. (14), the Fourier model of ref. [37], read the same way::

    τ_f = f1 sin q + f2 cos q + f3 sin 2q + f4 cos 2q + f_c sgn(dq) + f_s exp(-|dq|/q_e) sgn(dq)
          + f_v dq

(the printed ``f_ic sin(q)`` is taken as Coulomb ``f_c sgn(dq)``, ``f_is e^{-f_ii dq} sgn(q)`` as
static ``f_s exp(-|dq|/q_e) sgn(dq)`` with ``f_ii = 1/q_e``). Its Fourier terms do not depend
on the direction of motion, as printed, and sgn is the hard sign (0 at dq = 0).

Units: q [rad], dq [rad/s], torques [N·m] on the joint side.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import astuple, dataclass
from typing import Any

import numpy as np

#: Column order of :func:`eq15_basis` and :meth:`FrictionParams.linear_parameters`.
EQ15_PARAM_NAMES = (
    "tau_s_nm",
    "tau_c_nm",
    "f1_nm",
    "f2_nm",
    "f3_nm",
    "f4_nm",
    "f5_nm",
    "f6_nm",
    "tau_v1_nm_s_per_rad",
    "tau_v2_nm_s2_per_rad2",
)

#: Column order of :func:`eq14_basis` and :meth:`FourierFrictionParams.linear_parameters`.
EQ14_PARAM_NAMES = ("f1_nm", "f2_nm", "f3_nm", "f4_nm", "f_c_nm", "f_s_nm", "f_v_nm_s_per_rad")


def _check_positive(name: str, value: float) -> None:
    if not (np.isfinite(value) and value > 0):
        raise ValueError(f"{name}: {value!r} must be a finite number > 0")


@dataclass(frozen=True)
class FrictionParams:
    """Eq. (15) coefficients of one joint (our reading, see the module docstring)."""

    tau_s_nm: float  #: static friction τ_s [N·m]
    tau_c_nm: float  #: Coulomb friction τ_c [N·m]
    f1_nm: float  #: Fourier sin(q/R) [N·m]
    f2_nm: float  #: Fourier cos(q/R) [N·m]
    f3_nm: float  #: Fourier sin(2q/R) [N·m]
    f4_nm: float  #: Fourier cos(2q/R) [N·m]
    f5_nm: float  #: sin(q) [N·m]
    f6_nm: float  #: cos(q) [N·m]
    tau_v1_nm_s_per_rad: float  #: linear viscous τ_v1 [N·m·s/rad]
    tau_v2_nm_s2_per_rad2: float  #: quadratic viscous τ_v2 [N·m·s²/rad²]
    q_e_rad_s: float  #: transition velocity q_e of eqs. (16)-(17) [rad/s]
    gear_ratio: float  #: R, joint gear ratio [-]
    #: width q_sgn of the smooth sign [rad/s]; None: q_e, as the paper writes
    sign_width_rad_s: float | None = None

    def __post_init__(self) -> None:
        _check_positive("q_e_rad_s", self.q_e_rad_s)
        _check_positive("gear_ratio", self.gear_ratio)
        if self.sign_width_rad_s is not None:
            _check_positive("sign_width_rad_s", self.sign_width_rad_s)

    @property
    def sign_rad_s(self) -> float:
        """The smooth sign's width [rad/s]: ``sign_width_rad_s``, or q_e without one."""
        return self.q_e_rad_s if self.sign_width_rad_s is None else self.sign_width_rad_s

    def linear_parameters(self) -> np.ndarray:
        """The ten coefficients in :data:`EQ15_PARAM_NAMES` order, shape (10,)."""
        return np.array(astuple(self)[: len(EQ15_PARAM_NAMES)], dtype=float)

    @classmethod
    def from_linear(
        cls,
        theta: np.ndarray | Sequence[float],
        q_e_rad_s: float,
        gear_ratio: float,
        sign_width_rad_s: float | None = None,
    ) -> FrictionParams:
        """Inverse of :meth:`linear_parameters` (e.g. from a least-squares fit on eq15_basis)."""
        values = [float(v) for v in np.asarray(theta, dtype=float).ravel()]
        if len(values) != len(EQ15_PARAM_NAMES):
            raise ValueError(f"expected {len(EQ15_PARAM_NAMES)} coefficients, got {len(values)}")
        return cls(*values, q_e_rad_s, gear_ratio, sign_width_rad_s)

    @classmethod
    def from_table(cls, entry: Any, gear_ratio: float) -> FrictionParams:
        """From a config table (``tau_s_nm``, ``tau_c_nm``, ``tau_v1_nm_s_per_rad``,
        ``tau_v2_nm_s2_per_rad2``, ``q_e_rad_s``, ``fourier_nm`` = f1..f6), as written in the
        declared model and the simulator's truth."""
        f1, f2, f3, f4, f5, f6 = entry.fourier_nm
        return cls(entry.tau_s_nm, entry.tau_c_nm, f1, f2, f3, f4, f5, f6,
                   entry.tau_v1_nm_s_per_rad, entry.tau_v2_nm_s2_per_rad2,
                   entry.q_e_rad_s, gear_ratio)  # fmt: skip


@dataclass(frozen=True)
class FourierFrictionParams:
    """Eq. (14) coefficients of one joint (our reading, see the module docstring)."""

    f1_nm: float  #: sin(q) [N·m]
    f2_nm: float  #: cos(q) [N·m]
    f3_nm: float  #: sin(2q) [N·m]
    f4_nm: float  #: cos(2q) [N·m]
    f_c_nm: float  #: Coulomb [N·m]
    f_s_nm: float  #: static (Stribeck) [N·m]
    f_v_nm_s_per_rad: float  #: viscous [N·m·s/rad]
    q_e_rad_s: float  #: transition velocity, 1/f_ii of eq. (14) [rad/s]

    def __post_init__(self) -> None:
        _check_positive("q_e_rad_s", self.q_e_rad_s)

    def linear_parameters(self) -> np.ndarray:
        """The seven coefficients in :data:`EQ14_PARAM_NAMES` order, shape (7,)."""
        return np.array(astuple(self)[: len(EQ14_PARAM_NAMES)], dtype=float)


def smooth_sign(dq_rad_s: np.ndarray, q_e_rad_s: np.ndarray | float) -> np.ndarray:
    """``s(dq) = 2 S(dq) - 1 = tanh(dq / (2 q_e))`` with S the sigmoid of eq. (16); in (-1, 1)."""
    return np.tanh(np.asarray(dq_rad_s, dtype=float) / (2.0 * np.asarray(q_e_rad_s)))


def stribeck_column(dq_rad_s: np.ndarray, q_e_rad_s: float, sign: np.ndarray) -> np.ndarray:
    """The Stribeck column of eqs. (14) and (15), ``exp(-|dq| / q_e) · sign``, (T,): the one
    column of either that depends on q_e (a search over q_e computes only it again,
    :func:`control.identification.friction_law.qe_part`)."""
    return np.exp(-np.abs(dq_rad_s) / q_e_rad_s) * sign


def _per_joint(params_list: Sequence[object], names: Sequence[str]) -> dict[str, np.ndarray]:
    return {name: np.array([getattr(p, name) for p in params_list], dtype=float) for name in names}


def _check_shapes(q: np.ndarray, dq: np.ndarray, n: int) -> None:
    if q.shape != dq.shape:
        raise ValueError(f"q and dq shapes differ: {q.shape} vs {dq.shape}")
    if q.shape[-1:] != (n,):
        raise ValueError(f"last axis must hold the {n} joints, got shape {q.shape}")


class Eq15Friction:
    """Eq. (15) with the per-joint parameters gathered into arrays once: the form to call at
    servo rate (the simulator's inner loop, the control cycle)."""

    def __init__(self, params_list: Sequence[FrictionParams]) -> None:
        self.n = len(params_list)
        p = _per_joint(params_list, (*EQ15_PARAM_NAMES, "q_e_rad_s", "gear_ratio", "sign_rad_s"))
        self._p = p
        self._half_inv_sign = 1.0 / (2.0 * p["sign_rad_s"])
        self._inv_qe = 1.0 / p["q_e_rad_s"]
        self._inv_r = 1.0 / p["gear_ratio"]
        #: per joint, for the compiled cycle (:attr:`rows`)
        self._rows = [
            eq15_row(f.linear_parameters().tolist(), f.q_e_rad_s, f.gear_ratio, f.sign_rad_s)
            for f in params_list
        ]

    def __call__(self, q_rad: np.ndarray, dq_rad_s: np.ndarray) -> np.ndarray:
        """Friction torque [N·m]; ``q``, ``dq`` of shape (n,) or (T, n)."""
        q = np.asarray(q_rad, dtype=float)
        dq = np.asarray(dq_rad_s, dtype=float)
        _check_shapes(q, dq, self.n)
        p = self._p
        s = np.tanh(dq * self._half_inv_sign)  # smooth_sign
        qr = q * self._inv_r
        coulomb_like = (
            p["tau_s_nm"] * np.exp(-np.abs(dq) * self._inv_qe)
            + p["tau_c_nm"]
            + p["f1_nm"] * np.sin(qr)
            + p["f2_nm"] * np.cos(qr)
            + p["f3_nm"] * np.sin(2.0 * qr)
            + p["f4_nm"] * np.cos(2.0 * qr)
            + p["f5_nm"] * np.sin(q)
            + p["f6_nm"] * np.cos(q)
        )
        viscous = p["tau_v1_nm_s_per_rad"] * dq + p["tau_v2_nm_s2_per_rad2"] * dq * np.abs(dq)
        return coulomb_like * s + viscous

    @property
    def rows(self) -> list[tuple[float, ...]]:
        """Per joint, the constants of :func:`eq15_row`: what the compiled cycle evaluates
        (control/rt/src/friction.rs)."""
        return self._rows


def eq15_row(
    coef: Sequence[float],
    q_e_rad_s: float,
    gear_ratio: float,
    sign_width_rad_s: float | None = None,
) -> tuple[float, ...]:
    """The constants the compiled cycle's eq. (15) takes (control/rt/src/friction.rs): the ten
    coefficients (:data:`EQ15_PARAM_NAMES`), then 1/(2 q_sgn), 1/q_e, 1/R (q_sgn =
    ``sign_width_rad_s``, or q_e without one)."""
    c = [float(v) for v in coef]
    if len(c) != len(EQ15_PARAM_NAMES):
        raise ValueError(f"eq. (15) takes {len(EQ15_PARAM_NAMES)} coefficients, got {len(c)}")
    sign = q_e_rad_s if sign_width_rad_s is None else sign_width_rad_s
    return (*c, 1.0 / (2.0 * sign), 1.0 / q_e_rad_s, 1.0 / gear_ratio)


def friction_eq15(
    q_rad: np.ndarray, dq_rad_s: np.ndarray, params_list: Sequence[FrictionParams]
) -> np.ndarray:
    """Friction torque of eq. (15) [N·m], our reading; ``q``, ``dq`` of shape (n,) or (T, n)."""
    return Eq15Friction(params_list)(q_rad, dq_rad_s)


def eq15_basis(
    q_rad: np.ndarray,
    dq_rad_s: np.ndarray,
    q_e_rad_s: float,
    gear_ratio: float,
    sign_width_rad_s: float | None = None,
    direction: np.ndarray | None = None,
) -> np.ndarray:
    """Design matrix of eq. (15) for one joint, shape (T, 10), columns :data:`EQ15_PARAM_NAMES`.

    ``q_rad`` [rad] and ``dq_rad_s`` [rad/s] are that joint's samples, shape (T,). Given q_e,
    R and the sign width, ``eq15_basis(q, dq, q_e, R, w) @ params.linear_parameters()`` equals
    :func:`friction_eq15` for that joint [N·m]. ``direction`` (T,) in [-1, 1], when given,
    stands where the smooth sign s(dq) stands (a friction with memory,
    :mod:`control.identification.friction_law`); the viscous columns keep dq.
    """
    q = np.atleast_1d(np.asarray(q_rad, dtype=float))
    dq = np.atleast_1d(np.asarray(dq_rad_s, dtype=float))
    if q.ndim != 1 or q.shape != dq.shape:
        raise ValueError(f"q and dq must be 1-D of equal length, got {q.shape} and {dq.shape}")
    _check_positive("q_e_rad_s", q_e_rad_s)
    _check_positive("gear_ratio", gear_ratio)
    if sign_width_rad_s is not None:
        _check_positive("sign_width_rad_s", sign_width_rad_s)
    if direction is None:
        s = smooth_sign(dq, q_e_rad_s if sign_width_rad_s is None else sign_width_rad_s)
    else:
        s = np.broadcast_to(np.asarray(direction, dtype=float), dq.shape)
    qr = q / gear_ratio
    return np.column_stack(
        [
            stribeck_column(dq, q_e_rad_s, s),
            s,
            np.sin(qr) * s,
            np.cos(qr) * s,
            np.sin(2.0 * qr) * s,
            np.cos(2.0 * qr) * s,
            np.sin(q) * s,
            np.cos(q) * s,
            dq,
            dq * np.abs(dq),
        ]
    )


def friction_eq14(
    q_rad: np.ndarray, dq_rad_s: np.ndarray, params_list: Sequence[FourierFrictionParams]
) -> np.ndarray:
    """Friction torque of eq. (14) [N·m], our reading; ``q``, ``dq`` of shape (n,) or (T, n)."""
    q = np.asarray(q_rad, dtype=float)
    dq = np.asarray(dq_rad_s, dtype=float)
    _check_shapes(q, dq, len(params_list))
    p = _per_joint(params_list, (*EQ14_PARAM_NAMES, "q_e_rad_s"))
    sgn = np.sign(dq)
    return (
        p["f1_nm"] * np.sin(q)
        + p["f2_nm"] * np.cos(q)
        + p["f3_nm"] * np.sin(2.0 * q)
        + p["f4_nm"] * np.cos(2.0 * q)
        + p["f_c_nm"] * sgn
        + p["f_s_nm"] * np.exp(-np.abs(dq) / p["q_e_rad_s"]) * sgn
        + p["f_v_nm_s_per_rad"] * dq
    )


def eq14_basis(
    q_rad: np.ndarray,
    dq_rad_s: np.ndarray,
    q_e_rad_s: float,
    direction: np.ndarray | None = None,
) -> np.ndarray:
    """Design matrix of eq. (14) for one joint, shape (T, 7), columns :data:`EQ14_PARAM_NAMES`.

    ``q_rad`` [rad] and ``dq_rad_s`` [rad/s] have shape (T,); linear in the coefficients for a
    given q_e [rad/s]. ``direction`` (T,), when given, stands where sgn(dq) stands (as in
    :func:`eq15_basis`).
    """
    q = np.atleast_1d(np.asarray(q_rad, dtype=float))
    dq = np.atleast_1d(np.asarray(dq_rad_s, dtype=float))
    if q.ndim != 1 or q.shape != dq.shape:
        raise ValueError(f"q and dq must be 1-D of equal length, got {q.shape} and {dq.shape}")
    _check_positive("q_e_rad_s", q_e_rad_s)
    sgn = (
        np.sign(dq)
        if direction is None
        else np.broadcast_to(np.asarray(direction, dtype=float), dq.shape)
    )
    return np.column_stack(
        [
            np.sin(q),
            np.cos(q),
            np.sin(2.0 * q),
            np.cos(2.0 * q),
            sgn,
            stribeck_column(dq, q_e_rad_s, sgn),
            dq,
        ]
    )
