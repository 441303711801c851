"""The simulated robot: MuJoCo rigid bodies, the vendor's inner PI loop, true friction,
assist cylinders whose gas is compressed by their stroke and refilled with a lag, current
sensors with zero offsets, brakes, injected effects and the operator's hand.

Everything here is the plant's own (:mod:`sim_bridge.physics`, :mod:`sim_bridge.truth`, the
arm's MJCF): it imports nothing of the product's model, so a test of the product's model
against the plant can fail when that model is wrong.

Torque balance per joint (eq. (1) plus the cylinders and the hand):

    M(q) ddq + C dq + g(q) + τ_f(q, dq) = K sat(i_c) + T_cyl(q, p) + J(q)ᵀ F_hand + τ_effects

with i_c from eq. (19). MuJoCo supplies M, C, g (``qfrc_bias``) and integrates; everything on
the right side and the friction enter through ``qfrc_applied``; the hand force enters through
``xfrc_applied`` of the last link at the tool point.
"""

from __future__ import annotations

from collections.abc import Callable

import mujoco
import numpy as np

from sim_bridge.config import SimConfig
from sim_bridge.effects import EffectSet
from sim_bridge.physics import ATMOSPHERE_BAR, AssistCylinders, JointFriction
from sim_bridge.truth import arm_spec, draw

TOOL_SITE = "tool"


