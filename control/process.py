"""`leadthrough control`: the zero-moment lead-through control process.

For every JointState it computes the torque that makes the arm weightless and frictionless
(gravity + friction − cylinder assist, eq. (1) without the operator), adds a little damping and
soft joint limits, and turns it into a position/velocity command with eq. (21). It publishes a
command only while the gateway says TEACHING and the cylinder pressures are fresh; otherwise it
stays silent and the CAN driver holds position. While the arm is held at rest it checks that the
model carries the arm's static load (control/load_check.py) and reports the verdict in its
health; the gateway starts teaching only on a passing one.
"""

from __future__ import annotations

import argparse
import json
import logging
import math
import threading
import time
from collections import deque
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from control import _rt
from control._rt import (
    Admittance,
    EngageProbe,
    HoldAverage,
    OmegaAdaptation,
    OuterLoop,
    PaperAdaptation,
)
from control.config import ControlConfig
from control.declared_model import DeclaredModel, IdentifiedControlModel
from control.identification.inner_loop import read_outer_loop_gains
from control.load_check import REST_RAD_S, LoadCheck, static_load_check
from control.model_adaptation import (
    AdaptationSettings,
    PayloadAdaptation,
    load_state,
    model_sha256,
    save_state,
)
from control.plan_builder import Parts, PlanBuilder, PlanRefused, build_parts
from control.pressure_schedule import PressureSchedule, ScheduleSettings
from control.robot.description import RobotDescription, load_description
from control.rt_tables import chain_table, to_json
from gateway import bus_security as security
from gateway.bus import (
    BusConfig,
    bus_config_from,
    declare_loop_publisher,
    open_peer,
    peer_config_entries,
    undeclare_all,
)
from gateway.config import from_mapping, load_toml, resolve_path
from gateway.errors import ConfigError, MessageError
from gateway.messages import (
    COMMANDING,
    FLAG_PREV_COAST,
    FLAG_PREV_HOLD,
    HEALTH_RATE_HZ,
    PLAYING,
    ControllerState,
    IoState,
    JointCommand,
    JointState,
    Lifecycle,
    LifecycleMsg,
    LifecycleOrder,
    PressureSetpoint,
    encode_json,
    make_joint_command,
)
from gateway.program import MAX_JOINT_SPEED_RAD_S as MAX_REPLAY_JOINT_SPEED_RAD_S
from gateway.program import MAX_SPEED_MM_S
from gateway.ratelog import RateLimitedLog
from gateway.runner import run_service

log = logging.getLogger("leadthrough.control")

#: fastest tool speed a replay may ask for [m/s] (gateway.program's bound, ISO 10218-1)
MAX_REPLAY_SPEED_M_S = MAX_SPEED_MM_S / 1000.0
#: no point of the tool or the flange moves faster in a replay [m/s]: 20 % under the CAN
#: driver's speed monitor (250 mm/s). Planned at 0.24 m/s, one replay on a loaded machine was
#: measured at 263 mm/s and tripped the monitor: the vendor loop catching up after a held
#: cycle (traced 2026-11-29; the plan now resumes from rest, :class:`PlanPlayer`)
MAX_REPLAY_POINT_SPEED_M_S = 0.2
#: a plan resumes after a hold with no joint's commanded velocity rising faster than this
#: [rad/s²]: the CAN driver's controlled stop brakes at 2 rad/s² ([can]
#: stop_deceleration_rad_s2), and a resumption is no harder than an ordinary stop
RESUME_ACCEL_RAD_S2 = 2.0
#: a fractional plan index this close to a sample is that sample
_INDEX_TOLERANCE = 1e-9
PRESSURE_PUBLISH_PERIOD_S = 0.1
#: the pressure schedule follows the pose in teaching and replay only while a joint moves
#: faster than this [rad/s] (:meth:`ControlProcess.pressure_setpoints`)
SCHEDULE_MOVING_RAD_S = 0.01
#: the static-load check runs at most this often [s] (the gateway accepts one up to 0.5 s old)
LOAD_CHECK_PERIOD_S = 0.1
#: the admittance measures its estimate's noise on at least this many held states
MIN_NOISE_STATES = 16
#: the admittance's engagement probe breaks a stuck joint away within this share of a quarter
#: of it, at no more than PROBE_MAX_RAD_S (AdmittanceController.probe_speeds)
PROBE_BREAKAWAY_SHARE, PROBE_MAX_RAD_S = 0.4, 0.05
#: the admittance's stick zone fades out between rest and this speed [rad/s]
STICK_RAD_S = 2.0 * REST_RAD_S
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


def load_control_config(cell_path: str | Path) -> tuple[ControlConfig, BusConfig]:
    """The cell config's ``[control]`` and ``[bus]``. With ``[control].inner_loop``, ω and Υ_I
    come from that estimate (`leadthrough identify`) and may not also be written out."""
    raw = load_toml(cell_path)
    bus = bus_config_from(raw, str(cell_path))  # first: it refuses an unknown section
    section = dict(raw.get("control", {}))
    where = f"{cell_path} [control]"
    if section.get("inner_loop"):
        written = [k for k in ("omega_rad_s_per_nm", "upsilon_i_per_s") if k in section]
        if written:
            raise ConfigError(f"{where}: give {written} or inner_loop, not both")
        source = resolve_path(cell_path, section["inner_loop"])
        if "max_offset_rad" in section:  # else from_mapping names the missing key
            n = len(section["max_offset_rad"])
            omega, upsilon, delay = read_outer_loop_gains(source, n)
            section.update(omega_rad_s_per_nm=omega, upsilon_i_per_s=upsilon)
            if "command_delay_cycles" not in section:
                section["command_delay_cycles"] = delay
        section["inner_loop"] = str(source)
    cfg = from_mapping(ControlConfig, section, where)
    for key in ("model", "model_adaptation_file"):
        if getattr(cfg, key) is not None:
            cfg = ControlConfig(**{**cfg.__dict__, key: resolve_path(cell_path, getattr(cfg, key))})
    return cfg, bus


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

    #: the nominal rigid body whatever the settings (the admittance needs M(q) and the tool)
    ALWAYS_CHAIN = False

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
        self._inertia: _rt.Chain | None = None
        if (
            self.ALWAYS_CHAIN
            or cfg.command_delay_cycles
            or cfg.max_tool_speed_m_s > 0
            or cfg.friction_ramp_factor
            or cfg.inertia_compensation
        ):
            self._inertia = nominal_chain(model.desc)
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


