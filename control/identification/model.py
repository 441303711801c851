"""The identified model: its file (``model.json``) and its evaluation.

The model file (``model.json``, :data:`MODEL_FORMAT` version :data:`MODEL_VERSION`) holds the
URDF (path, sha256 and text), the base-parameter mapping and values, friction per joint, the
accepted effects, the joints on a fallback (:class:`PlainJoint`) and the torque channel's gain
and offset per joint (:mod:`.chain`); :class:`IdentifiedModel` loads and evaluates it,
vectorised. The fit that gives it is :mod:`.fit` (:func:`.fit.model_from_solution`).
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from control.identification import preprocess
from control.identification.datafile import Measurements
from control.identification.envelope import Envelope
from control.identification.friction_law import (
    FRICTION_PARAM_NAMES,
    friction_memory,
    rest_log_odds,
)
from control.identification.preprocess import Prepared
from control.identification.rigid import BaseParameters, RobotRegressor
from control.identification.signal_shift import shift_signal
from control.identification.terms import (
    Context,
    EffectTerm,
    FrictionTerm,
)
from control.model.cylinders import with_measured_cylinders
from gateway.errors import DataFileError
from gateway.robot.description import RobotDescription

MODEL_FORMAT = "leadthrough-model"
MODEL_VERSION = 6
#: Versions :meth:`IdentifiedModel.load` reads: 2 lacks the envelope and the plain joints, 3
#: the measurement chain (read as gain 1, offset 0); 4 stored a cylinder's measured diameter in
#: the torque channel's units (:meth:`.cylinders.Calibration.over_gain`): read where its joint's
#: gain is 1, refused where it is not; 5 has no friction with memory (``presliding_rad``) nor
#: a Gaussian Stribeck rise (``gauss_stribeck_*``), which a reader of version 5 would have
#: ignored (hence 6).
READABLE_VERSIONS = (2, 3, 4, 5, 6)


@dataclass(frozen=True)
class PlainJoint:
    """A joint on a fallback because the full model's held-out error was worse there (the
    guard of :func:`.guard.guard_joints`): its own base-parameter vector ``beta`` (nb,) over
    its row of the base regressor, Coulomb ``coulomb_nm`` [N·m] times sgn(dq) and viscous
    ``viscous_nm_s_per_rad`` [N·m·s/rad] and a constant ``offset_nm`` [N·m]. ``kind`` says
    which fallback: plain least squares (:func:`plain_columns`), the URDF's nominal β with
    fitted friction, or zero."""

    joint: int
    beta: np.ndarray
    coulomb_nm: float
    viscous_nm_s_per_rad: float
    kind: str = "plain_ls"
    offset_nm: float = 0.0

    @property
    def coef(self) -> np.ndarray:
        return np.r_[self.beta, self.coulomb_nm, self.viscous_nm_s_per_rad, self.offset_nm]

    @classmethod
    def from_coef(cls, joint: int, coef: np.ndarray, kind: str = "plain_ls") -> PlainJoint:
        """From the coefficients of :func:`plain_columns` (β, Coulomb, viscous, offset)."""
        c = np.asarray(coef, dtype=float)
        return cls(joint, c[:-3].copy(), float(c[-3]), float(c[-2]), kind, float(c[-1]))

    def friction(self, ctx: Context) -> np.ndarray:
        """Coulomb, viscous and the offset, (T,)."""
        return plain_friction_columns(ctx, self.joint) @ self.coef[-3:]


#: What predicts a joint's torque (:class:`PlainJoint`'s ``kind``, or the full model).
MODEL, PLAIN_LS, NOMINAL, ZERO = "model", "plain_ls", "nominal", "zero"
FALLBACKS = (PLAIN_LS, NOMINAL, ZERO)


def plain_key(j: int) -> str:
    return f"plain:{j}"


def plain_columns(ctx: Context, j: int) -> dict[int, np.ndarray]:
    """Plain least squares of joint j alone: its row of the base regressor with coefficients of
    its own, Coulomb ``sgn(dq_j)``, viscous ``dq_j`` (velocity clipped to the envelope) and a
    constant offset, columns filtered like the torque: the textbook fit the model must never do
    worse than. The offset is what a torque or current sensor's zero error adds; without it a
    constant the shared model cannot place (a wrist joint reading part of its neighbour's
    gravity torque) made plain least squares look worse than the textbook fit is."""
    assert ctx.y_base is not None
    return {j: np.column_stack([ctx.y_base[j], plain_friction_columns(ctx, j)])}


def plain_friction_columns(ctx: Context, j: int) -> np.ndarray:
    """Coulomb ``sgn(dq_j)``, viscous ``dq_j`` (velocity clipped to the envelope) and a
    constant 1 of joint j, filtered like the torque, (T, 3): the friction and offset of
    :func:`plain_columns`."""
    return ctx.filtered(
        ctx.sample_mean(j, lambda dq: np.column_stack([np.sign(dq), dq, np.ones_like(dq)]))
    )


@dataclass
class IdentifiedModel:
    """An identified model, as saved in ``model.json``; evaluation is vectorised over samples.

    Torques are joint side [N·m] and *exclude* the assist cylinders (they were taken out of the
    measured torque): the motor torque is ``torque_nm(...) - T_cyl(q, p)``. A ``time_delay``
    effect is a property of the measurement chain: it is reported as :attr:`delay_s` and not
    applied by :meth:`torque_nm`; a ``thermal_drift`` effect needs ``t_s``.

    The torque channel reads ``torque_gain · τ + torque_offset_nm`` per joint (the measurement
    chain of :mod:`.chain`; None: gain 1, offset 0). :meth:`torque_nm` is the physical torque,
    what a controller commands the joint to exert (through the drive's own torque constant,
    whose error the gain is: a command in the drive's units is ``torque_gain · τ``);
    :meth:`measured_torque_nm` (and :meth:`predict_measured`, ``leadthrough predict``) what
    the torque channel reads, what a reading is compared with (external force, residuals).
    In the control process the model's torque (gravity and friction of
    ``control/declared_model.py``, the point-model table of ``control/rt_tables.py``) stays
    physical, and every drive reading it is compared with is turned into physical torque
    first, in one place (``DeclaredModel.torque_per_amp_nm``: the law's motor torque, hence the
    hand torque, the engagement probe and the adaptation's residual, and
    ``control/load_check.py``); the law commands positions and velocities, never a torque in
    the drive's units.

    ``envelope`` bounds the friction and effect terms to the training range (see
    :mod:`.terms`); joints in ``plain_joints`` (0-based index → :class:`PlainJoint`) use their
    plain least-squares model instead of ``beta`` and the friction family, plus the effects
    that appeared between training and test (training-fitted effects are not on them).
    """

    regressor: RobotRegressor
    beta: np.ndarray
    friction_kind: str
    friction_terms: list[FrictionTerm]
    friction_coef: list[np.ndarray]
    effects: list[tuple[EffectTerm, np.ndarray, str]] = field(default_factory=list)
    urdf_path: str = ""
    metadata: dict[str, Any] = field(default_factory=dict)
    envelope: Envelope | None = None
    plain_joints: dict[int, PlainJoint] = field(default_factory=dict)
    torque_gain: np.ndarray | None = None
    torque_offset_nm: np.ndarray | None = None

    @property
    def joint_names(self) -> tuple[str, ...]:
        return self.regressor.joint_names

    @property
    def n(self) -> int:
        return self.regressor.n

    @property
    def delay_s(self) -> float:
        """Accepted torque-vs-kinematics delay δ [s] (0 without a time_delay effect)."""
        for term, _, _ in self.effects:
            if term.name == "time_delay":
                return float(term.setting["delay_s"])
        return 0.0

    def with_measured_cylinders(self, desc: RobotDescription) -> RobotDescription:
        """``desc`` with the piston diameters this model's identification measured
        (:mod:`.cylinders`): the cylinders it was fitted without, whose torque anything
        scoring or using the model must take out or add back. ``ValueError`` (naming what)
        when ``desc``'s cylinders are not the ones measured."""
        measured = (self.metadata.get("cylinders") or {}).get("cylinders", [])
        return with_measured_cylinders(desc, measured, "analysis.cylinders")

    def _arrays(self, *arrays: np.ndarray) -> tuple[bool, list[np.ndarray]]:
        arrs = [np.asarray(a, dtype=float) for a in arrays]
        single = arrs[0].ndim == 1
        out = [a.reshape(-1, self.n) for a in arrs]
        for a in out[1:]:
            if a.shape != out[0].shape:
                raise ValueError(f"shapes differ: {[x.shape for x in arrs]}")
        return single, out

    def _context(
        self,
        q: np.ndarray,
        dq: np.ndarray,
        ddq: np.ndarray,
        t_s: np.ndarray | None,
        dq_noise: np.ndarray | None = None,
        sequence: bool = True,
        directions: np.ndarray | None = None,
        rest_odds: np.ndarray | None = None,
        dq_friction: np.ndarray | None = None,
    ) -> Context:
        reg = self.regressor
        payload = any(term.name == "payload" for term, _, _ in self.effects)
        nb = reg.base.n_base
        cols = np.concatenate([reg.base.independent, reg.payload_indices if payload else []])
        y = reg.regressor_columns(q, dq, ddq, cols.astype(int))
        return Context(
            q, dq, ddq, t_s, y[:, :, :nb], y[:, :, nb:] if payload else None, None, None,
            self.envelope, dq_noise=dq_noise, sequence=sequence, directions=directions,
            rest_odds=None if rest_odds is None else np.asarray(rest_odds, dtype=float),
            dq_friction=dq_friction,
        )  # fmt: skip

    def _rigid(self, y_base: np.ndarray) -> np.ndarray:
        """``Y_b β`` per joint, (T, n); a plain joint uses its own β."""
        out = np.einsum("jtb,b->tj", y_base, self.beta)
        for j, pj in self.plain_joints.items():
            out[:, j] = y_base[j] @ pj.beta
        return out

    def _friction(self, ctx: Context) -> np.ndarray:
        out = np.zeros_like(ctx.q)
        for term, coef in zip(self.friction_terms, self.friction_coef, strict=True):
            out[:, term.joint] = term.columns(ctx)[term.joint] @ coef
        for j, pj in self.plain_joints.items():
            out[:, j] = pj.friction(ctx)
        return out

    def gravity_nm(self, q_rad: np.ndarray) -> np.ndarray:
        """Rigid-body torque at rest, g(q) of eq. (1) [N·m]; q (n,) or (T, n)."""
        single, (q,) = self._arrays(q_rad)
        zeros = np.zeros_like(q)
        out = self._rigid(self.regressor.base_regressor(q, zeros, zeros))
        return out[0] if single else out

    def friction_nm(self, q_rad: np.ndarray, dq_rad_s: np.ndarray) -> np.ndarray:
        """Friction torque of the identified friction model [N·m]; (n,) or (T, n). One sample
        (n,) has no history: a friction with memory slides there (:attr:`.terms.Context.sequence`);
        rows (T, n) are one motion in time order."""
        single, (q, dq) = self._arrays(q_rad, dq_rad_s)
        out = self._friction(Context(q, dq, dq, envelope=self.envelope, sequence=not single))
        return out[0] if single else out

    def rigid_nm(
        self, q_rad: np.ndarray, dq_rad_s: np.ndarray, ddq_rad_s2: np.ndarray
    ) -> np.ndarray:
        """``Y_b(q, dq, ddq) β`` [N·m]: identified rigid-body inverse dynamics."""
        single, (q, dq, ddq) = self._arrays(q_rad, dq_rad_s, ddq_rad_s2)
        out = self._rigid(self.regressor.base_regressor(q, dq, ddq))
        return out[0] if single else out

    def torque_nm(
        self,
        q_rad: np.ndarray,
        dq_rad_s: np.ndarray,
        ddq_rad_s2: np.ndarray,
        t_s: np.ndarray | None = None,
        dq_noise_rad_s: np.ndarray | None = None,
        directions: np.ndarray | None = None,
        rest_odds: np.ndarray | None = None,
        dq_friction_rad_s: np.ndarray | None = None,
    ) -> np.ndarray:
        """Rigid body + friction + accepted effect terms [N·m]; (n,) or (T, n).

        ``t_s`` [s] (scalar or (T,)) is only used by a thermal_drift effect (omitted without).
        ``dq_noise_rad_s`` (n,): the std of the noise on ``dq_rad_s`` (None: exact), over
        which friction is taken in expectation (:meth:`.terms.Context.sample_mean`). Rows
        (T, n) are one motion in time order, whose history a friction with memory follows;
        one sample (n,) has none, and such a friction slides there. ``directions`` (T, n):
        the friction directions of those rows when the caller follows the motion across
        several calls (:meth:`friction_directions`). ``rest_odds`` (n,): the log prior odds of
        rest per joint (:func:`.friction_law.rest_log_odds`) of the motion these rows belong
        to, for the same caller, or (T, n) per row; None: estimated from these rows.
        """
        single, (q, dq, ddq) = self._arrays(q_rad, dq_rad_s, ddq_rad_s2)
        t = None if t_s is None else np.broadcast_to(np.asarray(t_s, dtype=float), (q.shape[0],))
        v_fr = None
        if dq_friction_rad_s is not None:
            v_fr = np.asarray(dq_friction_rad_s, dtype=float).reshape(-1, self.n)
        ctx = self._context(q, dq, ddq, t, dq_noise_rad_s, not single, directions, rest_odds, v_fr)
        out = self.torque_from_context(ctx)
        return out[0] if single else out

    def measured(self, tau_nm: np.ndarray) -> np.ndarray:
        """What the torque channel reads for physical torques ``tau_nm`` (..., n): the
        measurement chain ``torque_gain · τ + torque_offset_nm``."""
        out = np.asarray(tau_nm, dtype=float)
        if self.torque_gain is not None:
            out = out * self.torque_gain
        return out if self.torque_offset_nm is None else out + self.torque_offset_nm

    def measured_torque_nm(
        self,
        q_rad: np.ndarray,
        dq_rad_s: np.ndarray,
        ddq_rad_s2: np.ndarray,
        t_s: np.ndarray | None = None,
        dq_noise_rad_s: np.ndarray | None = None,
        directions: np.ndarray | None = None,
        rest_odds: np.ndarray | None = None,
        dq_friction_rad_s: np.ndarray | None = None,
    ) -> np.ndarray:
        """:meth:`torque_nm` through the measurement chain (:meth:`measured`) [N·m]."""
        tau = self.torque_nm(
            q_rad, dq_rad_s, ddq_rad_s2, t_s, dq_noise_rad_s, directions, rest_odds,
            dq_friction_rad_s,
        )  # fmt: skip
        return self.measured(tau)

    def friction_directions(
        self,
        q_rad: np.ndarray,
        dq_rad_s: np.ndarray,
        dq_noise_rad_s: np.ndarray | None = None,
        start: np.ndarray | None = None,
        q_before: np.ndarray | None = None,
        rest_odds: np.ndarray | None = None,
    ) -> tuple[np.ndarray, np.ndarray]:
        """The friction memory of rows (T, n) of one motion, (T, n, 2): each joint's direction
        and speed (:func:`.friction_law.friction_memory`), and its last (n, 2): for a caller
        that evaluates the motion in pieces (``leadthrough predict``: stretches between gaps,
        chunks of rows) and passes each piece's slice to :meth:`torque_nm` as ``directions``,
        with ``start`` the previous piece's last ((n, 2), or (n,) directions alone; None: no
        history) and ``q_before`` (n,) its last position [rad] (the travel across a gap; None:
        none). Joints whose friction has no memory read 0. ``rest_odds`` (n,) as
        :meth:`torque_nm` takes it (None: estimated from these rows)."""
        q, dq = (np.asarray(a, dtype=float).reshape(-1, self.n) for a in (q_rad, dq_rad_s))
        out = np.zeros((*q.shape, 2))
        z0 = np.zeros((self.n, 2))
        if start is not None:
            given = np.asarray(start, dtype=float)
            z0[:, : 1 if given.ndim == 1 else 2] = given.reshape(self.n, -1)
        for term in self.friction_terms:
            j = term.joint
            if term.presliding_rad is None or j in self.plain_joints:
                continue
            sigma = 0.0 if dq_noise_rad_s is None else float(dq_noise_rad_s[j])
            before = None if q_before is None else float(q_before[j])
            odds = (
                rest_log_odds(dq[:, j], sigma)
                if rest_odds is None
                else np.asarray(rest_odds, dtype=float)[..., j]
            )
            z, w = friction_memory(
                q[:, j], dq[:, j], sigma, term.presliding_rad, z0[j, 0], before, odds, z0[j, 1]
            )
            out[:, j, 0], out[:, j, 1] = z, w
        end = out[-1].copy() if out.shape[0] else z0.copy()
        return out, end

    def torque_from_context(self, ctx: Context) -> np.ndarray:
        """:meth:`torque_nm` on a :class:`Context` whose regressor columns are computed (the
        analysis reuses its own); sets ``ctx.rigid`` and ``ctx.friction``. (T, n) [N·m]."""
        assert ctx.y_base is not None
        ctx.rigid = self._rigid(ctx.y_base)
        ctx.friction = self._friction(ctx)
        out = ctx.rigid + ctx.friction
        for term, coef, _ in self.effects:
            if not term.is_linear or (term.name == "thermal_drift" and ctx.t is None):
                continue
            # every effect acts on its own joints: the training-fitted ones were taken off the
            # plain joints when the model was built (assembly.restricted); one that appeared
            # between training and test was fitted on the residual of the plain joints' own
            # prediction and belongs on them too (a tool mounted weighs on every joint)
            for j, cols in term.columns(ctx).items():
                out[:, j] += cols @ coef
        return out

    def prepare(self, m: Measurements) -> Prepared:
        """``m`` filtered and decimated as the analysis that made this model prepared its
        files (its rate and cutoffs, :mod:`.preprocess`): the data :meth:`predict_measured`
        is scored on."""
        meta = self.metadata
        return preprocess.prepare(
            m,
            float(meta.get("analysis_rate_hz", preprocess.DEFAULT_RATE_HZ)),
            float(meta.get("position_cutoff_hz", preprocess.DEFAULT_POSITION_CUTOFF_HZ)),
            float(meta.get("torque_cutoff_hz", preprocess.DEFAULT_TORQUE_CUTOFF_HZ)),
        )

    def predict_measured(self, data: Prepared) -> np.ndarray:
        """What the torque sensor/drive should read on ``data`` (T, n), on the same target as
        ``data.tau``: :meth:`torque_nm` at the sample times, through the torque's low-pass
        (:meth:`.preprocess.Prepared.lowpass`), delayed by :attr:`delay_s` when a time_delay
        effect was accepted; through the measurement chain (:meth:`measured`)."""
        ctx = self._context(
            data.q, data.dq, data.ddq, data.t, data.dq_noise_rad_s, rest_odds=data.dq_rest_odds,
            dq_friction=data.dq_friction,
        )  # fmt: skip
        ctx.sample_hz, ctx.raw_hz = data.sample_hz, data.raw_hz
        ctx.resample_mix = data.resample_mix
        tau = self.measured(data.lowpass(self.torque_from_context(ctx)))
        return shift_signal(data.t, data.segment, tau, -self.delay_s) if self.delay_s else tau

    # -- file format -------------------------------------------------------------------------

    def to_json(self) -> dict[str, Any]:
        reg = self.regressor
        xml = self.metadata.get("urdf_xml", "")
        base = reg.base
        return {
            "format": MODEL_FORMAT,
            "version": MODEL_VERSION,
            "urdf": {
                "path": self.urdf_path,
                "sha256": hashlib.sha256(xml.encode()).hexdigest(),
                "xml": xml,
            },
            "gravity_m_s2": [float(v) for v in reg.gravity_m_s2],
            "joints": list(reg.joint_names),
            "base_parameters": {
                "columns": list(base.base_names),
                "values": [float(v) for v in self.beta],
                "definitions": base.definitions(),
                "independent_indices": [int(i) for i in base.independent],
                "dependent_indices": [int(i) for i in base.dependent],
                "dependent_in_independent": base.dependent_in_independent.tolist(),
                "full_parameter_names": list(base.names),
            },
            "friction": {
                "model": self.friction_kind,
                "parameter_names": list(FRICTION_PARAM_NAMES[self.friction_kind]),
                "joints": [
                    {"joint": reg.joint_names[t.joint], **t.parameters(c)}
                    for t, c in zip(self.friction_terms, self.friction_coef, strict=True)
                ],
            },
            "effects": [term.to_json(coef, appeared) for term, coef, appeared in self.effects],
            "training_envelope": None if self.envelope is None else self.envelope.to_json(),
            "plain_joints": [
                {
                    "joint": reg.joint_names[j],
                    "index": j + 1,
                    "base_parameter_values": pj.beta.tolist(),
                    "coulomb_nm": pj.coulomb_nm,
                    "viscous_nm_s_per_rad": pj.viscous_nm_s_per_rad,
                    "offset_nm": pj.offset_nm,
                    "fallback": pj.kind,
                }
                for j, pj in sorted(self.plain_joints.items())
            ],
            "measurement_chain": {
                "model": "the torque channel reads torque_gain * tau + torque_offset_nm",
                "torque_gain": [float(v) for v in self._chain()[0]],
                "torque_offset_nm": [float(v) for v in self._chain()[1]],
            },
            "cylinders_removed_from_torque": bool(self.metadata.get("cylinders_removed", False)),
            "analysis": {k: v for k, v in self.metadata.items() if k not in ("urdf_xml",)},
        }

    def chain_arrays(self) -> tuple[np.ndarray, np.ndarray]:
        """``(torque_gain, torque_offset_nm)`` per joint (gain 1, offset 0 where none)."""
        return self._chain()

    def _chain(self) -> tuple[np.ndarray, np.ndarray]:
        gain = np.ones(self.n) if self.torque_gain is None else self.torque_gain
        offset = np.zeros(self.n) if self.torque_offset_nm is None else self.torque_offset_nm
        return gain, offset

    def save(self, path: str | Path) -> None:
        Path(path).write_text(json.dumps(self.to_json(), indent=1) + "\n")

    @classmethod
    def load(cls, path: str | Path) -> IdentifiedModel:
        """Load ``model.json``; a malformed or foreign file raises :class:`DataFileError`."""
        p = Path(path)
        try:
            doc = json.loads(p.read_text())
        except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
            raise DataFileError(f"{p}: not a readable model file: {exc}") from None
        try:
            return cls.from_json(doc, str(p))
        except (KeyError, TypeError, ValueError, IndexError) as exc:
            if isinstance(exc, DataFileError):
                raise
            raise DataFileError(f"{p}: malformed model file: {exc!r}") from None

    @classmethod
    def from_json(cls, doc: dict[str, Any], where: str = "model") -> IdentifiedModel:
        if doc.get("format") != MODEL_FORMAT:
            raise DataFileError(f"{where}: format {doc.get('format')!r} is not {MODEL_FORMAT!r}")
        if doc.get("version") not in READABLE_VERSIONS:
            raise DataFileError(
                f"{where}: version {doc.get('version')!r}, expected one of {READABLE_VERSIONS}"
            )
        urdf = doc["urdf"]
        xml = urdf["xml"]
        if hashlib.sha256(xml.encode()).hexdigest() != urdf["sha256"]:
            raise DataFileError(f"{where}: URDF text does not match its sha256")
        bp = doc["base_parameters"]
        base = BaseParameters(
            independent=np.asarray(bp["independent_indices"], dtype=int),
            dependent=np.asarray(bp["dependent_indices"], dtype=int),
            dependent_in_independent=np.asarray(
                bp["dependent_in_independent"], dtype=float
            ).reshape(len(bp["independent_indices"]), len(bp["dependent_indices"])),
            names=tuple(bp["full_parameter_names"]),
        )
        reg = RobotRegressor(xml, tuple(doc["gravity_m_s2"]), base=base)
        if list(reg.joint_names) != list(doc["joints"]):
            raise DataFileError(f"{where}: joints {doc['joints']} differ from the URDF's")
        fr = doc["friction"]
        kind = fr["model"]
        terms, coefs = [], []
        for j, entry in enumerate(fr["joints"]):
            term = FrictionTerm(
                j,
                kind,
                float(entry["q_e_rad_s"]),
                float(entry.get("gear_ratio", 1.0)),
                None if entry.get("sign_width_rad_s") is None else float(entry["sign_width_rad_s"]),
                _positive_or_none(entry, "presliding_rad", where, j),
                _positive_or_none(entry, "gauss_stribeck_rad_s", where, j),
            )
            terms.append(term)
            coefs.append(np.array([float(entry[k]) for k in term.parameter_names]))
        effects = [
            (
                EffectTerm.from_json(e),
                np.asarray(e["coefficients"], dtype=float),
                str(e["appeared"]),
            )
            for e in doc.get("effects", [])
        ]
        beta = np.asarray(bp["values"], dtype=float)
        if beta.shape != (base.n_base,):
            raise DataFileError(f"{where}: {beta.size} base parameter values for {base.n_base}")
        meta = dict(doc.get("analysis", {}))
        meta["urdf_xml"] = xml
        meta["cylinders_removed"] = bool(doc.get("cylinders_removed_from_torque", False))
        env = doc.get("training_envelope")
        plain = {}
        for e in doc.get("plain_joints", []):
            j = int(e["index"]) - 1
            pj = PlainJoint(
                j,
                np.asarray(e["base_parameter_values"], dtype=float),
                float(e["coulomb_nm"]),
                float(e["viscous_nm_s_per_rad"]),
                str(e.get("fallback", PLAIN_LS)),
                float(e.get("offset_nm", 0.0)),
            )
            if not 0 <= j < reg.n or pj.beta.shape != (base.n_base,) or pj.kind not in FALLBACKS:
                raise DataFileError(f"{where}: plain joint {e['index']} malformed")
            plain[j] = pj
        gain, offset = _chain_from_json(doc.get("measurement_chain") or {}, reg, where)
        if doc.get("version") == 4:
            for e in (meta.get("cylinders") or {}).get("cylinders", []):
                j = int(e["joint_index"])
                if 0 <= j < reg.n and gain[j] != 1.0:
                    raise DataFileError(
                        f"{where}: version 4 with a torque gain of {gain[j]:.4g} on J{j + 1}, "
                        "which has a cylinder: its measured diameter is in the torque channel's "
                        "units, not physical ones (fixed in version 5); identify again"
                    )
        return cls(
            reg, beta, kind, terms, coefs, effects, str(urdf.get("path", "")), meta,
            None if env is None else Envelope.from_json(env), plain, gain, offset,
        )  # fmt: skip


