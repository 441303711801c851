"""Friction laws of the hard world (:mod:`.world`): one drawn per joint, most of them not the
product's eq. (15).

Every law gives the joint-side friction torque τ_f [N·m] of one joint over a whole session
(training run, then test run, then holdout, in continuous session time t [s]) from the true
joint position q [rad] and velocity v [rad/s] at the sample stamps. Stateful laws carry their
state across the runs. s(v) = tanh(v / 1e-4) stands for sgn(v) (as in :mod:`.family`).

Levels as the declared world's (P the joint's peak |rigid torque| over the training run):
F_c = 2-6 % P, F_s = 1.0-1.5 F_c, v_s = 0.01-0.05 rad/s, viscous σ_2 = 2-4 % P at the
training run's peak speed. The laws (``kind``, drawn uniformly per joint):

``eq15``
    the product's law, as :class:`.family.Friction`:
    (F_c + (F_s - F_c) exp(-|v|/v_s) + Σ_k a_k sin kq + b_k cos kq) s(v) + σ_2 v,
    |a_k|, |b_k| ≤ 4 % F_c.
``asymmetric_coulomb``
    F_+ max(s, 0) + F_- min(s, 0) + σ_2 v: the levels for positive and negative motion differ,
    F_- = r F_+, r = U(0.6, 1.4).
``stribeck_power``
    (F_c + (F_s - F_c) exp(-(|v|/v_s)^δ)) s(v) + σ_2 v, δ = U(0.5, 2).
``stribeck_lorentz``
    (F_c + (F_s - F_c) / (1 + (v/v_s)²)) s(v) + σ_2 v.
``lugre``
    bristle state z [rad]: dz/dt = v - σ_0 |v| / g(v) z, g(v) = F_c + (F_s - F_c) exp(-(v/v_s)²),
    τ_f = σ_0 z + σ_1 dz/dt + σ_2 v. σ_0 = F_s / z_b (presliding range z_b = 1e-4-1e-3 rad),
    σ_1 = ζ F_s / v_s (ζ = 0.05-0.3). At rest (v = 0) z is frozen: the joint holds a torque
    σ_0 z within ± F_s whose sign and size depend on how it came to rest.
``dahl``
    the same bristle with g = F_c and σ_1 = 0 (Dahl's model with exponent 1): τ_f = σ_0 z +
    σ_2 v, σ_0 = F_c / z_b.
``temperature_viscous``
    F_c s(v) + σ_2 c(t) v: the viscous coefficient falls as the arm warms over the session,
    first order with time constant T_θ = 5-20 min, by D = 10-30 % at the session's end:
    c(t) = 1 - D (1 - exp(-t/T_θ)) / (1 - exp(-t_end/T_θ)).

Integration of the bristle state (stable at any sample rate): between two stamps v is taken
linear, split in :data:`SUBSTEPS` pieces, each stepped exactly (for constant v the ODE is
linear in z: z → z_ss + (z - z_ss) exp(-a h), a = σ_0|v|/g(v), z_ss = v/a), continuous across
the session's runs; z starts at 0.

:meth:`FrictionLaw.columns` gives, per joint, the columns whose free combination is exactly the
law's torque with its true nonlinear shape parameters (the oracle of :mod:`.oracle` fits them):
the law's non-viscous torque as one column (the asymmetric Coulomb's two levels as two), and
the viscous term (temperature-viscous: its true time shape times v).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

# the levels are the declared world's (module docstring): one definition
from .family import (
    COULOMB_FRACTION,
    FOURIER_OVER_COULOMB,
    STATIC_OVER_COULOMB,
    VISCOUS_FRACTION,
)

SIGN_VELOCITY = 1e-4  # rad/s
SUBSTEPS = 4
KINDS = (
    "eq15",
    "asymmetric_coulomb",
    "stribeck_power",
    "stribeck_lorentz",
    "lugre",
    "dahl",
    "temperature_viscous",
)
V_S_RAD_S = (0.01, 0.05)
ASYMMETRY = (0.6, 1.4)
STRIBECK_EXPONENT = (0.5, 2.0)
PRESLIDING_RAD = (1e-4, 1e-3)
LUGRE_DAMPING = (0.05, 0.3)
WARM_DROP = (0.10, 0.30)
WARM_TIME_CONSTANT_S = (300.0, 1200.0)


#: the laws with a state (the bristle's deflection z), carried across the session's runs
STATEFUL_KINDS = ("lugre", "dahl")


def sign(v: np.ndarray) -> np.ndarray:
    return np.tanh(np.asarray(v) / SIGN_VELOCITY)


@dataclass(frozen=True)
class FrictionLaw:
    """One joint's law: ``kind`` (:data:`KINDS`) and its ``parameters`` (module docstring;
    ``session_end_s`` set for the temperature law)."""

    kind: str
    parameters: dict[str, Any] = field(default_factory=dict)

    def columns(self, t: np.ndarray, q: np.ndarray, v: np.ndarray) -> np.ndarray:
        """(T, m) columns of the law over a session (t [s], q [rad], v [rad/s], (T,)),
        scaled so that their plain sum is the law's torque [N·m]."""
        p = self.parameters
        fc, vs, visc = p.get("coulomb_nm", 0.0), p.get("v_s_rad_s", 1.0), p["viscous_nm_s_rad"]
        s = sign(v)
        if self.kind == "eq15":
            bracket = fc + (p["static_nm"] - fc) * np.exp(-np.abs(v) / vs)
            for k in range(2):
                bracket = bracket + p["sin_kq_nm"][k] * np.sin((k + 1) * q)
                bracket = bracket + p["cos_kq_nm"][k] * np.cos((k + 1) * q)
            return np.column_stack([bracket * s, visc * v])
        if self.kind == "asymmetric_coulomb":
            pos, neg = np.maximum(s, 0.0), np.minimum(s, 0.0)
            return np.column_stack([p["positive_nm"] * pos, p["negative_nm"] * neg, visc * v])
        if self.kind == "stribeck_power":
            drop = np.exp(-((np.abs(v) / vs) ** p["exponent"]))
            return np.column_stack([(fc + (p["static_nm"] - fc) * drop) * s, visc * v])
        if self.kind == "stribeck_lorentz":
            drop = 1.0 / (1.0 + (v / vs) ** 2)
            return np.column_stack([(fc + (p["static_nm"] - fc) * drop) * s, visc * v])
        if self.kind in STATEFUL_KINDS:
            z, dz = bristle(t, v, self)
            return np.column_stack([p["sigma0_nm_rad"] * z + p["sigma1_nm_s_rad"] * dz, visc * v])
        if self.kind == "temperature_viscous":
            return np.column_stack([fc * s, visc * self.warm_shape(t) * v])
        raise KeyError(f"unknown friction law {self.kind!r}")

    def torque(self, t: np.ndarray, q: np.ndarray, v: np.ndarray) -> np.ndarray:
        """τ_f [N·m] (T,) over a session."""
        return self.columns(t, q, v).sum(axis=1)

    def g(self, v: np.ndarray) -> np.ndarray:
        """The bristle's steady level g(v) [N·m] (LuGre: with the Stribeck drop; Dahl: F_c)."""
        p = self.parameters
        if self.kind == "dahl":
            return np.full_like(np.asarray(v, dtype=float), p["coulomb_nm"])
        fc = p["coulomb_nm"]
        return fc + (p["static_nm"] - fc) * np.exp(-((v / p["v_s_rad_s"]) ** 2))

    def warm_shape(self, t: np.ndarray) -> np.ndarray:
        """c(t) of the temperature law, 1 at t = 0, 1 - D at the session's end."""
        p = self.parameters
        tau, end = p["time_constant_s"], p["session_end_s"]
        return 1.0 - p["drop_at_end"] * (1.0 - np.exp(-t / tau)) / (1.0 - math.exp(-end / tau))

    def to_json(self) -> dict[str, Any]:
        return {"kind": self.kind, **self.parameters}


