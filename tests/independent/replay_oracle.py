"""The virtual robot's own torque on recorded states: the floor any state-based model meets.

The referee may read the plant (the product never does): the drawn plant of a run
(``truth.toml`` through :func:`sim_bridge.truth.draw`), its MuJoCo arm (masses, inertias,
armature, the viscous damping), its friction law at sliding (:class:`sim_bridge.physics.
JointFriction`, the Stribeck level times the direction) and its cylinders at the logged chamber
pressures (:class:`sim_bridge.physics.AssistCylinders`). Given the states a model is given
(q low-passed zero-phase at the same cutoff as the product's analysis, dq and ddq by central
differences of it) it answers the motor torque those states need: what a model that knew the
plant exactly would predict from them. Where it misses the measured torque, no state-based
model does better with those states (fast transients the states' filter cannot follow, the
inner loop's own dynamics, static friction's held torque).
"""

from __future__ import annotations

from pathlib import Path

import mujoco
import numpy as np
from scipy.signal import butter, sosfiltfilt

from sim_bridge.config import load_sim_config
from sim_bridge.physics import AssistCylinders, JointFriction
from sim_bridge.truth import arm_spec, draw

#: the cutoff the product's analysis filters positions at (control/identification/on_cell.py
#: ANALYSIS_CUTOFF_HZ): the oracle gets states as smooth as the model's [Hz]
STATE_CUTOFF_HZ = 20.0


def smooth_states(
    t: np.ndarray, q: np.ndarray, cutoff_hz: float = STATE_CUTOFF_HZ
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """q low-passed (4th-order Butterworth, forward and backward), dq and ddq its central
    differences; ``t`` evenly spaced."""
    step = float(np.median(np.diff(t)))
    sos = butter(2, cutoff_hz, fs=1.0 / step, output="sos")
    qf = sosfiltfilt(sos, q, axis=0)
    dq = np.gradient(qf, step, axis=0)
    return qf, dq, np.gradient(dq, step, axis=0)


class PlantTorque:
    """The motor torque [N·m] the drawn plant of ``truth_toml`` needs at given states."""

    def __init__(self, truth_toml: Path) -> None:
        self.cfg = draw(load_sim_config(truth_toml))
        self.model = arm_spec(self.cfg).compile()
        self.n = len(self.cfg.friction)
        self.friction = JointFriction(self.cfg.friction, self.cfg.drives.gear_ratio)
        self.model.dof_damping[: self.n] = self.friction.v1
        self.model.dof_frictionloss[:] = 0.0  # friction is added below, as a law
        self.cylinders = AssistCylinders(self.cfg.cylinders.units, self.n)
        self.data = mujoco.MjData(self.model)
        #: the drives' true torque constants and the current sensors' offsets
        self.k_nm_per_a = np.asarray(self.cfg.drives.gain_nm_per_a, dtype=float)
        offset = self.cfg.sensors.current_offset_a
        self.offset_a = np.asarray(offset, dtype=float) if offset else np.zeros(self.n)

    def motor_torque_nm(
        self, q: np.ndarray, dq: np.ndarray, ddq: np.ndarray, p_bar: np.ndarray
    ) -> np.ndarray:
        """(T, n): rigid body (inverse dynamics with armature and viscous damping) plus the
        sliding friction, less the cylinders' torque at ``p_bar`` (T, cylinders)."""
        out = np.empty_like(q)
        d, n = self.data, self.n
        for k in range(q.shape[0]):
            d.qpos[:n], d.qvel[:n], d.qacc[:n] = q[k], dq[k], ddq[k]
            mujoco.mj_inverse(self.model, d)
            level = self.friction.dry_level_nm(q[k], dq[k])
            dry = level * np.sign(dq[k]) + self.friction.v2 * dq[k] * np.abs(dq[k])
            out[k] = d.qfrc_inverse[:n] + dry - self.cylinders.torque_nm(q[k], p_bar[k])
        return out

    def true_torque_nm(self, current_a: np.ndarray) -> np.ndarray:
        """The motor torque reported currents ``current_a`` (T, n) [A] stand for."""
        return self.k_nm_per_a * (current_a - self.offset_a)
