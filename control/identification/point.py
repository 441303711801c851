"""An identified model compiled for one sample per control cycle.

:meth:`.fit.IdentifiedModel.torque_nm` is vectorised over samples: on a single sample its
per-term numpy calls cost about 0.3 ms, twice per cycle. :class:`PointModel` evaluates the same
model at ``ddq = 0`` on plain floats: the rigid body and payload as one pinocchio regressor
times a weight matrix fixed at load time, friction and effects as closures over their
coefficients with ``math``. It is the same model, not an approximation:
``tests/unit/test_point_model.py`` checks it against ``torque_nm`` for every friction family
and every effect of the vocabulary (:data:`.terms.EFFECT_NAMES`), inside and outside the
training envelope, and a name this module does not know is refused when the model is compiled,
not silently dropped.

Effects that are not a torque at run time are left out, as ``torque_nm`` leaves them out
without a time: ``time_delay`` (a lag of the measurement chain) and ``thermal_drift`` (linear in
a recording's own clock).
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np
import pinocchio as pin

from control.identification.fit import IdentifiedModel
from control.identification.terms import EffectTerm, Envelope, FrictionTerm
from control.model.friction import eq15_point, eq15_row

#: Joint friction of one joint: (q [rad], dq [rad/s]) → N·m, inputs already clipped.
JointFn = Callable[[float, float], float]
#: One effect on its joint: (q, dq, rigid, friction) per joint → N·m.
EffectFn = Callable[[list[float], list[float], list[float], list[float]], float]

#: Effects with no run-time torque (module docstring).
NOT_AT_RUN_TIME = ("time_delay", "thermal_drift")


def _sign(x: float) -> float:
    """``np.sign`` on a float: 0 at 0, NaN stays NaN."""
    return (x > 0.0) - (x < 0.0) if x == x else x


class _Clip:
    """The envelope's clipping (:class:`.terms.Envelope`) on floats; no-op without one."""

    def __init__(self, envelope: Envelope | None, n: int) -> None:
        if envelope is None:
            self.q_lo = self.dq_lo = [-math.inf] * n
            self.q_hi = self.dq_hi = [math.inf] * n
        else:
            self.q_lo, self.q_hi = envelope.q_min.tolist(), envelope.q_max.tolist()
            self.dq_lo, self.dq_hi = envelope.dq_min.tolist(), envelope.dq_max.tolist()

    def q(self, j: int, v: float) -> float:
        return min(max(v, self.q_lo[j]), self.q_hi[j])

    def dq(self, j: int, v: float) -> float:
        return min(max(v, self.dq_lo[j]), self.dq_hi[j])


def _friction_fn(term: FrictionTerm, coef: np.ndarray) -> JointFn:
    """:func:`.terms.friction_basis` ``@ coef`` of one joint."""
    c = [float(v) for v in coef]
    qe = float(term.q_e_rad_s)
    if term.kind == "eq15":
        row = eq15_row(c, qe, term.gear_ratio, term.sign_width_rad_s)
        return lambda q, dq: eq15_point(row, q, dq)
    if term.kind == "eq14":
        f1, f2, f3, f4, fc, fs, fv = c

        def eq14(q: float, dq: float) -> float:
            sgn = _sign(dq)
            return (
                f1 * math.sin(q)
                + f2 * math.cos(q)
                + f3 * math.sin(2.0 * q)
                + f4 * math.cos(2.0 * q)
                + fc * sgn
                + fs * math.exp(-abs(dq) / qe) * sgn
                + fv * dq
            )

        return eq14
    if term.kind == "simple":
        tc, tv, off = c
        return lambda q, dq: tc * math.tanh(dq / (2.0 * qe)) + tv * dq + off
    raise ValueError(f"unknown friction model {term.kind!r}")