class Plant:
    """One robot arm, drawn for ``cfg.plant_seed`` (:mod:`sim_bridge.truth`); call :meth:`step`
    once per physics timestep. :attr:`cfg` is the truth actually drawn."""

    def __init__(self, cfg: SimConfig) -> None:
        cfg = draw(cfg)
        self.cfg = cfg
        self.model = arm_spec(cfg).compile()
        self.n = int(self.model.njnt)
        #: joint limits [rad], (n,) each
        self.lower_rad = self.model.jnt_range[: self.n, 0].copy()
        self.upper_rad = self.model.jnt_range[: self.n, 1].copy()
        self.effects = EffectSet(cfg.effects, self.model, self.n, cfg.timestep_s)
        self.data = mujoco.MjData(self.model)
        self.data.qpos[:] = cfg.initial_q_rad
        self.tool_site = mujoco.mj_name2id(self.model, mujoco.mjtObj.mjOBJ_SITE, TOOL_SITE)
        self.last_body = self.model.site_bodyid[self.tool_site]
        self.k_nm_per_a = np.array(cfg.drives.gain_nm_per_a)
        self.i_max_a = np.array(cfg.drives.max_current_a)
        self.kp = np.array(cfg.inner_loop.kp_a_s_per_rad)
        self.ki = np.array(cfg.inner_loop.ki_a_per_rad)
        self.friction = JointFriction(cfg.friction, cfg.drives.gear_ratio)
        self.cylinders = AssistCylinders(cfg.cylinders.units, self.n)
        self.rng = np.random.default_rng(cfg.seed)
        self.pressure_bar = np.array(cfg.cylinders.initial_bar, dtype=float)
        self.pressure_set_bar = self.pressure_bar.copy()
        #: each chamber's gas volume over its piston area [m] (inf: an ideal reservoir)
        self._gas_m = self.cylinders.gas_columns_m(self.data.qpos[: self.n])
        offset = cfg.sensors.current_offset_a
        #: the current sensors' zero offsets [A], in every reported current
        self.current_offset_a = np.array(offset, dtype=float) if offset else np.zeros(self.n)
        self.current_a = np.zeros(self.n)
        self._current_sum = np.zeros(self.n)
        self._current_ticks = 0
        self.brakes = True
        self.hand_force_n = np.zeros(3)
        #: joint-side encoder step [rad] (0: exact), :class:`SensorTruth.encoder_bits`
        bits = cfg.sensors.encoder_bits
        ratio = np.asarray(cfg.drives.gear_ratio, dtype=float)
        self.encoder_step_rad = 2.0 * np.pi / (2.0**bits * ratio) if bits else np.zeros(self.n)
        self._has_encoder = bits > 0
        #: position and velocity as the drive has them at the end of the last servo tick
        #: [rad], [rad/s]: the encoder's position, and its difference over that tick; the
        #: current a drive reports is its mean over the communication cycle (PROTOCOL.md §2.1)
        self.sample_q_rad = self._encoder(self.data.qpos[: self.n])
        self.sample_dq_rad_s = np.zeros(self.n)
        #: called each step with the plant, returns the hand force [N] (world frame)
        self.hand: Callable[[Plant], np.ndarray] | None = None
        self.tau_motor_nm = np.zeros(self.n)
        mujoco.mj_forward(self.model, self.data)

    def _encoder(self, q: np.ndarray) -> np.ndarray:
        if not self._has_encoder:
            return q.copy()
        return np.round(q / self.encoder_step_rad) * self.encoder_step_rad

    def _sample(self, dt: float) -> None:
        """The drive's position and velocity at the end of this servo tick."""
        q = self._encoder(self.data.qpos[: self.n])
        if self._has_encoder:
            self.sample_dq_rad_s = (q - self.sample_q_rad) / dt
        else:
            self.sample_dq_rad_s = self.data.qvel[: self.n].copy()
        self.sample_q_rad = q

    @property
    def t_s(self) -> float:
        return float(self.data.time)

    @property
    def q_rad(self) -> np.ndarray:
        return self.data.qpos[: self.n].copy()

    @property
    def dq_rad_s(self) -> np.ndarray:
        return self.data.qvel[: self.n].copy()

    def tool_position_m(self) -> np.ndarray:
        return self.data.site_xpos[self.tool_site].copy()

    def tool_velocity_m_s(self) -> np.ndarray:
        jac = np.zeros((3, self.model.nv))
        mujoco.mj_jacSite(self.model, self.data, jac, None, self.tool_site)
        return jac @ self.data.qvel

    def measured_pressure_bar(self) -> np.ndarray:
        return self.pressure_bar + self.rng.normal(0.0, self.cfg.cylinders.noise_bar, 2)

    def measured_current_a(self) -> np.ndarray:
        """The current averaged over the servo ticks since the last call, plus noise [A]; the
        drive's current filter, as the feedback frame reports it (PROTOCOL.md §2.1). Resets
        the average."""
        mean = self._current_sum / max(self._current_ticks, 1)
        self._current_sum = np.zeros(self.n)
        self._current_ticks = 0
        noise = self.rng.normal(0.0, self.cfg.sensors.current_noise_a, self.n)
        return mean + self.current_offset_a + noise

    def _pressure_step(self, dt: float) -> None:
        """The chambers' gas over one timestep: isothermal with the rod's motion since the
        last step, then the regulator's first-order lag towards the set-point."""
        gas = self.cylinders.gas_columns_m(self.data.qpos[: self.n])
        closed = np.isfinite(gas)
        if closed.any():
            p_abs = self.pressure_bar[closed] + ATMOSPHERE_BAR
            self.pressure_bar[closed] = p_abs * self._gas_m[closed] / gas[closed] - ATMOSPHERE_BAR
        self._gas_m = gas
        alpha = dt / self.cfg.cylinders.time_constant_s
        self.pressure_bar += alpha * (self.pressure_set_bar - self.pressure_bar)

    def step(
        self,
        q_cmd_rad: np.ndarray | None,
        dq_cmd_rad_s: np.ndarray | None,
        brakes_released: bool = False,
    ) -> None:
        """Advance one timestep. ``None`` commands mean servo off: the brakes hold the joints,
        unless ``brakes_released`` (the brake-release switch held with the servo off): then
        the arm moves under gravity, the cylinders, friction and the hand, with no motor
        torque."""
        dt = self.cfg.timestep_s
        self._pressure_step(dt)
        d = self.data
        servo = q_cmd_rad is not None and dq_cmd_rad_s is not None
        if not servo and not brakes_released:
            # Brakes engaged: joints locked, motor unpowered, the hand can't move it.
            self.brakes = True
            self.hand_force_n = np.zeros(3)
            self.current_a[:] = 0.0
            self._current_ticks += 1
            self.tau_motor_nm[:] = 0.0
            d.qvel[:] = 0.0
            self._sample(dt)
            d.time += dt
            mujoco.mj_kinematics(self.model, d)
            self.effects.advance(self, dt)
            return
        self.brakes = False
        q, dq = d.qpos[: self.n], d.qvel[: self.n]
        if servo:
            # eq. (19) on what the drive measures: its encoder's position and velocity
            q_m, dq_m = self.sample_q_rad, self.sample_dq_rad_s
            i_c = -self.kp * (dq_m - dq_cmd_rad_s) - self.ki * (q_m - q_cmd_rad)
            self.current_a = np.clip(i_c, -self.i_max_a, self.i_max_a)
        else:
            self.current_a = np.zeros(self.n)
        self._current_sum += self.current_a
        self._current_ticks += 1
        self.tau_motor_nm = self.k_nm_per_a * self.current_a
        tau_f = self.friction(q, dq)
        tau_cyl = self.cylinders.torque_nm(q, self.pressure_bar)
        tau_eff = self.effects.torque(self, q, dq)
        self.hand_force_n = self.hand(self) if self.hand is not None else np.zeros(3)
        d.qfrc_applied[: self.n] = self.tau_motor_nm - tau_f + tau_cyl + tau_eff
        d.xfrc_applied[:] = 0.0
        if np.any(self.hand_force_n):
            arm = d.site_xpos[self.tool_site] - d.xipos[self.last_body]
            d.xfrc_applied[self.last_body, :3] = self.hand_force_n
            d.xfrc_applied[self.last_body, 3:] = np.cross(arm, self.hand_force_n)
        mujoco.mj_step(self.model, d)
        self._sample(dt)
        self.effects.advance(self, dt)