def bristle(t: np.ndarray, v: np.ndarray, law: FrictionLaw) -> tuple[np.ndarray, np.ndarray]:
    """The bristle state z [rad] and dz/dt [rad/s] at the stamps ``t`` (module docstring)."""
    sigma0 = law.parameters["sigma0_nm_rad"]
    n = t.size
    alpha, beta = np.ones(n), np.zeros(n)  # z_k = alpha_k z_{k-1} + beta_k
    if n > 1:
        dt = np.diff(t)
        for s in range(SUBSTEPS):
            frac = (s + 0.5) / SUBSTEPS
            vm = v[:-1] + frac * (v[1:] - v[:-1])
            a = sigma0 * np.abs(vm) / law.g(vm)
            zss = np.where(a > 0, vm / np.where(a > 0, a, 1.0), 0.0)
            e = np.exp(-a * dt / SUBSTEPS)
            # compose z -> e z + (1 - e) zss after the previous substeps
            alpha[1:], beta[1:] = e * alpha[1:], e * beta[1:] + (1.0 - e) * zss
    z = np.empty(n)
    zk = 0.0
    al, be = alpha.tolist(), beta.tolist()
    for k in range(n):
        zk = al[k] * zk + be[k]
        z[k] = zk
    dz = v - sigma0 * np.abs(v) / law.g(v) * z
    return z, dz


