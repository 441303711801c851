"""Effects the simulator can inject that the declared model does not contain.

They exist to test identification and residual analysis: each is configured per test in the
simulator's private config (``[[effects]]``), never visible to ``control/``. Signs follow the
plant's right-hand side: a returned torque *drives* the joint. An effect with ``after_s``
appears only from that simulated time on, one with ``after_onset_s`` that long after teaching
onset (the first cycle following a non-hold command), one with ``after_motion_s`` once the arm
has been in motion (some joint faster than :data:`MOTION_RAD_S`) for that long in total: an
excitation plan's moving time is known in advance where its start is not, so this mounts a
tool between a plan's training and test runs (in their pause).
"""

from __future__ import annotations

from collections import deque
from typing import Any

import mujoco
import numpy as np

from gateway.config import require

#: A joint faster than this counts as the arm being in motion (``after_motion_s``) [rad/s].
MOTION_RAD_S = 0.01


def _add_point_mass(model: mujoco.MjModel, body: int, mass_kg: float, pos_m: np.ndarray) -> None:
    """Rigidly attach a point mass at ``pos_m`` (body frame) to ``body``, in place."""
    m0 = float(model.body_mass[body])
    c0 = model.body_ipos[body].copy()
    rot = np.zeros(9)
    mujoco.mju_quat2Mat(rot, model.body_iquat[body])
    rot = rot.reshape(3, 3)
    i0 = rot @ np.diag(model.body_inertia[body]) @ rot.T  # about c0, body axes
    m = m0 + mass_kg
    c = (m0 * c0 + mass_kg * pos_m) / m

    def shift(mass: float, r: np.ndarray) -> np.ndarray:
        return mass * (np.dot(r, r) * np.eye(3) - np.outer(r, r))

    inertia = i0 + shift(m0, c0 - c) + shift(mass_kg, pos_m - c)
    evals, evecs = np.linalg.eigh(inertia)
    if np.linalg.det(evecs) < 0:
        evecs[:, 0] *= -1
    quat = np.zeros(4)
    mujoco.mju_mat2Quat(quat, evecs.reshape(-1))
    model.body_mass[body] = m
    model.body_ipos[body] = c
    model.body_iquat[body] = quat
    model.body_inertia[body] = evals


class EffectSet:
    """All configured effects; ``torque`` is called every physics step."""

    def __init__(
        self,
        effects: tuple[dict[str, Any], ...],
        model: mujoco.MjModel,
        n: int,
        timestep_s: float,
    ) -> None:
        self.torque_effects: list[dict[str, Any]] = []
        self.pending_payloads: list[tuple[dict[str, Any], int, float, np.ndarray]] = []
        self._model = model
        self.onset_s: float | None = None  #: set by the simulator at teaching onset
        self.motion_s = 0.0  #: simulated time spent in motion so far [s]
        self.delay_steps = 0
        for i, eff in enumerate(effects):
            where = f"[[effects]][{i}] ({eff.get('kind')})"
            kind = eff["kind"]
            if kind == "payload":
                site = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_SITE, "tool")
                body = int(model.site_bodyid[site])
                pos = model.site_pos[site] + np.asarray(eff.get("com_m", (0.0, 0.0, 0.0)))
                mass = float(eff["mass_kg"])
                require(mass > 0, where, "mass_kg must be > 0")
                if {"after_s", "after_onset_s", "after_motion_s"} & set(eff):
                    self.pending_payloads.append((eff, body, mass, pos))
                else:
                    _add_point_mass(model, body, mass, pos)
            elif kind == "time_delay":
                delay = float(eff["delay_s"])
                require(0 < delay < 0.1, where, "delay_s must be in (0, 0.1)")
                self.delay_steps = round(delay / timestep_s)
            else:
                j = int(eff["joint"]) - 1
                require(0 <= j < n, where, f"joint must be 1..{n}")
                self.torque_effects.append({**eff, "_j": j})
        #: the encoders' (q, dq) of the last ticks, appended by the plant every tick when a
        #: delay is injected
        self.history: deque[tuple[np.ndarray, np.ndarray]] = deque(
            maxlen=max(self.delay_steps, 1) + 1
        )

    def torque(
        self, t_s: float, tau_motor_nm: np.ndarray, q: np.ndarray, dq: np.ndarray
    ) -> np.ndarray:
        """The effects' joint torque at simulated time ``t_s`` [s], with the motors' torque
        ``tau_motor_nm`` (what load-dependent friction and a coupling scale with)."""
        tau = np.zeros(len(q))
        for eff in self.torque_effects:
            if not self._active(eff, t_s):
                continue  # not there yet (e.g. a hose clipped on after the training runs)
            j, kind = eff["_j"], eff["kind"]
            if kind == "spring":
                tau[j] -= float(eff["k_nm_per_rad"]) * (q[j] - float(eff.get("q0_rad", 0.0)))
            elif kind == "position_ripple":
                c = float(eff["cycles_per_rev"])
                tau[j] += float(eff["amplitude_nm"]) * np.sin(
                    c * q[j] + float(eff.get("phase_rad", 0.0))
                )
            elif kind == "stribeck":
                v = float(eff["velocity_rad_s"])
                tau[j] -= (
                    float(eff["amplitude_nm"]) * np.exp(-((dq[j] / v) ** 2)) * np.tanh(dq[j] / 1e-3)
                )
            elif kind == "load_dependent_friction":
                tau[j] -= float(eff["coefficient"]) * abs(tau_motor_nm[j]) * np.tanh(dq[j] / 0.01)
            elif kind == "thermal_drift":
                tau[j] += float(eff["rate_nm_per_s"]) * t_s
            elif kind == "wrist_coupling":
                k = int(eff["from_joint"]) - 1
                tau[j] -= float(eff["coefficient"]) * tau_motor_nm[k]
        return tau

    def _active(self, eff: dict[str, Any], t_s: float) -> bool:
        if "after_onset_s" in eff:
            return self.onset_s is not None and t_s - self.onset_s >= float(eff["after_onset_s"])
        if "after_motion_s" in eff:
            return self.motion_s >= float(eff["after_motion_s"])
        return t_s >= float(eff.get("after_s", 0.0))

    def advance(self, t_s: float, dq: np.ndarray, dt: float) -> None:
        """Once per run of the plant over ``dt`` [s], ending at ``t_s`` with joint velocity
        ``dq``: the time in motion, and payloads due."""
        if np.abs(dq).max() > MOTION_RAD_S:
            self.motion_s += dt
        if not self.pending_payloads:
            return
        for item in [p for p in self.pending_payloads if self._active(p[0], t_s)]:
            self.pending_payloads.remove(item)
            _, body, mass, pos = item
            _add_point_mass(self._model, body, mass, pos)  # the gun is mounted now

    def measured_kinematics(self, q: np.ndarray, dq: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Joint position and velocity as the encoders report them, from the plant's sampled
        ``q``, ``dq`` (delayed if injected)."""
        if self.delay_steps and len(self.history) == self.history.maxlen:
            return self.history[0]
        return q, dq
