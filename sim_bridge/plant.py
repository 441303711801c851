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
  limit), q_r(t) the controller's reference extrapolated along dq_r, ramped by MuJoCo as the
  actuator's integrator state (see :func:`_add_drives`);
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
  hand's force. Per tick there is only the friction level, ``mj_step`` and the sum of the
  drives' torque for the cycle's mean current.
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
_NO_ACTUATION = int(mujoco.mjtDisableBit.mjDSBL_ACTUATION)
#: cycles of sensor noise drawn at a time (:meth:`Plant._unit_noise`)
NOISE_BLOCK_ROWS = 256


def _add_drives(spec: mujoco.MjSpec, cfg: SimConfig) -> None:
    """One actuator per joint running eq. (19): an affine-bias servo whose input is
    u = K·(K_I·q_r(t) + K_p·dq_r), with its force limited to the drive's current limit.

    u is the actuator's activation, an integrator whose control is its slope K·K_I·dq_r:
    :meth:`Plant.run` sets both once per cycle, and MuJoCo ramps u along the extrapolated
    reference q_r(t) = q_r + dq_r (t - t_r) tick by tick (Euler, the force of a tick from
    its start's activation, as a per-tick control input would give it)."""
    # Semi-implicit Euler: implicitfast would integrate the loop's velocity gain K·K_p (up to
    # ~4e4 N·m·s/rad) implicitly, which adds h·K·K_p of spurious inertia (~25 kg·m² on J2 at
    # a 1 ms step) to every acceleration; explicit, the loop is stable (h·K·K_p / J < 2).
    spec.option.integrator = mujoco.mjtIntegrator.mjINT_EULER
    # No geom collides (contype 0): skip the collision stage of every step.
    spec.option.disableflags |= int(mujoco.mjtDisableBit.mjDSBL_CONTACT)
    k = cfg.drives.gain_nm_per_a
    for j, joint in enumerate(spec.joints):
        act = spec.add_actuator()
        act.name = f"drive{j + 1}"
        act.target = joint.name
        act.trntype = mujoco.mjtTrn.mjTRN_JOINT
        act.dyntype = mujoco.mjtDyn.mjDYN_INTEGRATOR
        act.actlimited = False
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
        self._noise, self._noise_row = np.zeros((0, self.n + 2)), 0  #: see _unit_noise
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
        #: the arm stands on its brakes (every joint locked)
        self.brakes = True
        brakes = cfg.brakes
        #: each joint's brake torque [N·m] (None: ideal brakes, locked at once) and the time
        #: from a power cut to it [s] (BrakesTruth)
        self._brake_nm = np.array(brakes.torque_nm, dtype=float) if brakes.torque_nm else None
        self._brake_engage_s = float(brakes.engage_s)
        #: sim time the power went off (None: powered or released); joints the brakes hold
        #: and where; each joint's velocity one tick ago (a brake locks at its zero crossing)
        self._power_off_s: float | None = -math.inf
        self._locked = np.ones(self.n, dtype=bool)
        self._lock_q = np.array(cfg.initial_q_rad, dtype=float)
        self._prev_dq = np.zeros(self.n)
        self.hand_force_n = np.zeros(3)
        #: joint-side encoder step [rad] (0: exact), :class:`SensorTruth.encoder_bits`
        bits = cfg.sensors.encoder_bits
        ratio = np.asarray(cfg.drives.gear_ratio, dtype=float)
        self.encoder_step_rad = 2.0 * np.pi / (2.0**bits * ratio) if bits else np.zeros(self.n)
        self._counts_per_rad = 1.0 / self.encoder_step_rad if bits else np.zeros(self.n)
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
        # Views of MuJoCo's buffers (fixed for the model's life), so a cycle does not look
        # them up again: the joints' position and velocity, their friction loss and damping,
        # the applied joint torques, the hand's wrench on the last body, the drives.
        m, d, n = self.model, self.data, self.n
        self._q = d.qpos[:n]
        self.dq_view = d.qvel[:n]  #: the joints' velocity [rad/s], a view that follows the ticks
        self._frictionloss, self._damping = m.dof_frictionloss[:n], m.dof_damping[:n]
        self._applied = d.qfrc_applied[:n]
        self._hand_wrench = d.xfrc_applied[self.last_body]
        #: joint torques [N·m] a scorer adds over each :meth:`run` (the inertia floor's ideal
        #: orientation lock, sim_bridge/baseline.py); None: none
        self.external_torque: Callable[[Plant], np.ndarray] | None = None
        self._act, self._ctrl, self._act_force = d.act, d.ctrl, d.actuator_force
        self._opt = m.opt
        self._hand_on = False  #: the hand's wrench is on the last body
        self._actuation_on = not (m.opt.disableflags & _NO_ACTUATION)
        mujoco.mj_forward(self.model, self.data)

    def _actuation(self, on: bool) -> None:
        """Drives powered (servo on) or not: MuJoCo's actuation stage on or off."""
        if on != self._actuation_on:
            if on:
                self._opt.disableflags &= ~_NO_ACTUATION
            else:
                self._opt.disableflags |= _NO_ACTUATION
            self._actuation_on = on

    def _encoder(self, q: np.ndarray) -> np.ndarray:
        if not self._has_encoder:
            return q.copy()
        counts = np.multiply(q, self._counts_per_rad)
        np.rint(counts, out=counts)
        return np.multiply(counts, self.encoder_step_rad, out=counts)

    def _sample(self, q_before_rad: np.ndarray, dt: float) -> None:
        """The drive's position and velocity at the end of the last servo tick, which began
        at ``q_before_rad``."""
        q = self._encoder(self._q)
        if self._has_encoder:
            dq = self._encoder(q_before_rad)
            np.subtract(q, dq, out=dq)
            dq /= dt
            self.sample_dq_rad_s = dq
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

    def _unit_noise(self) -> np.ndarray:
        """The next row of standard normal draws, (n + 2,): the current sensors', then the
        pressure transmitters'. Drawn 256 cycles at a time: one generator call per cycle cost
        more than the draws."""
        if self._noise_row >= len(self._noise):
            self._noise = self.rng.standard_normal((NOISE_BLOCK_ROWS, self.n + 2))
            self._noise_row = 0
        row = self._noise[self._noise_row]
        self._noise_row += 1
        return row

    def measured_pressure_bar(self) -> np.ndarray:
        return self.pressure_bar + self.cfg.cylinders.noise_bar * self._unit_noise()[self.n :]

    def measured_current_a(self) -> np.ndarray:
        """The current averaged over the servo ticks since the last call, plus noise [A]; the
        drive's current filter, as the feedback frame reports it (PROTOCOL.md §2.1). Resets
        the average."""
        mean = self._force_sum / (self.k_nm_per_a * max(self._current_ticks, 1))
        self._force_sum = np.zeros(self.n)
        self._current_ticks = 0
        mean += self.current_offset_a
        mean += self.cfg.sensors.current_noise_a * self._unit_noise()[: self.n]
        return mean

    def _pressure_step(self, dt: float, gas: list[float]) -> None:
        """The chambers' gas over ``dt``, now at ``gas`` (:meth:`AssistCylinders.arms_and_gas`):
        isothermal with the rod's motion since the last update, then the regulator's
        first-order lag towards the set-point."""
        p, p_set = self.pressure_bar.tolist(), self.pressure_set_bar.tolist()
        alpha = min(dt / self.cfg.cylinders.time_constant_s, 1.0)
        for k, (now, before) in enumerate(zip(gas, self._gas_m, strict=True)):
            if now != math.inf:
                p[k] = (p[k] + ATMOSPHERE_BAR) * before / now - ATMOSPHERE_BAR
            p[k] += alpha * (p_set[k] - p[k])
        self.pressure_bar[:] = p
        self._gas_m = gas

    def step(
        self,
        q_cmd_rad: np.ndarray | None,
        dq_cmd_rad_s: np.ndarray | None,
        brakes_released: bool = False,
        power_cut: bool = False,
    ) -> None:
        """Advance one servo tick following ``q_cmd_rad`` / ``dq_cmd_rad_s`` (both ``None``:
        servo off); :meth:`run` with one tick and the reference taken now."""
        reference = None
        if q_cmd_rad is not None and dq_cmd_rad_s is not None:
            reference = (q_cmd_rad, dq_cmd_rad_s, self.t_s)
        self.run(1, reference, brakes_released, power_cut)

    def _begin_braking(self, power_cut: bool) -> None:
        """The power goes off now: on a cut (``power_cut``, stop category 0) the brakes bite
        after their engagement time, else they were closed while the drives held (a servo-off
        the host asked for: a joint at rest is locked at once, a moving one braked)."""
        q, dq = self._q, self.dq_view
        self._power_off_s = self.data.time - (0.0 if power_cut else self._brake_engage_s)
        self._lock_q[:] = q
        self._prev_dq[:] = dq
        if self._brake_nm is None:
            self._locked[:] = True  # ideal brakes
        else:
            self._locked[:] = False if power_cut else (dq == 0.0)

    def _brake_torque(self, applied: np.ndarray) -> None:
        """Add the engaged brakes' torque, against each free joint's motion, to ``applied``."""
        if self.data.time - self._power_off_s < self._brake_engage_s:
            return
        assert self._brake_nm is not None
        tau = -self._brake_nm * np.sign(self.dq_view)
        tau[self._locked] = 0.0
        applied += tau

    def _brake_locks(self) -> None:
        """After a tick: a braked joint whose velocity reached or crossed zero is locked;
        locked joints stay where they were locked."""
        q, dq = self._q, self.dq_view
        if self.data.time - self._power_off_s >= self._brake_engage_s:
            stopped = ~self._locked & (dq * self._prev_dq <= 0.0)
            if stopped.any():
                self._locked |= stopped
                self._lock_q[stopped] = q[stopped]
            locked = self._locked
            q[locked] = self._lock_q[locked]
            dq[locked] = 0.0
        self._prev_dq[:] = dq

    def run(
        self,
        ticks: int,
        reference: tuple[np.ndarray, np.ndarray, float] | None,
        brakes_released: bool = False,
        power_cut: bool = False,
    ) -> None:
        """Advance ``ticks`` servo ticks (one controller cycle). ``reference`` is what the
        inner loop follows, (q_r [rad], dq_r [rad/s], t_r [s]): the position q_r + dq_r·(t -
        t_r) at time t. ``None`` means servo off: the brakes hold the joints, unless
        ``brakes_released`` (the brake-release switch held with the servo off): then the arm
        moves under gravity, the cylinders, friction and the hand, with no motor torque.

        The brakes (``[brakes]``, :class:`~sim_bridge.config.BrakesTruth`): when the servo
        goes off with ``power_cut`` (the controller's fault or e-stop, stop category 0) the arm
        moves freely for the engagement time, then each brake slows its joint with its torque
        until the joint's velocity reaches zero, and locks it there; otherwise the brakes were
        closed while the drives held, and bite at once. A load over a brake's torque keeps its
        joint moving."""
        dt = self.cfg.timestep_s
        model, d, n = self.model, self.data, self.n
        arms, gas = self.cylinders.arms_and_gas(d.qpos[:n].tolist())
        self._pressure_step(ticks * dt, gas)
        braking = reference is None and not brakes_released
        if not braking:
            self._power_off_s = None
        elif self._power_off_s is None:
            self._begin_braking(power_cut)
        if braking and self._locked.all():
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
            self.effects.advance(self.t_s, self.dq_view, ticks * dt)
            return
        self.brakes = False
        q, dq = self._q, self.dq_view  # views: they follow the ticks
        friction, coulomb = self.friction, self.friction.coulomb_level(q)
        stiction = self.stiction
        if stiction:
            dry = self._frictionloss  # MuJoCo reads it every step
            self._damping[:] = friction.damping_nm_s_per_rad(dq)
        held = self.cylinders.torque_from_arms(arms, self.pressure_bar.tolist())  # over the cycle
        if self.effects.torque_effects:
            held += self.effects.torque(self.t_s, self.tau_motor_nm, q, dq)
        if self.external_torque is not None:
            held += self.external_torque(self)
        hand = self.hand(self) if self.hand is not None else None
        if hand is not None and hand.any():
            self.hand_force_n, self._hand_on = hand, True
            ax, ay, az = (d.site_xpos[self.tool_site] - d.xipos[self.last_body]).tolist()
            fx, fy, fz = hand.tolist()
            # the force at the tool point, and its moment about the body's centre of mass
            self._hand_wrench[:] = (fx, fy, fz, ay * fz - az * fy, az * fx - ax * fz,
                                    ax * fy - ay * fx)  # fmt: skip
        elif self._hand_on:
            self.hand_force_n, self._hand_on = np.zeros(3), False
            self._hand_wrench[:] = 0.0
        force = np.zeros(n)
        applied = self._applied
        applied[:] = held
        history = self.effects.history if self.effects.delay_steps else None
        servo = reference is not None
        self._actuation(servo)
        if servo:
            q_r, dq_r, t_r = reference
            # eq. (19)'s input K (K_I q_r(t) + K_p dq_r) now, ramped by MuJoCo (_add_drives)
            act = np.multiply(dq_r, d.time - t_r, out=self._act)
            act += q_r
            act *= self._k_ki
            act += self._k_kp * dq_r
            np.multiply(self._k_ki, dq_r, out=self._ctrl)
        act_force = self._act_force
        for tick in range(ticks):
            if tick == ticks - 1:
                q_before = q.copy()
            if stiction:
                friction.stribeck_into(dq, coulomb, dry)
            else:
                np.subtract(held, friction.torque_nm(dq, coulomb), out=applied)
            if braking:
                if stiction:
                    applied[:] = held
                self._brake_torque(applied)
            mujoco.mj_step(model, d)
            if braking:
                self._brake_locks()
            if servo:
                force += act_force
            if history is not None:
                history.append((d.qpos[:n].copy(), d.qvel[:n].copy()))
        self._force_sum += force
        self._current_ticks += ticks
        self.tau_motor_nm = force / ticks
        self.current_a = self.tau_motor_nm / self.k_nm_per_a
        self._sample(q_before, dt)
        self.effects.advance(self.t_s, self.dq_view, ticks * dt)
