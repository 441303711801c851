"""The simulated robot: MuJoCo rigid bodies, the vendor's inner PI loop, true friction with a
Stribeck drop, assist cylinders whose gas is compressed by their stroke and refilled with a lag,
current sensors with zero offsets, brakes, injected effects and the operator's hand.

Everything here is the plant's own (:mod:`sim_bridge.physics`, :mod:`sim_bridge.truth`, the
arm's MJCF): it imports nothing of the product's model, so a test of the product's model
against the plant can fail when that model is wrong.

Torque balance per joint (eq. (1) plus the cylinders and the hand):

    M(q) ddq + C dq + g(q) + τ_f(q, dq) = K sat(i_c) + T_cyl(q, p) + J(q)ᵀ F_hand + τ_effects

with i_c from eq. (19). MuJoCo supplies M, C, g and integrates. One controller cycle is one
:meth:`Plant.run`: a few servo ticks (1 ms each) with as little Python per tick as the physics
allows:

- the vendor's PI velocity loop, eq. (19), is MuJoCo's: one actuator per joint with force
  K·(K_I·q_r(t) + K_p·dq_r) − K·K_I·q − K·K_p·dq, limited to ±K·i_max (the drive's current
  limit), q_r(t) the controller's reference extrapolated along dq_r (see :func:`_add_drives`);
- dry friction is the smooth law (:meth:`~sim_bridge.physics.JointFriction.torque_nm`,
  evaluated every tick from the tick's velocity, as an applied torque) or, with the truth's
  ``stiction``, MuJoCo's joint friction loss, a constraint that holds a joint
  at rest against any torque up to the static level and opposes sliding with the level of the
  Stribeck curve (:class:`~sim_bridge.physics.JointFriction`), the level set every tick from
  the tick's velocity, so it drops as a joint breaks away; with a reference time of two
  servo ticks and an impedance of 0.99 it is nearly hard: a joint under half its static level
  creeps by hundredths of a mrad/s;
- what changes slowly is evaluated once per cycle from the state at its start and held over
  it: the dry friction's position ripple, the viscous friction as joint damping
  τ_v1 + τ_v2 |dq|, the cylinders' gas and torque, injected effects and the
  hand's force. Per tick there is only the friction, the drives' control input and ``mj_step``.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import mujoco
import numpy as np

from sim_bridge.config import SimConfig
from sim_bridge.effects import EffectSet
from sim_bridge.physics import ATMOSPHERE_BAR, AssistCylinders, JointFriction
from sim_bridge.truth import arm_spec, draw

TOOL_SITE = "tool"


def _add_drives(spec: mujoco.MjSpec, cfg: SimConfig) -> None:
    """One actuator per joint running eq. (19): an affine-bias servo whose control input is
    K·(K_I·q_r + K_p·dq_r) (set every tick by :meth:`Plant.run`), with its force limited to
    the drive's current limit."""
    # Semi-implicit Euler: implicitfast would integrate the loop's velocity gain K·K_p (up to
    # ~4e4 N·m·s/rad) implicitly, which adds h·K·K_p of spurious inertia (~25 kg·m² on J2 at
    # a 1 ms step) to every acceleration; explicit, the loop is stable (h·K·K_p / J < 2).
    spec.option.integrator = mujoco.mjtIntegrator.mjINT_EULER
    k = cfg.drives.gain_nm_per_a
    for j, joint in enumerate(spec.joints):
        act = spec.add_actuator()
        act.name = f"drive{j + 1}"
        act.target = joint.name
        act.trntype = mujoco.mjtTrn.mjTRN_JOINT
        act.gaintype = mujoco.mjtGain.mjGAIN_FIXED
        act.gainprm[0] = 1.0
        act.biastype = mujoco.mjtBias.mjBIAS_AFFINE
        act.biasprm[:3] = [0.0, -k[j] * cfg.inner_loop.ki_a_per_rad[j],
                           -k[j] * cfg.inner_loop.kp_a_s_per_rad[j]]  # fmt: skip
        act.ctrllimited = False
        act.forcelimited = True
        limit = k[j] * cfg.drives.max_current_a[j]
        act.forcerange = [-limit, limit]


