"""The zero-moment lead-through law (:class:`ZeroMomentController`), free of I/O.

For every JointState it computes the torque that makes the arm weightless and frictionless
(gravity + friction − cylinder assist, eq. (1) without the operator), adds a little damping and
soft joint limits, and turns it into a position/velocity command with eq. (21). The control
process (control/process.py) runs it; the admittance law (control/admittance_law.py) is built
on it.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from typing import Any

import numpy as np

from control import _rt
from control._rt import HoldAverage, OmegaAdaptation, OuterLoop, PaperAdaptation
from control.config import ControlConfig
from control.declared_model import DeclaredModel
from control.load_check import REST_RAD_S
from control.rt_tables import chain_table, to_json
from gateway.errors import ConfigError, MessageError
from gateway.guide_modes import GUIDE_AXES
from gateway.message_factories import make_joint_command
from gateway.messages import FLAG_PREV_COAST, FLAG_PREV_HOLD, JointCommand, JointState
from gateway.robot.description import RobotDescription

#: the delay predictor's M(q)⁻¹ is recomputed after a joint moved this much [rad]
INERTIA_STEP_RAD = 0.02
#: the tool speed limit's Jacobians are recomputed once a joint moved this far [rad]: over
#: it a Jacobian changes by about a per cent (tests/unit/test_zero_moment_cycle.py), well
#: inside the limit's 12 % margin below ISO 10218-1's 250 mm/s, and the CAN driver's speed
#: monitor keeps its own exact check
SPEED_JACOBIAN_STEP_RAD = 0.005
#: Hand guiding's speed limit with feedback: while the speed of the tool point or the flange
#: (the one the zero-moment law predicts the arm to have when its command acts; the measured
#: one for the admittance) is over max_tool_speed_m_s by e, the commands are held to the limit
#: less this × e.
#: A hard push overruns a limit on the command alone by what the vendor loop's velocity gain
#: lets through (200 N: 266 mm/s for a 220 mm/s limit); the feedback takes that excess down by
#: a factor 1 + gain in steady state.
SPEED_FEEDBACK_GAIN = 3.0

#: speeds [rad/s] at which :meth:`ZeroMomentController.friction_level_nm` reads the model
FRICTION_LEVEL_SPEEDS_RAD_S = (0.002, 0.005, 0.01, 0.02)


def nominal_chain(desc: RobotDescription) -> _rt.Chain:
    """The datasheet's rigid body with its rotor inertias and tool frame, compiled
    (control/rt/src/chain.rs): M(q) and the tool's Jacobian every cycle, no pinocchio."""
    from control.model.dynamics import RigidBodyModel

    rigid = RigidBodyModel.from_description(desc)
    tool = rigid.model.frames[rigid.tool_frame_id].name
    return _rt.Chain(to_json(chain_table(rigid.model, rigid.armature_kgm2, tool)))


