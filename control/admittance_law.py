"""The sensorless admittance law (:class:`AdmittanceController`, ``[control].strategy =
"admittance"``): the hand's torque from the motor current, the arm on a reference of a share
of its inertia; behind the zero-moment law's interface (control/zero_moment_law.py), free of
I/O. The control process (control/process.py) runs it.
"""

from __future__ import annotations

import logging
from collections import deque
from collections.abc import Sequence
from typing import Any

import numpy as np

from control import _rt
from control._rt import Admittance, EngageProbe
from control.config import ControlConfig
from control.declared_model import DeclaredModel
from control.load_check import REST_RAD_S
from control.soft_walls import wall_torque_nm
from control.startup_dither import StartupDither
from control.stick_anchor import StickAnchor
from control.stribeck_speed import stribeck_speeds
from control.zero_moment_law import INERTIA_STEP_RAD, ZeroMomentController
from gateway.errors import MessageError
from gateway.messages import FLAG_PREV_COAST, FLAG_PREV_HOLD, JointState

log = logging.getLogger("leadthrough.control")

#: the admittance measures its estimate's noise on at least this many held states
MIN_NOISE_STATES = 16
#: the admittance's engagement probe breaks a stuck joint away within this share of a quarter
#: of it, at no more than PROBE_MAX_RAD_S (AdmittanceController.probe_speeds)
PROBE_BREAKAWAY_SHARE, PROBE_MAX_RAD_S = 0.4, 0.05
#: the admittance's stick zone fades out between rest and this speed [rad/s]
STICK_RAD_S = 2.0 * REST_RAD_S
#: after a cycle the drive held or coasted on its own (the law's command came late or not at
#: all), the currents of this many further states are the vendor loop's answer to that step
#: of the command, not a hand's: AdmittanceController.answer keeps τ̂_h as it was over them.
#: The vendor loop settles a one-cycle hold in about four cycles: in 49 isolated holds while
#: a hand dragged the arm on the LTC cell (one competing CPU load, 2026-12-03), J1-J3's largest
#: current deviation from the cycles before, p90 over the holds, was 20 A at the hold, then
#: 12, 12, 6, 6, 3.6 A, against about 1 A of scatter between the cycles before
DRIVE_SETTLE_CYCLES = 4