class AdmittanceController(ZeroMomentController):
    """Sensorless admittance (control/rt/src/law/admittance.rs) behind the controller's interface.

    Engages as :class:`ZeroMomentController` does (after the arm has rested in the driver's
    hold): the hold's mean offset and current calibrate ω̂ (the offset that makes the vendor
    loop give a torque) and the residual b of (A1). Then each cycle: τ̂_h from the motor
    current of the cycle that just ended and the reference acceleration that drove it, the
    reference of (A2), and the command ``q_r + ω̂ (τ_model − b) / Υ̂_I``, ``q̇_r``. ω̂ does not
    adapt here: the hand's torque is in the current, so eq. (28) would learn it.
    """

    ALWAYS_CHAIN = True

    def __init__(self, cfg: ControlConfig, model: DeclaredModel) -> None:
        super().__init__(cfg, model)
        band = _rt.hold_band_nm(
            cfg.rest_hold_nm or [0.0] * model.n,
            cfg.admittance_band_rms_factor,
            model.heldout_rms_nm,
        )
        self.admittance = Admittance(
            cfg.admittance_mass_fraction,
            cfg.damping_nm_s_per_rad,
            band,
            cfg.admittance_filter_hz,
            cfg.max_velocity_rad_s,
            cfg.admittance_rest_damping_factor,
        )
        if cfg.max_tool_speed_m_s > 0:
            self.admittance.speed_limit = lambda q, dq: self.tool_speed_scale(
                np.asarray(q), np.asarray(dq)
            )
        self._bias = np.zeros(model.n)
        self._max_offset = np.array(cfg.max_offset_rad)
        #: reference accelerations sent, newest last: the current of a state was measured over
        #: the cycle the one ``delay + 1`` back drove
        self._sent_ddq: deque[np.ndarray] = deque(maxlen=cfg.command_delay_cycles + 1)
        self._mass: tuple[np.ndarray, np.ndarray] | None = None
        #: the engagement probe while it runs (control/rt/src/law/admittance.rs), its first cycle,
        #: the command it starts from, and the noise measured in the hold before it
        self._probe: EngageProbe | None = None
        self._probe_start = 0
        self._probe_q0 = np.zeros(model.n)
        self._probe_noise: np.ndarray | None = None
        self._probe_offset = self._probe_velocity = np.zeros((0, model.n))
        self._probe_period_s = 0.0
        #: per joint, the hand torque a joint at rest hides in its friction [N·m]
        self._stick = np.zeros(model.n)
        #: the model's friction level at the engagement's pose [N·m]
        self._friction_level = np.zeros(model.n)
        #: the desired torque of the last cycle [N·m]
        self._tau_d = np.zeros(model.n)

    @property
    def tau_d_nm(self) -> np.ndarray:
        return self._tau_d.copy()

    def disengage(self) -> None:
        super().disengage()
        self._probe = None

    def engagement(self) -> dict[str, Any]:
        """As the zero-moment law's, plus ``"probing"`` while the engagement probe moves the
        arm, with ``left_s``, its time still to run [s] (the painter should hold the tool
        lightly and not push: a push now is taken for the model's error)."""
        probe, last = self._probe, self.last_cycle  # the cycle's thread may change them
        if probe is None or not self.engaged:
            return super().engagement()
        done = 0 if last is None else last - self._probe_start
        left = len(probe) + self.cfg.command_delay_cycles + 1 - done
        return {"phase": "probing", "left_s": round(max(left, 0) * self._probe_period_s, 2)}

    def mass(self, q: np.ndarray) -> np.ndarray:
        """M̂(q), recomputed after a joint moved INERTIA_STEP_RAD: the identified model's
        (in the unit its torques and the drives' currents share), or the nominal rigid body's
        with rotor inertias where the model has none or its M̂ is not positive definite."""
        cached = self._mass
        if cached is None or float(np.max(np.abs(q - cached[0]))) > INERTIA_STEP_RAD:
            cached = self._mass = (q.copy(), self._mass_at(q))
        return cached[1]

    def _mass_at(self, q: np.ndarray) -> np.ndarray:
        identified = getattr(self.model, "identified", None)
        if identified is not None:
            n = self.model.n
            ddq = np.vstack([np.zeros(n), np.eye(n)])
            tau = identified.torque_nm(np.tile(q, (n + 1, 1)), np.zeros((n + 1, n)), ddq)
            m = (tau[1:] - tau[0]).T
            m = 0.5 * (m + m.T)
            if np.isfinite(m).all() and np.linalg.eigvalsh(m).min() > 0:
                return m
        assert self._inertia is not None
        return np.array(self._inertia.mass_matrix(q.tolist(), armature=True))

    def model_torque(self, q: np.ndarray, dq: np.ndarray, ddq: np.ndarray, p_bar) -> np.ndarray:
        """What the drives must give for the arm to move so, without a hand [N·m]: M̂ q̈ +
        gravity − cylinders + the model's friction where it opposes the motion, at the speed
        beyond the friction deadband (as the zero-moment law: at rest the arm stands on its
        own friction, and a creep never earns a push)."""
        dead = self.cfg.friction_deadband_rad_s
        dq_f = np.sign(dq) * np.maximum(np.abs(dq) - dead, 0.0)
        static, friction = self.model.cycle_torques_nm(q, dq_f.tolist(), [float(v) for v in p_bar])
        f = np.array(friction)
        f = np.where(f * dq_f > 0.0, self.cfg.friction_compensation * f, 0.0)
        return np.array(static) + f + self.mass(q) @ ddq

    def answer(self, st: JointState, p_bar: Sequence[float]) -> tuple[list[float], list[float]]:
        period = st.cycle_period_s or self.cfg.default_cycle_period_s
        n = self.model.n
        if not self.engaged:
            if self._still_waiting(st):
                return st.q_cmd_rad.tolist(), [0.0] * n
            zeros = np.zeros(n)
            noise = None
            if len(self.hold):
                offset, tau_m = self.hold.mean()
                self.loop.calibrate_from_hold(offset, tau_m)
                if len(self.hold) >= MIN_NOISE_STATES:
                    noise = self.admittance.filtered_noise(np.array(self.hold.torque_std()), period)
            else:
                tau_m = self.motor_torque_nm(st)
            self._bias = self.model_torque(st.q_rad, zeros, zeros, p_bar) - np.array(tau_m)
            # the model's friction at the engagement pose: the stick zone, the probe's speeds
            # and the fallback of a joint the probe did not slide
            self._friction_level = self.friction_level_nm(st.q_rad)
            self._stick = self.cfg.admittance_stick_zone * self._friction_level
            self.hold.clear()
            self._sent_ddq.clear()
            self.engaged = True
            self.last_cycle = st.cycle - 1
            if self.cfg.admittance_probe_speed_rad_s > 0:
                self._probe = EngageProbe(
                    self.probe_speeds(self._friction_level),
                    self.cfg.admittance_probe_s,
                    period,
                    REST_RAD_S,
                )
                self._probe_start, self._probe_q0 = st.cycle, st.q_cmd_rad.copy()
                # the probe's path, read once (each read of the compiled probe's tables
                # builds them anew)
                self._probe_offset = np.array(self._probe.offset)
                self._probe_velocity = np.array(self._probe.velocity)
                self._probe_noise, self._probe_period_s = noise, period
                log.info("admittance probe: %.1f s, every joint a few mrad out and back to "
                         "measure the model's error; the painter holds the tool lightly",
                         len(self._probe) * period)  # fmt: skip
            else:
                self._start_admittance(st.q_rad, noise)
        if self._probe is not None:
            return self._probe_cycle(st, p_bar)
        gap = st.cycle - (self.last_cycle if self.last_cycle is not None else st.cycle - 1)
        dt = period * max(1, min(gap, 50))
        if self.cfg.max_tool_speed_m_s > 0 and self._inertia is not None:
            self.speed_target_m_s = self.speed_target(st.q_rad, st.dq_rad_s)
        self.last_cycle = st.cycle
        q = st.q_rad
        adm = self.admittance
        if len(self._sent_ddq) == self._sent_ddq.maxlen:
            drove = self._sent_ddq[0]
        else:
            drove = np.array(adm.ddq_r)
        tau_m = np.array(self.motor_torque_nm(st))
        # the friction the arm met is at its measured speed, not at the reference's
        tau_h = self.model_torque(q, st.dq_rad_s, drove, p_bar) - self._bias - tau_m
        # a joint at rest: its friction carries any torque up to its static level, which the
        # current cannot tell from a hand (the stick zone, fading out as the joint slides)
        stuck = self._stick * np.maximum(0.0, 1.0 - np.abs(st.dq_rad_s) / STICK_RAD_S)
        tau_h = np.sign(tau_h) * np.maximum(np.abs(tau_h) - stuck, 0.0)
        k = self.cfg.wall_stiffness_nm_per_rad
        walls = -k * np.maximum(q - self.upper, 0.0) + k * np.maximum(self.lower - q, 0.0)
        if not (np.isfinite(tau_h).all() and np.isfinite(walls).all()):
            raise MessageError(f"cycle {st.cycle}: hand torque estimate undefined")
        q_r, dq_r = (np.array(v) for v in adm.step(tau_h, walls, self.mass(np.array(adm.q_r)), dt))
        ddq_r = np.array(adm.ddq_r)
        self._sent_ddq.append(ddq_r)
        tau = self.model_torque(q_r, dq_r, ddq_r, p_bar) - self._bias
        self._tau_d = tau
        offset = np.clip(self.loop.omega * tau / self.loop.upsilon_i, -self._max_offset,
                         self._max_offset)  # fmt: skip
        # the command may lead the arm by at most the offset limit (the controller faults at
        # a larger following error): a hand pushing a joint into a stop cannot wind it up
        q_cmd = np.clip(q_r + offset, q - self._max_offset, q + self._max_offset)
        if not np.array_equal(q_cmd, q_r + offset):
            adm.q_r = q_cmd - offset
        return q_cmd.tolist(), dq_r.tolist()

    def probe_speeds(self, friction_level_nm: np.ndarray) -> np.ndarray:
        """The engagement probe's cruise speed per joint [rad/s]: at least the configured
        one, and fast enough that the command leads a joint stuck at one end of its friction
        by enough to break it away the other way, ``2 × 2 f / k`` (f the model's friction
        level, twice for a true static level above it; k = Υ̂_I / ω̂ the vendor loop's
        position stiffness), within :data:`PROBE_BREAKAWAY_SHARE` of a quarter of the probe;
        at most :data:`PROBE_MAX_RAD_S`."""
        lead = 4.0 * friction_level_nm * self.loop.omega / self.loop.upsilon_i
        quarter = 0.25 * self.cfg.admittance_probe_s
        speed = np.maximum(self.cfg.admittance_probe_speed_rad_s,
                           lead / (PROBE_BREAKAWAY_SHARE * quarter))  # fmt: skip
        return np.minimum(speed, PROBE_MAX_RAD_S)

    def _start_admittance(self, q: np.ndarray, noise: np.ndarray | None) -> None:
        self.admittance.reset(q, noise)
        log.info("admittance engaged: dead zone %s N·m, residual b %s N·m",
                 np.round(self.admittance.band, 3).tolist(),
                 np.round(self._bias, 2).tolist())  # fmt: skip
        self._sent_ddq.clear()

    def _probe_cycle(
        self, st: JointState, p_bar: Sequence[float]
    ) -> tuple[list[float], list[float]]:
        """One cycle of the engagement probe (:class:`EngageProbe`): take in the state the
        probe's command ``delay + 1`` cycles back drove, answer with its next command; at
        its end, ``b`` and the admittance's start."""
        probe = self._probe
        assert probe is not None
        k = st.cycle - self._probe_start
        drove = k - (self.cfg.command_delay_cycles + 1)
        self.last_cycle = st.cycle
        if drove >= 0 and not st.flags & (FLAG_PREV_HOLD | FLAG_PREV_COAST):
            zeros = np.zeros(self.model.n)
            residual = self.model_torque(st.q_rad, zeros, zeros, p_bar) - np.array(
                self.motor_torque_nm(st)
            )
            if not np.isfinite(residual).all():
                raise MessageError(f"cycle {st.cycle}: hand torque estimate undefined")
            probe.observe(drove, st.dq_rad_s, residual)
        if drove < len(probe) - 1:
            i = min(k, len(probe) - 1)
            return (self._probe_q0 + self._probe_offset[i]).tolist(), self._probe_velocity[
                i
            ].tolist()
        bias, kept = probe.bias(self._bias, self._friction_level)
        self._bias = np.array(bias)
        log.info("admittance probe: sliding samples (+, -) per joint %s", probe.samples())
        if kept:
            log.warning("admittance probe: joints %s did not slide both ways; their "
                        "residual b is the one at rest beyond their friction",
                        [j + 1 for j in kept])  # fmt: skip
        self._probe = None
        # the reference starts where the arm is: one where the probe began would lead a joint
        # the probe left stuck a little off by a torque its friction cannot hold (J2: 0.05
        # mrad is 40 N·m of the vendor loop), which reads as a hand, and J2/J3 hunted
        self._start_admittance(st.q_rad, self._probe_noise)
        return self.answer(st, p_bar)


