"""Rigid-body regressor and base parameters of any serial robot given as URDF (pinocchio).

The inverse dynamics of eq. (1) is linear in the link parameters (eq. (2) of the paper and
:mod:`control.model.dynamics`): ``τ = Y(q, dq, ddq) θ`` with ten parameters per link,
``[m, mcx, mcy, mcz, Ixx, Ixy, Iyy, Ixz, Iyz, Izz]`` (kg, kg·m, kg·m²; first moments and
inertias about the link's joint frame, pinocchio's ``Inertia.toDynamicParameters`` order).

Not all of θ shows in the torques: some columns of Y are zero for every motion and others are
fixed linear combinations of the rest. The *base parameters* (Section 3.1.2: "removing the
quantity that does not affect the dynamic output", QR as in ref. [39]) are found numerically:
stack Y over random samples (q within the joint limits, random dq and ddq), take a QR
decomposition with column pivoting (``scipy.linalg.qr(pivoting=True)``), and count as rank the
pivots with ``|R_kk| > RANK_TOLERANCE · |R_00|``. The chosen (independent) columns ``Y_b`` stay;
every other column is ``Y[:, dep] = Y_b K``, so

    τ = Y θ = Y_b β   with   β = θ[indep] + K θ[dep]

and each base parameter is a documented combination (:meth:`BaseParameters.definitions`).

Geared drives add the rotor inertia reflected through the gear, ``I_a = J_rotor R²``, to each
joint: ``τ_j += I_a,j ddq_j`` (for a big gearbox it rivals the link inertia: 11.7 kg·m² on the
GR630ST's joint 2). The URDF cannot say it, so θ carries one more parameter per joint,
``<joint>.armature``, whose column is ``ddq_j`` in row j; the QR regroups it where it is not
separable (joint 1's armature adds to link 1's Izz).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pinocchio as pin
from scipy import linalg

from control.model.dynamics import LINK_PARAMETER_NAMES
from gateway.errors import ConfigError

#: Relative pivot size below which a QR column counts as dependent (columns here are exact
#: combinations up to rounding, ~1e-14 relative, so the gap to real pivots is wide).
RANK_TOLERANCE = 1e-8
#: Entries of K below this are rounding noise and set to zero.
K_CLEAN_TOLERANCE = 1e-9
DEFAULT_GRAVITY_M_S2 = (0.0, 0.0, -9.81)
_RANDOM_DQ_RAD_S = 2.0
_RANDOM_DDQ_RAD_S2 = 5.0
_UNLIMITED_RAD = np.pi
#: The payload effect uses all ten parameters of the last link: a mounted tool brings mass,
#: first moments and (point-mass-like) inertia; fitting only [m, mc] leaves its inertia torque.
PAYLOAD_PARAMETER_NAMES = LINK_PARAMETER_NAMES


@dataclass(frozen=True)
class BaseParameters:
    """Mapping from the full link parameters θ (10 per link) to the base parameters β.

    ``independent`` (nb,) and ``dependent`` (nd,) index θ; ``dependent_in_independent`` K
    (nb, nd) gives ``Y[:, dependent] = Y[:, independent] @ K`` and so
    ``β = θ[independent] + K θ[dependent]``. ``names`` are the full parameter names
    (``"link3.mcx"``).
    """

    independent: np.ndarray
    dependent: np.ndarray
    dependent_in_independent: np.ndarray
    names: tuple[str, ...]

    @property
    def n_base(self) -> int:
        return int(self.independent.size)

    @property
    def base_names(self) -> tuple[str, ...]:
        """Name of each base parameter's independent column (the leading term of its sum)."""
        return tuple(self.names[i] for i in self.independent)

    def base_values(self, theta_full: np.ndarray) -> np.ndarray:
        """β from a full parameter vector θ (10 per link)."""
        theta = np.asarray(theta_full, dtype=float)
        return theta[self.independent] + self.dependent_in_independent @ theta[self.dependent]

    def definitions(self, digits: int = 6) -> list[str]:
        """Each β_i as ``"link2.mcx + 0.9001*link3.m - ..."`` (the regrouped sum)."""
        out = []
        for i, col in enumerate(self.independent):
            terms = [self.names[col]]
            for k, dep in enumerate(self.dependent):
                c = float(self.dependent_in_independent[i, k])
                if c == 0.0:
                    continue
                sign = "-" if c < 0 else "+"
                mag = abs(c)
                coef = "" if abs(mag - 1.0) < 10 ** (-digits) else f"{mag:.{digits}g}*"
                terms.append(f"{sign} {coef}{self.names[dep]}")
            out.append(" ".join(terms))
        return out


def _body_names(model: pin.Model) -> list[str]:
    """Name of the link (body frame) each joint carries; the joint name if there is none."""
    names = []
    for jid in range(1, model.njoints):
        name = model.names[jid]
        for frame in model.frames:
            if frame.parentJoint == jid and frame.type == pin.FrameType.BODY:
                name = frame.name
                break
        names.append(name)
    return names