class AdmittanceController(ZeroMomentController):
    """Sensorless admittance (control/rt/src/law/admittance.rs) behind the controller's interface.

    Engages as :class:`ZeroMomentController` does (after the arm has rested in the driver's
    hold): the hold's mean offset and current calibrate ω̂ (the offset that makes the vendor
    loop give a torque) and the residual b of (A1). Then each cycle: τ̂_h from the motor
    current of the cycle that just ended and the reference acceleration that drove it, the
    reference of (A2), and the command ``q_r + ω̂ (τ_model − b) / Υ̂_I``, ``q̇_r``. ω̂ does not
    adapt here: the hand's torque is in the current, so eq. (28) would learn it.
    """

    def __init__(self, cfg: ControlConfig, model: DeclaredModel) -> None:
        super().__init__(cfg, model)
        band = _rt.hold_band_nm(
            cfg.rest_hold_nm or [0.0] * model.n,
            cfg.admittance_band_rms_factor,
            model.heldout_rms_nm,
        )
        self.admittance = Admittance(
            cfg.admittance_mass_fraction,
            cfg.admittance_damping_nm_s_per_rad or cfg.damping_nm_s_per_rad,
            band,
            cfg.admittance_filter_hz,
            cfg.max_velocity_rad_s,
            cfg.admittance_rest_damping_factor,
        )
        # per joint, the speed below which a joint nobody pushes is held [rad/s]
        hold = np.full(model.n, cfg.admittance_hold_rad_s)
        if cfg.admittance_hold_stribeck:
            hold = np.maximum(hold, stribeck_speeds(model, np.zeros(model.n), np.array(band)))
        self.admittance.hold_rad_s = hold.tolist()
        #: ``admittance_stick = "anchor"``: the estimate each resting joint settled with
        self._anchor = StickAnchor(model.n, cfg.admittance_filter_hz)
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
        #: states still to come whose currents a cycle the drive held or coasted drove
        self._drive_own = 0
        #: the start-up dither on each joint whose reference rests (control/startup_dither.py)
        self._dither = StartupDither(cfg.admittance_dither, cfg.admittance_dither_hz,
                                     REST_RAD_S, cfg.command_delay_cycles)  # fmt: skip

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
        if gap > 1 or st.flags & (FLAG_PREV_HOLD | FLAG_PREV_COAST):
            # the drive answered a cycle the law did not command in time: a hold steps the
            # command's speed to zero, which the vendor loop turns into tens of N·m
            self._drive_own = self.cfg.command_delay_cycles + 1 + DRIVE_SETTLE_CYCLES
        if self.cfg.max_tool_speed_m_s > 0:
            self.speed_target_m_s = self.speed_target(st.q_rad, st.dq_rad_s)
        self.last_cycle = st.cycle
        q = st.q_rad
        adm = self.admittance
        if len(self._sent_ddq) == self._sent_ddq.maxlen:
            drove = self._sent_ddq[0]
        else:
            drove = np.array(adm.ddq_r)
        # the drive gave the dither that drove this state too: not a hand
        tau_m = np.array(self.motor_torque_nm(st)) - self._dither.drove()
        # the friction the arm met is at its measured speed, not at the reference's
        tau_h = self.model_torque(q, st.dq_rad_s, drove, p_bar) - self._bias - tau_m
        # a joint at rest: its friction carries any torque up to its static level, which the
        # current cannot tell from a hand (the stick zone, fading out as the joint slides)
        stuck = self._stick * np.maximum(0.0, 1.0 - np.abs(st.dq_rad_s) / STICK_RAD_S)
        zoned = np.sign(tau_h) * np.maximum(np.abs(tau_h) - stuck, 0.0)
        if self.cfg.admittance_stick == "anchor":
            # a joint settled at rest: the push is what moved its estimate off the one it
            # settled with (control/stick_anchor.py); sliding or settling, the stick zone
            rel, settled = self._anchor.hand(
                tau_h, np.abs(st.dq_rad_s) <= REST_RAD_S, np.array(adm.band), dt
            )
            # an arm at rest keeps the stick zone about the anchor
            if not adm.moving:
                rel = np.sign(rel) * np.maximum(np.abs(rel) - stuck, 0.0)
            tau_h = np.where(settled, rel, zoned)
        else:
            tau_h = zoned
        if self._drive_own > 0:
            # currents the drive's own cycle drove: no hand is read from them, the estimate
            # stays where it was (an arm springing back from a hold read as a hand reversed
            # the reference, and a release's stop then ran the arm back: issue 47's item 4)
            self._drive_own -= 1
            tau_h = np.array(adm.tau_h)
        mass = self.mass(np.array(adm.q_r))
        # soft walls, damped for the inertia the reference renders (control/soft_walls.py)
        walls = wall_torque_nm(q, np.array(adm.dq_r), self.lower, self.upper,
                               self.cfg.wall_stiffness_nm_per_rad,
                               adm.alpha * np.diag(mass), dt)  # fmt: skip
        if not (np.isfinite(tau_h).all() and np.isfinite(walls).all()):
            raise MessageError(f"cycle {st.cycle}: hand torque estimate undefined")
        # constrained guiding holds the reference the arm follows on its fixture exactly
        # (control/rt/src/law/guide.rs, Guide::constraint): rows on its speed, or none
        rows, rates = self._cycle.guide_constraint_at(adm.q_r)
        constraint = (rows, rates) if rows else None
        q_r, dq_r = (np.array(v) for v in adm.step(tau_h, walls, mass, dt, constraint))
        ddq_r = np.array(adm.ddq_r)
        self._sent_ddq.append(ddq_r)
        tau = self.model_torque(q_r, dq_r, ddq_r, p_bar) - self._bias
        dither = self._dither.step(dq_r, dt)
        self._tau_d = tau + dither
        offset = np.clip(self.loop.omega * tau / self.loop.upsilon_i, -self._max_offset,
                         self._max_offset)  # fmt: skip
        # the command may lead the arm by at most the offset limit (the controller faults at
        # a larger following error): a hand pushing a joint into a stop cannot wind it up
        q_cmd = np.clip(q_r + offset, q - self._max_offset, q + self._max_offset)
        if not np.array_equal(q_cmd, q_r + offset):
            adm.q_r = q_cmd - offset
        if dither.any():
            # on the command only: the reference stays where (A2) put it
            q_cmd = np.clip(q_cmd + self.loop.omega * dither / self.loop.upsilon_i,
                            q - self._max_offset, q + self._max_offset)  # fmt: skip
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
        self._anchor.reset()
        self._drive_own = 0
        self._dither.reset(self._friction_level)
        self._cycle.restart_guide()
        log.info("admittance engaged: dead zone %s N·m, residual b %s N·m, joints nobody "
                 "pushes held below %s rad/s", np.round(self.admittance.band, 3).tolist(),
                 np.round(self._bias, 2).tolist(),
                 np.round(self.admittance.hold_rad_s, 4).tolist())  # fmt: skip
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