class ZeroMomentController:
    """The computation, free of I/O: JointState (+ pressures) → JointCommand.

    Its cycle is compiled (``control._rt.ZeroMomentCycle``, control/rt/src/law/zero_moment.rs):
    the zero-moment torque, the delay predictor, the friction ramps, the inertia
    compensation, the speed limit, eq. (21) and the adaptation of its gains, over the pieces
    this object builds from the config and owns (:attr:`loop`, :attr:`predictor`,
    :attr:`rest_hold`, :attr:`hold`, :attr:`inner_estimate`: compiled too), which the
    telemetry and the admittance read. :meth:`desired_torque` states the physics on arrays,
    the reference tests/unit/test_zero_moment_cycle.py pins the cycle to.
    """

    def __init__(self, cfg: ControlConfig, model: DeclaredModel) -> None:
        self.cfg = cfg
        n = model.n
        adaptation: OmegaAdaptation | PaperAdaptation | None = None
        omega, upsilon_i = np.array(cfg.omega_rad_s_per_nm), np.array(cfg.upsilon_i_per_s)
        if cfg.strategy == "paper":
            if cfg.paper_upsilon_i0_per_s > 0:
                # the paper's Υ̂_I(0); ω̂(0) keeps the commissioned static gain K K_I = Υ_I/ω
                # (the hold before teaching then calibrates it, :meth:`answer`)
                omega = omega * cfg.paper_upsilon_i0_per_s / upsilon_i
                upsilon_i = np.full(n, cfg.paper_upsilon_i0_per_s)
            if cfg.paper_adaptation_per_s > 0:
                adaptation = PaperAdaptation(
                    cfg.paper_adaptation_per_s,
                    cfg.omega_adaptation_min_torque_nm,
                    dead_zone_nm=cfg.paper_dead_zone_nm,
                )
        elif cfg.omega_adaptation_per_s > 0:
            adaptation = OmegaAdaptation(
                cfg.omega_adaptation_per_s, cfg.omega_adaptation_min_torque_nm
            )
        self.loop = OuterLoop(
            omega,
            upsilon_i,
            np.array(cfg.max_offset_rad),
            np.array(cfg.max_velocity_rad_s),
            adaptation,
        )
        #: the state when a command takes effect (control/rt/src/law/delay.rs), on the
        #: datasheet's nominal rigid body (with rotor inertias) for M(q)
        self.predictor = _rt.DelayPredictor(cfg.command_delay_cycles)
        #: built whatever the settings: a constrained guide (control/rt/src/law/guide.rs),
        #: which the operator may ask for at any start, needs the tool's Jacobian
        self._inertia: _rt.Chain = nominal_chain(model.desc)
        #: the driver's hold at rest before teaching (:meth:`observe_hold`)
        self.hold = HoldAverage()
        self.damping = np.array(cfg.damping_nm_s_per_rad)
        self.lower = np.array([j.lower_rad for j in model.desc.joints]) + cfg.soft_limit_margin_rad
        self.upper = np.array([j.upper_rad for j in model.desc.joints]) - cfg.soft_limit_margin_rad
        self._guided = _rt.GuidedFriction(cfg.friction_ramp_guided_s)
        band = _rt.hold_band_nm(
            cfg.rest_hold_nm or [0.0] * n, cfg.rest_hold_rms_factor, model.heldout_rms_nm
        )
        self.rest_hold = _rt.RestHold(band, cfg.rest_hold_deflection_rad)
        # the joint torque of the motor currents, through the measured torque channel
        k, b = model.torque_per_amp_nm()
        k_nm_per_a = k.tolist()
        #: online estimate of the drives' K_p, K_I from the measured current (telemetry)
        self.inner_estimate: _rt.InnerLoopEstimator | None = None
        if cfg.inner_loop_estimate and cfg.omega_rad_s_per_nm:
            kp0 = 1.0 / (np.array(k_nm_per_a) * np.array(cfg.omega_rad_s_per_nm))
            self.inner_estimate = _rt.InnerLoopEstimator(
                kp0, kp0 * np.array(cfg.upsilon_i_per_s), k_nm_per_a
            )
        #: the drive model of the delay predictor, (K K_p, Υ_I), when it is not the law's
        #: estimates: the paper's law starts far from the drive (Υ̂_I(0) = 1.2/s against
        #: ~30/s: a K̂* 26 times the drive's made the predictor's explicit integration
        #: diverge, |q_cmd - q| of 10⁴ rad on the virtual cell), so the predictor keeps the
        #: commissioned, measured drive
        drive_model = None
        if cfg.strategy == "paper":
            drive_model = {
                "k_star": (1.0 / np.array(cfg.omega_rad_s_per_nm)).tolist(),
                "upsilon": list(cfg.upsilon_i_per_s),
            }
        #: the dither's torque amplitude per joint [N·m] (control/rt/src/law/inner_estimate.rs)
        if cfg.inner_loop_dither_a and len(cfg.inner_loop_dither_a) != n:
            raise ConfigError(
                f"[control].inner_loop_dither_a has {len(cfg.inner_loop_dither_a)} values; "
                f"the robot has {n} joints"
            )
        dither = cfg.inner_loop_dither_a or ()
        settings = {
            "n": n,
            "default_cycle_period_s": cfg.default_cycle_period_s,
            "engage_rest_states": cfg.engage_rest_states,
            "engage_max_wait_states": cfg.engage_max_wait_states,
            "rest_rad_s": REST_RAD_S,
            "flag_prev_hold": int(FLAG_PREV_HOLD),
            "flag_prev_coast": int(FLAG_PREV_COAST),
            "k_nm_per_a": k_nm_per_a,
            "torque_offset_nm": b.tolist(),
            "friction_deadband_rad_s": cfg.friction_deadband_rad_s,
            "friction_compensation": cfg.friction_compensation,
            "wall_stiffness_nm_per_rad": cfg.wall_stiffness_nm_per_rad,
            "damping_nm_s_per_rad": self.damping.tolist(),
            "lower_rad": self.lower.tolist(),
            "upper_rad": self.upper.tolist(),
            "friction_ramp_factor": cfg.friction_ramp_factor,
            "command_delay_cycles": cfg.command_delay_cycles,
            "inertia_compensation": cfg.inertia_compensation,
            "inertia_compensation_hz": cfg.inertia_compensation_hz,
            "max_tool_speed_m_s": cfg.max_tool_speed_m_s,
            "speed_feedback_gain": SPEED_FEEDBACK_GAIN,
            "inertia_step_rad": INERTIA_STEP_RAD,
            "speed_jacobian_step_rad": SPEED_JACOBIAN_STEP_RAD,
            "friction_level_speeds_rad_s": list(FRICTION_LEVEL_SPEEDS_RAD_S),
            "nominal_pressures_bar": model.desc.nominal_pressures_bar.tolist(),
            "tool_in_6_m": list(model.desc.tool.position_in_link6_m),
            "drive_servo_rate_hz": cfg.drive_servo_rate_hz,
            "dither_nm": [a * k for a, k in zip(dither, k_nm_per_a, strict=True)] if dither else [],
            "stiction_dither": cfg.stiction_dither,
            "stiction_dither_hz": cfg.stiction_dither_hz,
            "stiction_dither_hold_s": cfg.stiction_dither_hold_s,
            "drive_model": drive_model,
            "guide": cfg.guide,
            "guide_axis": GUIDE_AXES.index(cfg.guide_axis),
            "guide_stiffness_n_per_m": cfg.guide_stiffness_n_per_m,
            "guide_damping_n_s_per_m": cfg.guide_damping_n_s_per_m,
            "guide_rot_stiffness_nm_per_rad": cfg.guide_rot_stiffness_nm_per_rad,
            "guide_rot_damping_nm_s_per_rad": cfg.guide_rot_damping_nm_s_per_rad,
        }
        #: the compiled cycle over the pieces above
        self._cycle = _rt.ZeroMomentCycle(
            json.dumps(settings), self.loop, self.predictor, self.rest_hold, self._guided,
            self.hold, self.inner_estimate, model.point, self._inertia,
        )  # fmt: skip
        self._model = model

    @property
    def model(self) -> DeclaredModel:
        """The model the law compensates."""
        return self._model

    @model.setter
    def model(self, model: DeclaredModel) -> None:
        self._cycle.set_model(model.point)
        self._model = model

    @property
    def engaged(self) -> bool:
        return self._cycle.engaged

    @engaged.setter
    def engaged(self, value: bool) -> None:
        self._cycle.engaged = value

    @property
    def last_cycle(self) -> int | None:
        return self._cycle.last_cycle

    @last_cycle.setter
    def last_cycle(self, value: int | None) -> None:
        self._cycle.last_cycle = value

    @property
    def tau_d_nm(self) -> np.ndarray:
        """The desired torque of the last cycle [N·m]."""
        return np.array(self._cycle.tau_d_nm)

    def desired_torque(self, q: np.ndarray, dq: np.ndarray, p_bar: np.ndarray) -> np.ndarray:
        """Zero-moment torque: what the motors must give so the operator feels no load.

        The reference form of the physics on arrays, with this cycle's friction ramps; the
        cycle computes the same and adds the rest hold (control/rt/src/law/rest_hold.rs: it
        depends on the path of q, so it has no reference form here) and the inertia
        compensation.
        """
        m = self.model
        tau = m.gravity_nm(q) - m.cylinder_nm(q, p_bar)
        dead = self.cfg.friction_deadband_rad_s
        dq_f = np.sign(dq) * np.maximum(np.abs(dq) - dead, 0.0)
        friction = m.friction_nm(q, dq_f)
        friction = np.where(friction * dq > 0.0, friction, 0.0)  # it opposes motion, or nothing
        ramp = np.array(self._cycle.ramps)
        share = np.minimum(np.abs(dq_f) / np.where(ramp > 0.0, ramp, 1.0), 1.0)
        share = np.where(ramp > 0.0, share, 1.0)
        tau = tau + self.cfg.friction_compensation * share * friction
        tau = tau - self.damping * dq
        k = self.cfg.wall_stiffness_nm_per_rad
        tau = tau - k * np.maximum(q - self.upper, 0.0) + k * np.maximum(self.lower - q, 0.0)
        return tau

    def hold_offset(self, q: np.ndarray, dq: np.ndarray, p_bar: Sequence[float]) -> np.ndarray:
        """The command offset ``q_c - q`` [rad] at which the vendor loop, following a path at
        ``q``, ``dq``, gives the model's torque there (gravity less the cylinders, friction):
        eq. (21)'s steady state ``ω̂ τ / Υ̂_I``. Position mode without it sags by the load over
        the loop's stiffness (eq. 19 holds a load with a position error, not an integral).
        It runs every replay cycle (compiled). Raises ``ValueError`` or ``ArithmeticError``
        where the model is undefined."""
        return np.array(self._cycle.hold_offset(q.tolist(), dq.tolist(), list(p_bar)))

    def inverse_inertia(self, q: np.ndarray) -> np.ndarray:
        """M(q)⁻¹ of the nominal rigid body with rotor inertias, recomputed once a joint has
        moved more than :data:`INERTIA_STEP_RAD` since the last time (a 6×6 CRBA and inverse
        cost half the law, and the predictor holds with M off by 30 %)."""
        return np.array(self._cycle.inverse_inertia(q.tolist()))

    def inertia(self, q: np.ndarray) -> np.ndarray:
        """M(q) of the nominal rigid body with rotor inertias, cached as
        :meth:`inverse_inertia`'s."""
        return np.array(self._cycle.inertia(q.tolist()))

    def tool_speed_scale(self, q: np.ndarray, dq: np.ndarray) -> float:
        """The factor (≤ 1) on ``dq`` that keeps the tool point and the flange within the
        cycle's target, :attr:`speed_target_m_s` (nominal kinematics)."""
        return self._cycle.tool_speed_scale(q.tolist(), dq.tolist())

    @property
    def speed_target_m_s(self) -> float:
        """The tool speed the commands of the last cycle were held to [m/s]."""
        return self._cycle.speed_target_m_s

    @speed_target_m_s.setter
    def speed_target_m_s(self, value: float) -> None:
        self._cycle.speed_target_m_s = value

    def point_speed(self, q: np.ndarray, dq: np.ndarray) -> float:
        """The faster of the tool point and the flange at (q, dq) [m/s] (their Jacobians
        recomputed once a joint has moved :data:`SPEED_JACOBIAN_STEP_RAD`)."""
        return self._cycle.point_speed(q.tolist(), dq.tolist())

    def speed_target(self, q: np.ndarray, dq: np.ndarray) -> float:
        """The speed the commands are to be held to at (q, dq) [m/s]:
        ``max_tool_speed_m_s``, less :data:`SPEED_FEEDBACK_GAIN` × what the arm's speed at
        (q, dq) exceeds it by (not below 0)."""
        return self._cycle.speed_target(q.tolist(), dq.tolist())

    def friction_level_nm(self, q: np.ndarray) -> np.ndarray:
        """The model's friction at ``q`` just above rest [N·m], per joint: the most of it over
        a few low speeds both ways (its static level, where the model has a Stribeck rise);
        0 where the model is undefined. It runs in the cycle at every engagement."""
        return np.array(self._cycle.friction_level_nm(q.tolist()))

    @property
    def guide(self) -> str:
        """Constrained guiding's mode (gateway/guide_modes.py ``GUIDES``,
        control/rt/src/law/guide.rs); a new one takes its reference at the next cycle. Raises
        ValueError for a name not among them."""
        return self._cycle.guide

    @guide.setter
    def guide(self, name: str) -> None:
        self._cycle.guide = name

    def guide_deviation(self) -> tuple[float, float]:
        """The last cycle's distance of the tool point from its plane or line [m] and the
        tool's rotation from its locked orientation [rad] (0 where the mode holds neither)."""
        return self._cycle.guide_deviation

    def disengage(self) -> None:
        self._cycle.disengage()

    def engagement(self) -> dict[str, Any]:
        """What the law is doing, for the operator's status: ``{"phase": "idle"}`` (not
        engaged: the driver holds the arm) or ``"following"`` (the hand guides it)."""
        return {"phase": "following" if self.engaged else "idle"}

    def motor_torque_nm(self, st: JointState) -> list[float]:
        """The joint torque ``st``'s motor currents report [N·m]: datasheet K × current,
        through the torque channel's gain and offset the model carries
        (:meth:`DeclaredModel.torque_per_amp_nm`)."""
        return self._cycle.motor_torque_nm(st.current_a.tolist())

    def observe_hold(self, st: JointState) -> None:
        """A state while the arm is held (by the driver, or by this controller waiting to
        engage): at rest, its held offset and current go into :attr:`hold` for the next
        engagement; moving, the average restarts."""
        self._cycle.observe_hold(
            st.flags, st.q_rad.tolist(), st.dq_rad_s.tolist(), st.q_cmd_rad.tolist(),
            st.current_a.tolist(),
        )  # fmt: skip

    def _still_waiting(self, st: JointState) -> bool:
        """Before engaging: take ``st`` into the hold's average; True while the arm has not
        rested long enough to calibrate ω̂ (and at most ``engage_max_wait_states``): the
        caller then holds on where the driver holds."""
        return self._cycle.still_waiting(
            st.flags, st.q_rad.tolist(), st.dq_rad_s.tolist(), st.q_cmd_rad.tolist(),
            st.current_a.tolist(),
        )  # fmt: skip

    def update(
        self, st: JointState, p_bar: Sequence[float], now_s: float, state_rx_s: float = 0.0
    ) -> JointCommand:
        """Return the JointCommand answering ``st``, sent at ``now_s``, ``st`` received at
        ``state_rx_s`` (monotonic [s])."""
        q_cmd, dq_cmd = self.answer(st, p_bar)
        return make_joint_command(st.cycle, st.stamp_s, now_s, q_cmd, dq_cmd, state_rx_s)

    def answer(self, st: JointState, p_bar: Sequence[float]) -> tuple[list[float], list[float]]:
        """``(q_cmd, dq_cmd)`` answering ``st`` with cylinder pressures ``p_bar`` [bar] (the
        compiled cycle, class docstring).

        Raises MessageError if the model cannot be evaluated at ``st``; a NaN in the result is
        left for :func:`make_joint_command` to refuse.
        """
        try:
            return self._cycle.answer(
                st.cycle, st.flags, st.cycle_period_s, st.q_rad.tolist(), st.dq_rad_s.tolist(),
                st.q_cmd_rad.tolist(), st.dq_cmd_rad_s.tolist(), st.current_a.tolist(),
                [float(v) for v in p_bar],
            )  # fmt: skip
        except (ValueError, ArithmeticError) as exc:  # where numpy would have given NaN
            raise MessageError(f"cycle {st.cycle}: model torque undefined ({exc})") from None