#: Samples whose full regressor is held at once by :meth:`RobotRegressor.regressor_columns`.
REGRESSOR_CHUNK = 2048


class RobotRegressor:
    """pinocchio model of one URDF with its base-parameter regressor; joint order = URDF chain.

    ``gravity_m_s2`` is the gravity vector in the URDF's root frame [m/s²]. Only 1-DOF joints
    (revolute, prismatic) are supported. ``base`` reuses an earlier base-parameter mapping (as
    stored in a model file); by default it is computed (:func:`compute_base_parameters`).
    """

    def __init__(
        self,
        urdf_xml: str,
        gravity_m_s2: tuple[float, float, float] | np.ndarray = DEFAULT_GRAVITY_M_S2,
        base: BaseParameters | None = None,
        seed: int = 0,
    ) -> None:
        try:
            self.model = pin.buildModelFromXML(urdf_xml)
        except (RuntimeError, ValueError) as exc:
            raise ConfigError(f"URDF not usable by pinocchio: {exc}") from None
        if self.model.nq != self.model.nv or self.model.nv != self.model.njoints - 1:
            raise ConfigError(
                "URDF: only revolute/prismatic (1-DOF) joints are supported; continuous or "
                "floating joints are not (give continuous joints limits: type revolute)"
            )
        if self.model.nv == 0:
            raise ConfigError("URDF has no moving joint")
        gravity = np.asarray(gravity_m_s2, dtype=float)
        if gravity.shape != (3,) or not np.all(np.isfinite(gravity)):
            raise ConfigError(f"gravity: {gravity_m_s2!r} must be 3 finite values [m/s²]")
        self.gravity_m_s2 = gravity
        self.model.gravity = pin.Motion(gravity, np.zeros(3))
        self.data = self.model.createData()
        self.n = int(self.model.nv)
        self.joint_names = tuple(self.model.names[1:])
        self.link_names = tuple(_body_names(self.model))
        self.parameter_names = tuple(
            f"{link}.{p}" for link in self.link_names for p in LINK_PARAMETER_NAMES
        ) + tuple(f"{joint}.armature" for joint in self.joint_names)
        lower = np.asarray(self.model.lowerPositionLimit, dtype=float)
        upper = np.asarray(self.model.upperPositionLimit, dtype=float)
        bad = ~np.isfinite(lower) | ~np.isfinite(upper) | (upper <= lower)
        self.lower_rad = np.where(bad, -_UNLIMITED_RAD, lower)
        self.upper_rad = np.where(bad, _UNLIMITED_RAD, upper)
        last = 10 * (self.n - 1)
        #: θ indices of the last link's ten parameters (payload columns).
        self.payload_indices = np.arange(last, last + len(PAYLOAD_PARAMETER_NAMES))
        self.base = base if base is not None else compute_base_parameters(self, seed=seed)
        if self.base.names != self.parameter_names:
            raise ConfigError("base-parameter mapping belongs to another robot (names differ)")

    @classmethod
    def from_file(
        cls, path: str | Path, gravity_m_s2: tuple[float, float, float] = DEFAULT_GRAVITY_M_S2
    ) -> RobotRegressor:
        p = Path(path)
        try:
            xml = p.read_text()
        except OSError as exc:
            raise ConfigError(f"--urdf {p}: cannot read: {exc.strerror or exc}") from None
        return cls(xml, gravity_m_s2)

    def regressor(self, q: np.ndarray, dq: np.ndarray, ddq: np.ndarray) -> np.ndarray:
        """Full joint-torque regressor Y of one sample, shape (n, 11 n): ten link columns per
        link, then one armature column per joint."""
        y = pin.computeJointTorqueRegressor(self.model, self.data, q, dq, ddq)
        y = np.reshape(y, (self.n, -1))  # a one-joint robot's comes back flat
        return np.hstack([y, np.diag(np.asarray(ddq, dtype=float))])

    def regressor_columns(
        self,
        q: np.ndarray,
        dq: np.ndarray,
        ddq: np.ndarray,
        columns: np.ndarray,
        progress: Callable[[str], None] | None = None,
    ) -> np.ndarray:
        """Chosen columns of Y for T samples, joint-major: shape (n, T, len(columns)).

        ``q``, ``dq``, ``ddq`` have shape (T, n); ``out[j]`` holds joint j's rows.
        """
        q = np.ascontiguousarray(q, dtype=float).reshape(-1, self.n)
        dq = np.ascontiguousarray(dq, dtype=float).reshape(-1, self.n)
        ddq = np.ascontiguousarray(ddq, dtype=float).reshape(-1, self.n)
        cols = np.asarray(columns, dtype=int)
        out = np.empty((self.n, q.shape[0], cols.size))
        # a Data of its own: calls may run side by side in threads
        model, data, fn = self.model, self.model.createData(), pin.computeJointTorqueRegressor
        link_cols = cols[cols < 10 * self.n]
        arm_pos = np.flatnonzero(cols >= 10 * self.n)  # positions in ``cols`` of armatures
        arm_joint = cols[arm_pos] - 10 * self.n
        link_pos = np.flatnonzero(cols < 10 * self.n)
        out[:, :, arm_pos] = 0.0
        for j_col, j in zip(arm_pos, arm_joint, strict=True):
            out[j, :, j_col] = ddq[:, j]
        fn(model, data, q[0], dq[0], ddq[0]) if q.shape[0] else None
        # ``data.jointTorqueRegressor`` is a live view of pinocchio's result: copying it per
        # sample costs a third of taking the returned copy apart; chunks bound the memory
        view = data.jointTorqueRegressor
        chunk = np.empty((min(REGRESSOR_CHUNK, q.shape[0]), *view.shape))
        step = max(1, q.shape[0] // 10)
        for a in range(0, q.shape[0], REGRESSOR_CHUNK):
            b = min(a + REGRESSOR_CHUNK, q.shape[0])
            for k in range(a, b):
                fn(model, data, q[k], dq[k], ddq[k])
                chunk[k - a] = view
                if progress is not None and k and k % step == 0 and q.shape[0] > 50_000:
                    progress(f"regressor {100 * k // q.shape[0]} %")
            rows = chunk[: b - a].reshape(b - a, self.n, -1)
            out[:, a:b, link_pos] = np.moveaxis(rows[:, :, link_cols], 0, 1)
        return out

    def base_regressor(self, q: np.ndarray, dq: np.ndarray, ddq: np.ndarray) -> np.ndarray:
        """Base regressor Y_b for T samples, joint-major: shape (n, T, nb)."""
        return self.regressor_columns(q, dq, ddq, self.base.independent)

    def rnea(self, q: np.ndarray, dq: np.ndarray, ddq: np.ndarray) -> np.ndarray:
        """Inverse dynamics with the URDF's own inertials for T samples [N·m], shape (T, n)."""
        q = np.asarray(q, dtype=float).reshape(-1, self.n)
        dq = np.asarray(dq, dtype=float).reshape(-1, self.n)
        ddq = np.asarray(ddq, dtype=float).reshape(-1, self.n)
        return np.array(
            [pin.rnea(self.model, self.data, a, b, c) for a, b, c in zip(q, dq, ddq, strict=True)]
        )

    def parameters(self) -> np.ndarray:
        """The URDF's own parameters θ, shape (11 n,): link parameters, then zero armatures
        (a URDF has none)."""
        links = [self.model.inertias[i].toDynamicParameters() for i in range(1, self.model.njoints)]
        return np.concatenate([*links, np.zeros(self.n)])

    def random_samples(
        self, n_samples: int, rng: np.random.Generator
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """q uniform within the limits, dq and ddq uniform in ±2 rad/s and ±5 rad/s²."""
        q = rng.uniform(self.lower_rad, self.upper_rad, size=(n_samples, self.n))
        dq = rng.uniform(-_RANDOM_DQ_RAD_S, _RANDOM_DQ_RAD_S, size=(n_samples, self.n))
        ddq = rng.uniform(-_RANDOM_DDQ_RAD_S2, _RANDOM_DDQ_RAD_S2, size=(n_samples, self.n))
        return q, dq, ddq


def compute_base_parameters(
    reg: RobotRegressor, n_samples: int | None = None, seed: int = 0
) -> BaseParameters:
    """Base parameters by pivoted QR of Y stacked over random samples (module docstring)."""
    n_params = 11 * reg.n
    if n_samples is None:
        n_samples = max(100, (4 * n_params) // reg.n)
    rng = np.random.default_rng(seed)
    q, dq, ddq = reg.random_samples(n_samples, rng)
    w = np.vstack([reg.regressor(a, b, c) for a, b, c in zip(q, dq, ddq, strict=True)])
    _, r, piv = linalg.qr(w, mode="economic", pivoting=True)
    diag = np.abs(np.diag(r))
    rank = int(np.sum(diag > RANK_TOLERANCE * diag[0]))
    independent = np.sort(piv[:rank])
    dependent = np.sort(piv[rank:])
    if dependent.size:
        k, *_ = linalg.lstsq(w[:, independent], w[:, dependent])
        k[np.abs(k) < K_CLEAN_TOLERANCE] = 0.0
    else:
        k = np.zeros((rank, 0))
    scale = max(1.0, float(np.max(np.abs(w))))
    err = np.max(np.abs(w[:, independent] @ k - w[:, dependent])) if dependent.size else 0.0
    if err > 1e-7 * scale:  # pragma: no cover - would mean the rank tolerance is wrong
        raise RuntimeError(f"base-parameter regrouping inexact (error {err:.3g})")
    return BaseParameters(
        independent=independent,
        dependent=dependent,
        dependent_in_independent=k,
        names=reg.parameter_names,
    )