def draw_law(
    rng: np.random.Generator, kind: str, peak_nm: float, peak_speed_rad_s: float, end_s: float
) -> FrictionLaw:
    """One joint's law of ``kind`` sized from its peak rigid torque and the training run's peak
    speed; ``end_s`` the session's length [s] (module docstring)."""
    fc = float(rng.uniform(*COULOMB_FRACTION) * peak_nm)
    fs = float(rng.uniform(*STATIC_OVER_COULOMB) * fc)
    vs = float(rng.uniform(*V_S_RAD_S))
    visc = float(rng.uniform(*VISCOUS_FRACTION) * peak_nm / peak_speed_rad_s)
    p: dict[str, Any] = {"viscous_nm_s_rad": visc}
    if kind == "eq15":
        four = rng.uniform(-1.0, 1.0, (2, 2)) * FOURIER_OVER_COULOMB * fc
        p.update(coulomb_nm=fc, static_nm=fs, v_s_rad_s=vs, sin_kq_nm=four[0].tolist(),
                 cos_kq_nm=four[1].tolist())  # fmt: skip
    elif kind == "asymmetric_coulomb":
        ratio = float(rng.uniform(*ASYMMETRY))
        p.update(positive_nm=fc, negative_nm=ratio * fc, ratio=ratio)
    elif kind == "stribeck_power":
        exponent = float(rng.uniform(*STRIBECK_EXPONENT))
        p.update(coulomb_nm=fc, static_nm=fs, v_s_rad_s=vs, exponent=exponent)
    elif kind == "stribeck_lorentz":
        p.update(coulomb_nm=fc, static_nm=fs, v_s_rad_s=vs)
    elif kind == "lugre":
        zb = float(np.exp(rng.uniform(*np.log(PRESLIDING_RAD))))
        p.update(coulomb_nm=fc, static_nm=fs, v_s_rad_s=vs, presliding_rad=zb,
                 sigma0_nm_rad=fs / zb,
                 sigma1_nm_s_rad=float(rng.uniform(*LUGRE_DAMPING) * fs / vs))  # fmt: skip
    elif kind == "dahl":
        zb = float(np.exp(rng.uniform(*np.log(PRESLIDING_RAD))))
        p.update(coulomb_nm=fc, presliding_rad=zb, sigma0_nm_rad=fc / zb, sigma1_nm_s_rad=0.0)
    elif kind == "temperature_viscous":
        p.update(coulomb_nm=fc, drop_at_end=float(rng.uniform(*WARM_DROP)),
                 time_constant_s=float(rng.uniform(*WARM_TIME_CONSTANT_S)),
                 session_end_s=float(end_s))  # fmt: skip
    else:
        raise KeyError(f"unknown friction law {kind!r}")
    return FrictionLaw(kind, p)


def draw_laws(
    rng: np.random.Generator, peak_nm: np.ndarray, peak_speed: np.ndarray, end_s: float
) -> tuple[FrictionLaw, ...]:
    """A law per joint, its kind uniform over :data:`KINDS`."""
    kinds = [KINDS[int(i)] for i in rng.integers(len(KINDS), size=peak_nm.size)]
    return tuple(
        draw_law(rng, k, float(p), float(s), end_s)
        for k, p, s in zip(kinds, peak_nm, peak_speed, strict=True)
    )