def _finite_or_none(values: Sequence[float]) -> list[float | None]:
    """5 significant digits, None where not finite (JSON has no NaN)."""
    return [float(f"{v:.5g}") if math.isfinite(v) else None for v in values]


class PlanPlayer:
    """Plays an excitation plan (control/experiments.py) or a taught program's replay path as
    position/velocity commands, one sample per controller cycle, starting from the position
    the robot is holding.

    The plan is built off the cycle (control/plan_builder.py) when a ``builder`` is given:
    meanwhile the player is ``planning`` and answers every cycle with the plan's first sample,
    the pose the robot holds, at rest. A plan not built within :attr:`MAX_PLANNING_S` fails.
    Without a builder (pure tests) :meth:`start` builds it in place.

    The plan waits for the robot: a sample the CAN driver answered with a hold (its command
    came late or out of range; the next JointState's FLAG_PREV_HOLD says so) is sent again
    instead of running ahead, which would leave the held arm ever further behind and every
    later command out of range. A plan held for longer than :attr:`MAX_PAUSE_S` fails, with
    the reason. A coast moves the arm on as the plan does, so the plan moves on too. Each
    segment's cycle range is recorded as played, for the export.

    A hold stops the arm; the plan then resumes from rest: its speed along the samples is
    scaled by σ, 0 after a hold, rising each cycle so that no joint's commanded velocity
    rises faster than :data:`RESUME_ACCEL_RAD_S2`, up to 1 (the plan's own timing). Sent at
    full speed after a hold, the plan stepped each joint's velocity from 0 to the path's in
    one cycle and the drive, catching up with a reference that ran on, overshot it: a
    100 mm/s replay on a loaded machine reached 249 mm/s at the tool and the CAN driver's
    speed monitor stopped it (2026-11-29). Between samples, positions and velocities are
    interpolated.
    """

    #: keep plans this far inside the joint range [rad]
    LIMIT_MARGIN_RAD = 0.05
    #: the plan fails when its commands were held this long in a row [s]
    MAX_PAUSE_S = 0.5
    #: the plan fails when it is not built within this long [s]: a replay path of minutes
    #: builds in well under a second on a fast machine of our class; the arm holds meanwhile
    MAX_PLANNING_S = 30.0

    def __init__(
        self,
        lower_rad: np.ndarray,
        upper_rad: np.ndarray,
        desc: RobotDescription | None = None,
        builder: PlanBuilder | None = None,
    ) -> None:
        self.lower, self.upper = lower_rad, upper_rad
        self.desc = desc  #: the robot, for a taught program's tool path (plan key "replay")
        self.builder = builder
        self.plan_id: str | None = None
        self.state = "idle"  # idle | planning | running | done | failed
        self.reason = ""
        self.start_cycle = 0
        self.period_s = 0.0
        self.q = self.dq = np.zeros((0, len(lower_rad)))
        self.segments: list[dict] = []
        self._bounds: list[tuple[int, int]] = []  #: first and last sample of each segment
        self.k = 0  #: the plan sample to play next
        self._s = 0.0  #: where along the samples the last command was (a fractional index)
        self._sigma = 1.0  #: speed along the plan (1: its own timing; 0 after a hold)
        self._sent_cycle: int | None = None  #: cycle the last sample was sent for
        self.held_s = 0.0  #: how long the plan's commands have been held in a row [s]
        self.repeats = 0  #: samples sent again after a hold
        self._q0 = np.zeros(len(lower_rad))  #: where the plan starts, held while planning
        self._job: int | None = None  #: the builder's job of the plan being built
        self._planning_cycle = 0  #: the cycle planning began in
        self.planning_s = 0.0  #: how long the plan took to build [s] (reported)

    def start(self, plan: dict, st: JointState, period_s: float) -> None:
        self.plan_id, self.k, self._sent_cycle, self.held_s = str(plan.get("plan_id")), 0, None, 0.0
        self._s, self._sigma = 0.0, 1.0
        self.start_cycle, self.period_s, self.repeats = st.cycle, period_s, 0
        self.segments, self._bounds, self.planning_s = [], [], 0.0
        self._q0 = st.q_cmd_rad.copy()
        limits = {
            "max_speed_m_s": MAX_REPLAY_SPEED_M_S,
            "max_joint_speed_rad_s": MAX_REPLAY_JOINT_SPEED_RAD_S,
            "max_point_speed_m_s": MAX_REPLAY_POINT_SPEED_M_S,
        }
        args = (plan, self._q0.copy(), self.lower, self.upper, period_s, self.LIMIT_MARGIN_RAD,
                self.desc, limits)  # fmt: skip
        if self.builder is not None:
            self.state, self.reason = "planning", ""
            self._job, self._planning_cycle = self.builder.submit(*args), st.cycle
            log.info("excitation plan %s: planning", self.plan_id)
            return
        try:
            self._install(build_parts(*args))
        except PlanRefused as exc:
            self.fail(str(exc))

    def fail(self, why: str) -> None:
        """The plan ends here, failed, with ``why``; nothing more is sent for it."""
        self.state, self.reason, self._job = "failed", why, None
        log.error("excitation plan %s failed: %s", self.plan_id, why)

    def _install(self, parts: Parts) -> None:
        self.segments, self._bounds, offset = [], [], 0
        for label, role, q, _dq in parts:
            self.segments.append({"label": label, "role": role,
                                  "start_cycle": None, "end_cycle": None})  # fmt: skip
            self._bounds.append((offset, offset + len(q) - 1))
            offset += len(q)
        self.q = np.vstack([p[2] for p in parts])
        self.dq = np.vstack([p[3] for p in parts])
        self.state, self.reason, self._job = "running", "", None
        log.info("excitation plan %s: %d segments, %.1f s (built in %.2f s)", self.plan_id,
                 len(parts), len(self.q) * self.period_s, self.planning_s)  # fmt: skip

    def _planned(self, st: JointState) -> None:
        """While planning: take the builder's outcome if it came, or fail the plan when it
        takes too long."""
        assert self.builder is not None and self._job is not None
        self.planning_s = (st.cycle - self._planning_cycle) * self.period_s
        outcome = self.builder.poll(self._job)
        if outcome is None:
            if self.planning_s > self.MAX_PLANNING_S:
                self.fail(f"not planned within {self.MAX_PLANNING_S:g} s")
            return
        kind, value = outcome
        if kind == "ok":
            self._install(value)
        else:
            self.fail(value if kind == "refused" else f"planning failed: {value}")

    def _played(self, cycle: int) -> None:
        """Sample ``self.k`` was carried out in ``cycle``: note segment bounds, move on."""
        for seg, (first, last) in zip(self.segments, self._bounds, strict=True):
            if self.k == first:
                seg["start_cycle"] = cycle
            if self.k == last:
                seg["end_cycle"] = cycle
        self.k += 1
        if self.k >= len(self.q):
            self.state = "done"
            log.info("excitation plan %s done (%d samples sent again after a hold)",
                     self.plan_id, self.repeats)  # fmt: skip

    def command(self, st: JointState) -> tuple[np.ndarray, np.ndarray] | None:
        """This cycle's sample (q [rad], dq [rad/s]), or None when nothing is to be sent."""
        if self.state == "planning":
            self._planned(st)
            if self.state == "planning":
                return self._q0, np.zeros_like(self._q0)  # held where the plan will start
        if self.state == "running" and self._sent_cycle is not None:
            if st.flags & FLAG_PREV_HOLD:
                self.repeats += 1
                self.held_s += self.period_s * max(1, st.cycle - self._sent_cycle)
                if self.held_s > self.MAX_PAUSE_S:
                    self.state = "failed"
                    self.reason = (
                        f"the robot did not follow: the CAN driver held the plan's commands for "
                        f"{self.held_s:.2f} s at sample {self.k} of {len(self.q)} (its log says "
                        f"why: late or out-of-range commands)"
                    )
                    log.error("excitation plan %s failed: %s", self.plan_id, self.reason)
                    return None
                self._sigma = 0.0  # the arm was stopped: the plan resumes from rest
            else:
                self.held_s = 0.0
                self._advance(self._sent_cycle)
        if self.state == "done":
            return self.q[-1], np.zeros_like(self.dq[-1])
        if self.state != "running":
            return None
        self._sent_cycle = st.cycle
        return self._sample()

    def _advance(self, cycle: int) -> None:
        """The command sent for ``cycle`` was carried out: every sample up to where it was is
        played; the next command is further along by σ, which recovers towards 1."""
        while self.state == "running" and self.k <= self._s + _INDEX_TOLERANCE:
            self._played(cycle)
        if self.state != "running":
            return
        self._sigma = min(1.0, self._sigma + self._sigma_step())
        self._s = min(self._s + self._sigma, len(self.q) - 1.0)

    def _sigma_step(self) -> float:
        """How much σ may rise in one cycle: a joint's commanded velocity σ·dq rises by at
        most RESUME_ACCEL_RAD_S2 per second."""
        fastest = float(np.max(np.abs(self._interpolate(self.dq, self._s))))
        if fastest <= 0.0:
            return 1.0
        return self.period_s * RESUME_ACCEL_RAD_S2 / fastest

    def _interpolate(self, samples: np.ndarray, s: float) -> np.ndarray:
        i = min(int(np.floor(s + _INDEX_TOLERANCE)), len(samples) - 1)
        frac = s - i
        if i + 1 >= len(samples) or frac <= _INDEX_TOLERANCE:
            return samples[i]
        return samples[i] + frac * (samples[i + 1] - samples[i])

    def _sample(self) -> tuple[np.ndarray, np.ndarray]:
        """The command at the plan's current place: its position, its velocity times σ."""
        return self._interpolate(self.q, self._s), self._sigma * self._interpolate(self.dq, self._s)

    def report(self) -> dict:
        return {
            "plan_id": self.plan_id,
            "state": self.state,
            "reason": self.reason,
            "progress": self.k / max(len(self.q), 1),
            "start_cycle": self.start_cycle,
            "repeated_samples": self.repeats,
            "planning_s": round(self.planning_s, 3),
            "segments": self.segments,
        }