class Plant:
    """One robot arm, drawn for ``cfg.plant_seed`` (:mod:`sim_bridge.truth`); :meth:`run` it
    one controller cycle at a time (or :meth:`step` one servo tick). :attr:`cfg` is the truth
    actually drawn."""

    def __init__(self, cfg: SimConfig) -> None:
        cfg = draw(cfg)
        self.cfg = cfg
        spec = arm_spec(cfg)
        _add_drives(spec, cfg)
        self.model = spec.compile()
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
        self.kp = np.array(cfg.inner_loop.kp_a_s_per_rad)
        self.ki = np.array(cfg.inner_loop.ki_a_per_rad)
        #: K·K_I and K·K_p [N·m/rad, N·m·s/rad]: eq. (19)'s gains on torque, for the drives'
        #: control input
        self._k_ki, self._k_kp = self.k_nm_per_a * self.ki, self.k_nm_per_a * self.kp
        self.friction = JointFriction(cfg.friction, cfg.drives.gear_ratio)
        self.model.dof_damping[: self.n] = self.friction.v1
        self.stiction = bool(cfg.stiction)
        if self.stiction:
            # friction loss as stiff as the step allows (MuJoCo's safe minimum: 2 timesteps),
            # its impedance near a hard constraint: half the static level creeps ~0.03 mrad/s
            self.model.dof_solref[: self.n] = [2.0 * cfg.timestep_s, 1.0]
            self.model.dof_solimp[: self.n, :2] = [0.99, 0.99]
            self.model.dof_frictionloss[: self.n] = self.friction.dry_level_nm(
                np.asarray(cfg.initial_q_rad, dtype=float), np.zeros(self.n)
            )
        self.cylinders = AssistCylinders(cfg.cylinders.units, self.n)
        self.rng = np.random.default_rng(cfg.seed)
        self.pressure_bar = np.array(cfg.cylinders.initial_bar, dtype=float)
        self.pressure_set_bar = self.pressure_bar.copy()
        #: each chamber's gas volume over its piston area [m] (inf: an ideal reservoir)
        self._gas_m = self.cylinders.gas_columns_m(self.data.qpos[: self.n])
        offset = cfg.sensors.current_offset_a
        #: the current sensors' zero offsets [A], in every reported current
        self.current_offset_a = np.array(offset, dtype=float) if offset else np.zeros(self.n)
        #: the motor current over the last :meth:`run` [A] (its mean over the servo ticks)
        self.current_a = np.zeros(self.n)
        self._force_sum = np.zeros(self.n)  #: the drives' torque summed over the ticks [N·m]
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
        #: called each cycle with the plant, returns the hand force [N] (world frame)
        self.hand: Callable[[Plant], np.ndarray] | None = None
        #: the drives' torque [N·m], mean over the last :meth:`run`
        self.tau_motor_nm = np.zeros(self.n)
        mujoco.mj_forward(self.model, self.data)

    def _encoder(self, q: np.ndarray) -> np.ndarray:
        if not self._has_encoder:
            return q.copy()
        return np.round(q / self.encoder_step_rad) * self.encoder_step_rad

    def _sample(self, q_before_rad: np.ndarray, dt: float) -> None:
        """The drive's position and velocity at the end of the last servo tick, which began
        at ``q_before_rad``."""
        q = self._encoder(self.data.qpos[: self.n])
        if self._has_encoder:
            self.sample_dq_rad_s = (q - self._encoder(q_before_rad)) / dt
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
        mean = self._force_sum / (self.k_nm_per_a * max(self._current_ticks, 1))
        self._force_sum = np.zeros(self.n)
        self._current_ticks = 0
        noise = self.rng.normal(0.0, self.cfg.sensors.current_noise_a, self.n)
        return mean + self.current_offset_a + noise

    def _pressure_step(self, dt: float) -> None:
        """The chambers' gas over ``dt``: isothermal with the rod's motion since the last
        update, then the regulator's first-order lag towards the set-point."""
        gas = self.cylinders.gas_columns_m(self.data.qpos[: self.n])
        p, p_set, before = self.pressure_bar, self.pressure_set_bar, self._gas_m
        alpha = min(dt / self.cfg.cylinders.time_constant_s, 1.0)
        for k, now in enumerate(gas):
            if now != math.inf:
                p[k] = (p[k] + ATMOSPHERE_BAR) * before[k] / now - ATMOSPHERE_BAR
            p[k] += alpha * (p_set[k] - p[k])
        self._gas_m = gas

    def step(
        self,
        q_cmd_rad: np.ndarray | None,
        dq_cmd_rad_s: np.ndarray | None,
        brakes_released: bool = False,
    ) -> None:
        """Advance one servo tick following ``q_cmd_rad`` / ``dq_cmd_rad_s`` (both ``None``:
        servo off); :meth:`run` with one tick and the reference taken now."""
        reference = None
        if q_cmd_rad is not None and dq_cmd_rad_s is not None:
            reference = (q_cmd_rad, dq_cmd_rad_s, self.t_s)
        self.run(1, reference, brakes_released)

    def run(
        self,
        ticks: int,
        reference: tuple[np.ndarray, np.ndarray, float] | None,
        brakes_released: bool = False,
    ) -> None:
        """Advance ``ticks`` servo ticks (one controller cycle). ``reference`` is what the
        inner loop follows, (q_r [rad], dq_r [rad/s], t_r [s]): the position q_r + dq_r·(t -
        t_r) at time t. ``None`` means servo off: the brakes hold the joints, unless
        ``brakes_released`` (the brake-release switch held with the servo off): then the arm
        moves under gravity, the cylinders, friction and the hand, with no motor torque."""
        dt = self.cfg.timestep_s
        self._pressure_step(ticks * dt)
        model, d, n = self.model, self.data, self.n
        if reference is None and not brakes_released:
            # Brakes engaged: joints locked, motor unpowered, the hand can't move it.
            self.brakes = True
            self.hand_force_n = np.zeros(3)
            self.current_a[:] = 0.0
            self.tau_motor_nm[:] = 0.0
            self._current_ticks += ticks
            d.qvel[:] = 0.0
            self.sample_dq_rad_s = np.zeros(n)
            d.time += ticks * dt
            mujoco.mj_kinematics(model, d)
            self.effects.advance(self, ticks * dt)
            return
        self.brakes = False
        q, dq = d.qpos[:n], d.qvel[:n]  # views: they follow the ticks
        friction, coulomb = self.friction, self.friction.coulomb_level(q)
        stiction = self.stiction
        if stiction:
            dry = model.dof_frictionloss[:n]  # a view: MuJoCo reads it every step
            model.dof_damping[:n] = friction.damping_nm_s_per_rad(dq)
        tau_cyl = self.cylinders.torque_nm(q, self.pressure_bar)
        tau_eff = self.effects.torque(self, q, dq)
        self.hand_force_n = self.hand(self) if self.hand is not None else np.zeros(3)
        held = tau_cyl + tau_eff  # over the cycle
        d.xfrc_applied[:] = 0.0
        if self.hand_force_n.any():
            arm = d.site_xpos[self.tool_site] - d.xipos[self.last_body]
            d.xfrc_applied[self.last_body, :3] = self.hand_force_n
            d.xfrc_applied[self.last_body, 3:] = np.cross(arm, self.hand_force_n)
        force = np.zeros(n)
        applied = d.qfrc_applied[:n]
        applied[:] = held
        history = self.effects.history if self.effects.delay_steps else None
        servo = reference is not None
        if servo:
            model.opt.disableflags &= ~int(mujoco.mjtDisableBit.mjDSBL_ACTUATION)
            q_r, dq_r, t_r = reference
            # eq. (19) as the actuator's control input: K (K_I q_r(t) + K_p dq_r)
            at_t_r = self._k_ki * (q_r - dq_r * t_r) + self._k_kp * dq_r
            slope = self._k_ki * dq_r
        else:
            model.opt.disableflags |= int(mujoco.mjtDisableBit.mjDSBL_ACTUATION)
        ctrl, act_force = d.ctrl, d.actuator_force
        for tick in range(ticks):
            if tick == ticks - 1:
                q_before = q.copy()
            if stiction:
                friction.stribeck_into(dq, coulomb, dry)
            else:
                np.subtract(held, friction.torque_nm(dq, coulomb), out=applied)
            if servo:
                np.add(at_t_r, slope * d.time, out=ctrl)
            mujoco.mj_step(model, d)
            if servo:
                force += act_force
            if history is not None:
                history.append((d.qpos[:n].copy(), d.qvel[:n].copy()))
        self._force_sum += force
        self._current_ticks += ticks
        self.tau_motor_nm = force / ticks
        self.current_a = self.tau_motor_nm / self.k_nm_per_a
        self._sample(q_before, dt)
        self.effects.advance(self, ticks * dt)