def _effect_fn(term: EffectTerm, coef: np.ndarray, clip: _Clip) -> EffectFn:
    """``term.columns(ctx)[j] @ coef`` for the single joint j an effect other than the payload
    acts on (:meth:`.terms.EffectTerm._raw_columns`)."""
    name, s = term.name, term.setting
    (j,) = term.joints
    c = [float(v) for v in coef]
    if name == "position_ripple":
        cpr = float(s["cycles_per_rev"])
        a, b = c
        return lambda q, dq, rigid, fr: a * math.sin(cpr * q[j]) + b * math.cos(cpr * q[j])
    if name == "spring":
        k, b = c
        return lambda q, dq, rigid, fr: k * q[j] + b  # physics: unclipped (terms.py)
    if name == "stribeck":
        v = float(s["velocity_rad_s"])
        (a,) = c

        def stribeck(q: list[float], dq: list[float], rigid: list[float], fr: list[float]) -> float:
            d = clip.dq(j, dq[j])
            return a * (math.exp(-((d / v) ** 2)) * _sign(d))

        return stribeck
    if name == "load_dependent_friction":
        (a,) = c
        return lambda q, dq, rigid, fr: a * (abs(rigid[j]) * _sign(clip.dq(j, dq[j])))
    if name == "wrist_coupling":
        k = int(s["from_joint"])
        (a,) = c
        if s["source"] == "friction":
            return lambda q, dq, rigid, fr: a * fr[k]
        return lambda q, dq, rigid, fr: a * (rigid[k] + fr[k])
    raise ValueError(f"effect {name!r} cannot be evaluated per cycle")


class PointModel:
    """:meth:`.fit.IdentifiedModel.torque_nm` at ``ddq = 0`` for one sample (module docstring)."""

    def __init__(self, model: IdentifiedModel) -> None:
        reg = model.regressor
        n = self.n = reg.n
        self._pin = (reg.model, reg.data, pin.computeJointTorqueRegressor)
        self._zeros = np.zeros(n)
        n_link = 10 * n
        base = reg.base.independent
        # Y_b β = Y[:, independent] β: the armature columns vanish at ddq = 0
        links = base < n_link
        w_rigid = np.zeros((n, n_link))
        w_rigid[:, base[links]] = np.asarray(model.beta, dtype=float)[links]
        for j, pj in model.plain_joints.items():
            w_rigid[j] = 0.0
            w_rigid[j, base[links]] = np.asarray(pj.beta, dtype=float)[links]
        w_payload = np.zeros((n, n_link))
        clip = _Clip(model.envelope, n)
        self._clip = clip
        friction: list[JointFn | None] = [None] * n
        for term, coef in zip(model.friction_terms, model.friction_coef, strict=True):
            friction[term.joint] = _friction_fn(term, coef)
        for j, pj in model.plain_joints.items():
            coulomb, viscous, offset = pj.coulomb_nm, pj.viscous_nm_s_per_rad, pj.offset_nm
            friction[j] = lambda q, dq, c=coulomb, v=viscous, o=offset: c * _sign(dq) + v * dq + o
        self._friction = [(j, f) for j, f in enumerate(friction) if f is not None]
        self._effects: list[tuple[int, EffectFn]] = []
        for term, coef, _ in model.effects:
            if term.name in NOT_AT_RUN_TIME:
                continue
            if term.name == "payload":
                for j in term.joints:
                    w_payload[j, reg.payload_indices] += np.asarray(coef, dtype=float)
                continue
            self._effects.append((term.joints[0], _effect_fn(term, coef, clip)))
        self._w_rigid = w_rigid
        self._w_payload = w_payload if np.any(w_payload) else None

    def torque_nm(self, q_rad: np.ndarray, dq_rad_s: np.ndarray | None = None) -> list[float]:
        """Joint torque [N·m] at ``q_rad``, ``dq_rad_s`` (float64 arrays (n,); ``None`` for
        rest) and ``ddq = 0``, as ``n`` floats: rigid body + friction + effects, cylinders
        excluded like :meth:`.fit.IdentifiedModel.torque_nm`. ``math`` raises ``ValueError`` or
        ``ArithmeticError`` on some inputs where the array form returns NaN or inf."""
        model, data, fn = self._pin
        dq_arr = self._zeros if dq_rad_s is None else dq_rad_s
        y = fn(model, data, q_rad, dq_arr, self._zeros)
        rigid = np.einsum("ij,ij->i", y, self._w_rigid).tolist()
        q = q_rad.tolist()
        dq = dq_arr.tolist()
        clip = self._clip
        fr = [0.0] * self.n
        for j, f in self._friction:
            fr[j] = f(clip.q(j, q[j]), clip.dq(j, dq[j]))
        out = [r + f for r, f in zip(rigid, fr, strict=True)]
        if self._w_payload is not None:
            for j, v in enumerate(np.einsum("ij,ij->i", y, self._w_payload).tolist()):
                out[j] += v
        for j, e in self._effects:
            out[j] += e(q, dq, rigid, fr)
        return out