class ControlProcess:
    def __init__(
        self,
        cfg: ControlConfig,
        bus: BusConfig,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.cfg = cfg
        self.bus = bus
        self.keys = bus.keys
        self.clock = clock
        #: the zero-moment law; None on a cell not commissioned yet (it only identifies)
        self.ctl: ZeroMomentController | None = None
        if cfg.uncommissioned is None:
            assert cfg.model is not None
            law = AdmittanceController if cfg.strategy == "admittance" else ZeroMomentController
            self.ctl = law(cfg, DeclaredModel.load(cfg.model))
        joints = load_description().joints if self.ctl is None else self.ctl.model.desc.joints
        self.n = len(joints)
        if len(cfg.max_offset_rad) != self.n:
            raise ConfigError(
                f"[control].max_offset_rad: {len(cfg.max_offset_rad)} values, the robot has "
                f"{self.n} joints"
            )
        desc = load_description() if self.ctl is None else self.ctl.model.desc
        #: builds plans in a worker process (control/plan_builder.py), started with the first
        #: plan (its interpreter's start-up, 1-2 s of CPU, would otherwise compete with every
        #: teaching session's start for the cores; the arm is held while it starts)
        self.plan_builder = PlanBuilder()
        self.player = PlanPlayer(np.array([j.lower_rad for j in joints]),
                                 np.array([j.upper_rad for j in joints]), desc,
                                 self.plan_builder)  # fmt: skip
        self._report_sent: tuple | None = None
        self._lock = threading.Lock()
        self.io: IoState | None = None
        self.lifecycle: LifecycleMsg | None = None
        self.lifecycle_rx_s = -1e9
        self.stats = {"states": 0, "commands": 0, "bad_messages": 0, "io_stale": 0}
        self.lifecycle_order = LifecycleOrder()
        self._ratelog = RateLimitedLog(log, 5.0, time.monotonic)
        self.stop_event = threading.Event()
        self.session = None
        self._subs: list = []
        self._pub_cmd = None
        #: the compiled joint-state subscription (control/rt/src/py_cycle_loop.rs): the
        #: zero-moment law answers teaching's states there, every other state comes to
        #: :meth:`_on_state_bytes`
        self._loop: _rt.CycleLoop | None = None
        #: the newest state Python handled: (cycle, q, dq)
        self._last_state: tuple[int, np.ndarray, np.ndarray] | None = None
        #: the latest static-load check and when it was made (monotonic [s])
        self.load_check: LoadCheck | None = None
        self.load_check_s = -1e9
        #: pose-scheduled cylinder set-points (None: the fixed ones), and the last measured
        #: joint positions they are scheduled from
        self.schedule: PressureSchedule | None = None
        if cfg.pressure_schedule and self.ctl is not None:
            lo, hi = cfg.pressure_schedule_range_bar
            settings = ScheduleSettings(
                share=cfg.pressure_schedule_share,
                min_bar=lo,
                max_bar=hi,
                rate_bar_per_s=cfg.pressure_schedule_rate_bar_per_s,
            )
            self.schedule = PressureSchedule(desc.cylinders, settings, cfg.pressure_setpoint_bar)
        #: eq. (29) in replay (control/model_adaptation.py), and the version of it the law
        #: compensates
        self.adaptation: PayloadAdaptation | None = None
        self._adaptation_applied = 0
        self._model_sha256 = ""
        #: why the kept adapted mass could not be used (None: no problem)
        self.adaptation_problem: str | None = None
        #: the mass was kept from before this start (``model_adaptation_file``)
        self._adaptation_restored = False
        model = None if self.ctl is None else self.ctl.model
        if cfg.model_adaptation and isinstance(model, IdentifiedControlModel):
            if model.heldout_rms_nm is None:
                log.warning("model adaptation off: %s has no held-out RMS", cfg.model)
            else:
                self.adaptation = PayloadAdaptation(
                    model.identified,
                    model.desc,
                    model.heldout_rms_nm,
                    AdaptationSettings(
                        rate_per_s=cfg.model_adaptation_rate_per_s,
                        max_mass_kg=cfg.model_adaptation_max_mass_kg,
                        max_reach_m=cfg.model_adaptation_max_reach_m,
                    ),
                )
                self._restore_adaptation()

    def _restore_adaptation(self) -> None:
        """Start from the mass adapted before this start, if it was kept for this model."""
        adapt, ctl, path = self.adaptation, self.ctl, self.cfg.model_adaptation_file
        if adapt is None or ctl is None or path is None or self.cfg.model is None:
            return
        self._model_sha256 = model_sha256(self.cfg.model)
        try:
            kept = load_state(path, self._model_sha256)
        except ValueError as exc:  # the commissioned model, as if never adapted
            self.adaptation_problem = str(exc)
            log.error("adapted payload not used: %s", exc)
            return
        if kept is None:
            if path.exists():
                log.info("%s was adapted for another model (re-identified since): not used", path)
            return
        adapt.restore(*kept)
        self._apply_adaptation(save=False)
        self._adaptation_restored = True

    def open(self) -> None:
        self.session = open_peer(self.bus, security.CONTROL)
        s = self.session
        self._pub_cmd = declare_loop_publisher(s, self.keys.joint_command)
        compiled = type(self.ctl) is ZeroMomentController  # the admittance's law is Python's
        self._loop = _rt.CycleLoop(
            peer_config_entries(self.bus, security.CONTROL), self.keys.joint_state,
            self.keys.joint_command, self.ctl._cycle if compiled else None,
            self._on_state_bytes,
        )  # fmt: skip
        self._subs = [
            s.declare_subscriber(self.keys.io_state, self._on_io),
            s.declare_subscriber(self.keys.lifecycle, self._on_lifecycle),
        ]

    def close(self) -> None:
        if self._loop is not None:
            self._loop.close()
        undeclare_all([*self._subs, self._pub_cmd])
        self._subs, self._pub_cmd = [], None
        if self.session is not None:
            self.session.close()
            self.session = None
        self.plan_builder.close()

    # --- callbacks: decode, compute, publish; never block --------------------------------
    def _decode(self, cls, sample):
        """``cls.from_bytes`` of the sample, or None (counted and logged) if malformed."""
        return self._decode_bytes(cls, sample.payload.to_bytes(), sample.key_expr)

    def _decode_bytes(self, cls, data: bytes, key: str):
        try:
            return cls.from_bytes(data)
        except MessageError as exc:
            self.stats["bad_messages"] += 1
            log.warning("ignored %s on %s: %s", cls.__name__, key, exc)
            return None

    def _on_io(self, sample) -> None:
        io = self._decode(IoState, sample)
        if io is not None:
            with self._lock:
                self.io = io
            if self._loop is not None:
                self._loop.set_io(io.p2_bar, io.p3_bar, io.stamp_s, self.cfg.io_timeout_s)

    def _on_lifecycle(self, sample) -> None:
        msg = self._decode(LifecycleMsg, sample)
        if msg is not None:
            with self._lock:
                dropped = self.lifecycle_order.admit(msg)
                if dropped is None:
                    self.lifecycle, self.lifecycle_rx_s = msg, self.clock()
                    if self._loop is not None:
                        self._loop.set_lifecycle(
                            msg.state == Lifecycle.TEACHING, self.lifecycle_rx_s,
                            self.cfg.lifecycle_timeout_s,
                        )  # fmt: skip
            if dropped is not None:
                self._ratelog(
                    logging.WARNING, f"lifecycle_{dropped}", "lifecycle seq %d %s dropped: %s",
                    msg.seq, msg.state.name, dropped,
                )  # fmt: skip

    def _fresh_state(self, now: float) -> Lifecycle | None:
        """The gateway's lifecycle state if its last message is fresh, else None."""
        lc = self.lifecycle
        if lc is None or now - self.lifecycle_rx_s > self.cfg.lifecycle_timeout_s:
            return None
        return lc.state

    def _mode(self, now: float) -> Lifecycle | None:
        """TEACHING, IDENTIFYING or REPLAYING when the gateway says so (fresh), else None."""
        state = self._fresh_state(now)
        return state if state in COMMANDING else None

    def _on_state(self, sample) -> None:
        """A joint state as a zenoh sample (the benchmark and the tests drive it so)."""
        self._on_state_bytes(sample.payload.to_bytes(), self.clock())

    def _on_state_bytes(self, data: bytes, now: float) -> None:
        """A joint state the compiled loop did not answer (the law's teaching cycle is
        compiled: control/rt/src/py_cycle_loop.rs), received at ``now`` (monotonic [s]: the
        command's state_rx_stamp_s)."""
        st = self._decode_bytes(JointState, data, self.keys.joint_state)
        if st is None:
            return
        self.stats["states"] += 1
        with self._lock:
            io, mode, lc = self.io, self._mode(now), self.lifecycle
        if st.n != self.n:
            self.stats["bad_messages"] += 1
            log.error("joint state has %d joints, the robot has %d", st.n, self.n)
            return
        self._last_state = (st.cycle, st.q_rad, st.dq_rad_s)
        ctl = self.ctl
        following = st.controller_state in (ControllerState.HOLD, ControllerState.EXTERNAL)
        period = st.cycle_period_s or self.cfg.default_cycle_period_s
        if mode is None or not following:
            if ctl is not None:
                ctl.disengage()
                if following:
                    ctl.observe_hold(st)
            if following and io is not None and now - io.stamp_s <= self.cfg.io_timeout_s:
                self._check_load(st, io, now)
            return
        if mode in PLAYING:
            if ctl is not None:
                ctl.disengage()
            plan = lc.extra.get("plan") if lc else None
            if isinstance(plan, dict) and str(plan.get("plan_id")) != self.player.plan_id:
                self.player.start(plan, st, period)
            qd = self.player.command(st)
            if qd is not None:
                q_cmd = qd[0]
                if mode == Lifecycle.REPLAYING and ctl is not None and io is not None:
                    # a taught path is where the tool must be: the load's offset on top
                    try:
                        q_cmd = q_cmd + ctl.hold_offset(qd[0], qd[1], (io.p2_bar, io.p3_bar))
                    except (ValueError, ArithmeticError) as exc:
                        self.player.fail(f"the model is undefined on the path: {exc}")
                        return
                cmd = make_joint_command(st.cycle, st.stamp_s, self.clock(), q_cmd, qd[1], now)
                self._pub_cmd.put(cmd.to_bytes())
                self.stats["commands"] += 1
                if (
                    mode == Lifecycle.REPLAYING
                    and self.adaptation is not None
                    and io is not None
                    and now - io.stamp_s <= self.cfg.io_timeout_s
                    and ctl is not None
                ):  # free motion: eq. (29) learns from it (processed on the slow loop)
                    self.adaptation.add(
                        st.cycle, st.stamp_s, st.q_rad, st.dq_rad_s, ctl.motor_torque_nm(st),
                        (io.p2_bar, io.p3_bar),
                    )  # fmt: skip
            return
        if ctl is None:  # teaching without a model: the gateway refuses it; never command
            return
        if io is None or now - io.stamp_s > self.cfg.io_timeout_s:
            self.stats["io_stale"] += 1
            ctl.disengage()  # no pressures, no cylinder torque: let the driver hold
            return
        try:
            q_cmd, dq_cmd = ctl.answer(st, (io.p2_bar, io.p3_bar))
            payload = JointCommand.pack(st.cycle, st.stamp_s, self.clock(), q_cmd, dq_cmd, now)
        except MessageError as exc:  # NaN from the model: never send it
            self.stats["bad_messages"] += 1
            ctl.disengage()
            log.error("command not sent: %s", exc)
            return
        self._pub_cmd.put(payload)
        self.stats["commands"] += 1

    def _check_load(self, st: JointState, io: IoState, now: float) -> None:
        """Held by the driver, not commanded: check the static load if the arm is at rest, at
        most every LOAD_CHECK_PERIOD_S (a check costs ~0.3 ms; the cycle is 2–8 ms)."""
        if now - self.load_check_s < LOAD_CHECK_PERIOD_S:
            return
        if float(np.max(np.abs(st.dq_rad_s))) > REST_RAD_S:
            return
        if self.ctl is None:
            zero = (0.0,) * self.n
            reason = self.cfg.uncommissioned or "no model"
            self.load_check, self.load_check_s = LoadCheck(False, 0, zero, zero, zero, reason), now
            return
        check = static_load_check(
            self.ctl.model,
            st.q_rad,
            st.current_a,
            np.array([io.p2_bar, io.p3_bar]),
            self.cfg.load_check_margin_nm,
        )
        if not check.ok and (self.load_check is None or self.load_check.ok):
            log.warning("static-load check failed: %s", check.message)
        self.load_check, self.load_check_s = check, now

    # --- slow loop: pressure set-points, health, telemetry -------------------------------
    def pressure_setpoints(self, now: float) -> tuple[float, ...]:
        """The cylinders' set-points to publish now [bar]: the fixed ones, or the schedule's
        (control/pressure_schedule.py). It follows the pose while the drives hold the arm
        (READY: a change of the cylinders' torque is the position loop's to absorb) and while
        the arm moves in teaching and replay; with the arm at rest under the zero-moment law
        it holds, since there a change of pressure reaches the arm through the cylinder
        model's error (an arm without stiction drifted 2.3 mm in 5 s on the virtual cell
        while the set-points settled). Identification ramps back to the fixed ones; any
        other state holds."""
        sched, ctl = self.schedule, self.ctl
        q, dq = self._last_pose()
        if sched is None or ctl is None:
            return self.cfg.pressure_setpoint_bar
        with self._lock:
            state = self._fresh_state(now)
        if state == Lifecycle.IDENTIFYING:
            return sched.update(None, now)
        moving = dq is not None and float(np.max(np.abs(dq))) > SCHEDULE_MOVING_RAD_S
        follow = state == Lifecycle.READY or (
            state in (Lifecycle.TEACHING, Lifecycle.REPLAYING) and moving
        )
        if not follow or q is None:
            return sched.hold(now)
        try:
            static = ctl.model.gravity_nm(q)  # the torque at rest, without the cylinders
            target = sched.target_bar(q.tolist(), static.tolist())
        except (ValueError, ArithmeticError):  # the model undefined there: stay
            return sched.hold(now)
        return sched.update(target, now)

    def _last_pose(self) -> tuple[np.ndarray | None, np.ndarray | None]:
        """The newest measured (q, dq): of the states Python handled or the compiled loop
        answered."""
        mine = self._last_state
        theirs = None if self._loop is None else self._loop.last_state()
        if theirs is not None and (mine is None or theirs[0] > mine[0]):
            return np.array(theirs[1]), np.array(theirs[2])
        return (None, None) if mine is None else (mine[1], mine[2])

    def _loop_report(self) -> dict[str, int]:
        """The process's counters with the compiled loop's, and its notes logged."""
        stats = dict(self.stats)
        if self._loop is None:
            return stats
        for note in self._loop.take_notes():
            log.error("%s", note)
        c = self._loop.counters()
        stats["states"] = c["states"]
        stats["commands"] += c["commands"]
        stats["bad_messages"] += c["errors"]
        stats["compiled_commands"] = c["commands"]
        return stats

    def _adapt_model(self, now: float) -> None:
        """Eq. (29) on the replay's states collected since the last call; the law takes the
        adapted model once the arm is neither taught nor replayed (a model never changes
        under the operator's hand or mid-program)."""
        adapt, ctl = self.adaptation, self.ctl
        if adapt is None or ctl is None:
            return
        adapt.process()
        if adapt.version == self._adaptation_applied or ctl.engaged:
            return
        with self._lock:
            state = self._fresh_state(now)
        if state in (Lifecycle.TEACHING, Lifecycle.REPLAYING):
            return
        self._apply_adaptation(save=True)

    def _apply_adaptation(self, save: bool) -> None:
        """The law (and the load check) compensate the adapted model from now on; ``save``:
        keep it across restarts (``model_adaptation_file``)."""
        adapt, ctl = self.adaptation, self.ctl
        assert adapt is not None and ctl is not None
        model = ctl.model
        assert isinstance(model, IdentifiedControlModel)
        ctl.model = IdentifiedControlModel(adapt.adapted(), model.desc)
        self._adaptation_applied = adapt.version
        before, after = adapt.residual_rms_nm()
        log.info(
            "model %s (eq. 29): %+.2f kg at %s m on the flange; motor torque RMS over %d "
            "windows of this run, as identified %s, as adapted %s N·m",
            "adapted in replay" if save else "restored as adapted before",
            adapt.mass_kg, adapt.com_m, adapt.windows_used, before, after,
        )  # fmt: skip
        path = self.cfg.model_adaptation_file
        if save and path is not None and self._model_sha256:
            try:
                save_state(path, adapt, self._model_sha256)
                self.adaptation_problem = None
            except OSError as exc:
                self.adaptation_problem = f"adapted payload not kept: {path}: {exc}"
                log.error("%s", self.adaptation_problem)

    def _adaptation_report(self) -> dict | None:
        """Eq. (29) for the health (the operator's status) and the telemetry: the mass the
        law compensates, and the model's error on this run's replays (data it was not
        fitted to)."""
        adapt = self.adaptation
        if adapt is None:
            return None
        return {
            **adapt.report(),
            "applied": self._adaptation_applied == adapt.version,
            "restored": self._adaptation_restored,
            "problem": self.adaptation_problem,
        }

    def run(self, notifier: Any = None) -> None:
        """The slow loop (pressure set-points, health, telemetry) until :attr:`stop_event`."""
        s = self.session
        assert s is not None
        period = 1.0 / HEALTH_RATE_HZ
        while not self.stop_event.wait(min(period, PRESSURE_PUBLISH_PERIOD_S)):
            now = self.clock()
            self._adapt_model(now)
            adapted = self._adaptation_report()
            p2, p3 = self.pressure_setpoints(now)
            s.put(self.keys.pressure_setpoint, PressureSetpoint(now, p2, p3).to_bytes())
            health = {
                "process": "control",
                "stamp_s": now,
                "engaged": self.ctl is not None and self.ctl.engaged,
                "engagement": None if self.ctl is None else self.ctl.engagement(),
                **self._loop_report(),
                "lifecycle_dropped": dict(self.lifecycle_order.dropped),
                "load_check": None
                if self.load_check is None
                else {**self.load_check.to_json(), "age_s": round(now - self.load_check_s, 3)},
                "model_adaptation": adapted,
            }
            s.put(self.keys.health("control"), encode_json(health))
            if self.ctl is not None:
                tele = {
                    "stamp_s": now,
                    "tau_d_nm": [round(float(v), 3) for v in self.ctl.tau_d_nm],
                    "offset_rad": [round(float(v), 6) for v in self.ctl.loop.offset_rad],
                    "omega_rad_s_per_nm": [float(f"{v:.5g}") for v in self.ctl.loop.omega],
                    "upsilon_i_per_s": [float(f"{v:.5g}") for v in self.ctl.loop.upsilon_i],
                }
                if isinstance(self.ctl, AdmittanceController):
                    adm = self.ctl.admittance
                    tele["hand_torque_nm"] = [round(float(v), 3) for v in adm.tau_h]
                    tele["hand_band_nm"] = [round(float(v), 3) for v in adm.band]
                    tele["reference_speed_rad_s"] = [round(float(v), 6) for v in adm.dq_r]
                if adapted is not None:
                    tele["model_adaptation"] = adapted
                est = self.ctl.inner_estimate
                if est is not None:
                    tele["inner_loop_estimate"] = {
                        "omega_rad_s_per_nm": _finite_or_none(est.omega_rad_s_per_nm),
                        "upsilon_i_per_s": _finite_or_none(est.upsilon_i_per_s),
                        "rel_std": [[round(float(v), 4) for v in r] for r in est.rel_std],
                        "rejected_cycles": est.rejected,
                        "seconds": round(est.seconds, 2),
                    }
                s.put(self.keys.control_telemetry, encode_json(tele))
            if self.player.plan_id is not None:
                s.put(self.keys.experiment, encode_json(self.player.report()))

    def stop(self) -> None:
        self.stop_event.set()


def configure_parser(p: argparse.ArgumentParser) -> None:
    p.description = (
        "Run the zero-moment lead-through control process. It reads joint state and pressures "
        "from the zenoh bus and publishes joint position/velocity commands while the gateway "
        "is TEACHING. Normally started by `leadthrough gateway`."
    )
    p.add_argument("--config", type=Path, required=True, help="cell config TOML")
    p.add_argument("--bus", default=None, help="zenoh router endpoint (overrides the config)")


def cli_main(args: argparse.Namespace) -> int:
    """Run until SIGTERM/SIGINT (:func:`gateway.runner.run_service`): 0 on a clean stop,
    EXIT_CONFIG (78) on a bad config, 1 on any other failure."""

    def build() -> ControlProcess:
        cfg, bus = load_control_config(args.config)
        return ControlProcess(cfg, bus.with_overrides(args.bus))

    return run_service("control", build)