def _positive_or_none(entry: dict[str, Any], key: str, where: str, j: int) -> float | None:
    """A friction entry's optional ``key`` (``presliding_rad``: memory; ``gauss_stribeck_rad_s``:
    a Gaussian Stribeck rise; absent: none); finite and positive."""
    value = entry.get(key)
    if value is None:
        return None
    x = float(value)
    if not (np.isfinite(x) and x > 0.0):
        raise DataFileError(f"{where}: friction of joint {j + 1}: {key} {value!r} is not > 0")
    return x


def _chain_from_json(
    mc: dict[str, Any], reg: RobotRegressor, where: str
) -> tuple[np.ndarray, np.ndarray]:
    """The ``measurement_chain`` of a model file: ``torque_gain`` (n,) and ``torque_offset_nm``
    (n,) [N·m] (absent, version 3: gain 1, offset 0). A gain must be finite and positive and an
    offset finite: the channel's reading is divided by the gain and has the offset taken off,
    and a NaN there would pass every later comparison silently."""
    fields = {"torque_gain": np.ones(reg.n), "torque_offset_nm": np.zeros(reg.n)}
    out = []
    for name, default in fields.items():
        try:
            values = np.asarray(mc.get(name, default), dtype=float)
        except (TypeError, ValueError):
            raise DataFileError(
                f"{where}: measurement_chain.{name} is {mc.get(name)!r}, not {reg.n} numbers"
            ) from None
        if values.shape != (reg.n,):
            raise DataFileError(
                f"{where}: measurement_chain.{name} has shape {values.shape}, not ({reg.n},)"
            )
        for j, v in enumerate(values):
            if not np.isfinite(v) or (name == "torque_gain" and v <= 0.0):
                need = "finite and > 0" if name == "torque_gain" else "finite"
                raise DataFileError(
                    f"{where}: measurement_chain.{name} of joint {j + 1} "
                    f"({reg.joint_names[j]}) is {float(v)}; it must be {need}"
                )
        out.append(values)
    return out[0], out[1]
