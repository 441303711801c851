"""The sensorless admittance law (:class:`AdmittanceController`, ``[control].strategy =
"admittance"``): the hand's torque from the motor current, the arm on a reference of a share
of its inertia; behind the zero-moment law's interface (control/zero_moment_law.py), free of
I/O. Its cycle is compiled (control/rt/src/law/admittance/cycle.rs: the engagement and its
probe, the stick zone or anchor, the start-up dither, the soft walls, the guide, the speed
limit, the command), and the control process's compiled loop runs it with no Python on the
cycle (control/rt/src/py_cycle_loop.rs). What stays here is what is not per cycle: building it
from the config, M̂ of the identified model (computed off the cycle, :meth:`refresh_mass`), the
operator's status and log.
"""

from __future__ import annotations

import json
import logging
from collections.abc import Sequence
from typing import Any

import numpy as np

from control import _rt
from control._rt import Admittance
from control.config import ControlConfig
from control.declared_model import DeclaredModel
from control.stribeck_speed import stribeck_speeds
from control.zero_moment_law import INERTIA_STEP_RAD, ZeroMomentController
from gateway.errors import MessageError
from gateway.messages import JointState

log = logging.getLogger("leadthrough.control")

#: after a cycle the drive held or coasted on its own, the currents of this many further states
#: are the vendor loop's answer to that step of the command, not a hand's (the compiled cycle's
#: constant, with its measurement: control/rt/src/law/admittance/cycle.rs)
DRIVE_SETTLE_CYCLES = _rt.ADMITTANCE_DRIVE_SETTLE_CYCLES


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
        settings = {
            "max_offset_rad": list(cfg.max_offset_rad),
            "stick": cfg.admittance_stick,
            "stick_zone": cfg.admittance_stick_zone,
            "probe_speed_rad_s": cfg.admittance_probe_speed_rad_s,
            "probe_s": cfg.admittance_probe_s,
            "dither": cfg.admittance_dither,
            "dither_hz": cfg.admittance_dither_hz,
            "identified_mass": self._identified is not None,
            "inertia_step_rad": INERTIA_STEP_RAD,
        }
        #: the compiled cycle (control/rt/src/law/admittance/cycle.rs) over the zero-moment
        #: law's pieces and :attr:`admittance`
        self.compiled = _rt.AdmittanceCycle(json.dumps(settings), self._cycle, self.admittance)
        self._mass: tuple[np.ndarray, np.ndarray] | None = None

    @property
    def _identified(self) -> Any:
        return getattr(self.model, "identified", None)

    @property
    def tau_d_nm(self) -> np.ndarray:
        return np.array(self.compiled.tau_d_nm)

    @property
    def bias(self) -> np.ndarray:
        """The residual b of (A1) the engagement measured [N·m]."""
        return np.array(self.compiled.bias)

    @property
    def probing(self) -> bool:
        """The engagement probe runs."""
        return self.compiled.probe_span is not None

    def disengage(self) -> None:
        self.compiled.disengage()

    def engagement(self) -> dict[str, Any]:
        """As the zero-moment law's, plus ``"probing"`` while the engagement probe moves the
        arm, with ``left_s``, its time still to run [s] (the painter should hold the tool
        lightly and not push: a push now is taken for the model's error)."""
        span, last = self.compiled.probe_span, self.last_cycle
        if span is None or not self.engaged:
            return super().engagement()
        start, length, period = span
        done = 0 if last is None else last - start
        left = length + self.cfg.command_delay_cycles + 1 - done
        return {"phase": "probing", "left_s": round(max(left, 0) * period, 2)}

    def mass(self, q: np.ndarray) -> np.ndarray:
        """M̂(q), recomputed after a joint moved INERTIA_STEP_RAD: the identified model's
        (in the unit its torques and the drives' currents share), or the nominal rigid body's
        with rotor inertias where the model has none or its M̂ is not positive definite."""
        cached = self._mass
        if cached is None or float(np.max(np.abs(q - cached[0]))) > INERTIA_STEP_RAD:
            cached = self._mass = (q.copy(), self._mass_at(q))
        return cached[1]

    def _mass_at(self, q: np.ndarray) -> np.ndarray:
        identified = self._identified
        if identified is not None:
            n = self.model.n
            ddq = np.vstack([np.zeros(n), np.eye(n)])
            tau = identified.torque_nm(np.tile(q, (n + 1, 1)), np.zeros((n + 1, n)), ddq)
            m = (tau[1:] - tau[0]).T
            m = 0.5 * (m + m.T)
            if np.isfinite(m).all() and np.linalg.eigvalsh(m).min() > 0:
                return m
        return np.array(self._inertia.mass_matrix(q.tolist(), armature=True))

    def refresh_mass(self, q: np.ndarray) -> bool:
        """Hand the compiled cycle M̂ at ``q`` (the reference; before engaging, the arm's
        pose) if it has none of the identified model within INERTIA_STEP_RAD of it: the
        identified model is evaluated here, off the cycle (the control process's mass thread,
        or before a cycle in a direct call). True if it did."""
        if not self.compiled.mass_wanted(q.tolist()):
            return False
        self.compiled.set_mass(q.tolist(), self.mass(q).tolist())
        return True

    def mass_pose(self, measured_q: np.ndarray | None) -> np.ndarray | None:
        """Where M̂ is wanted: the reference while the admittance follows a hand, else (before
        it engages, while its probe runs: the reference then is the last one's, and the
        admittance starts where the arm is) the arm's pose ``measured_q``."""
        if self.engaged and not self.probing:
            return np.array(self.admittance.q_r)
        return measured_q

    def model_torque(self, q: np.ndarray, dq: np.ndarray, ddq: np.ndarray, p_bar) -> np.ndarray:
        """What the drives must give for the arm to move so, without a hand [N·m]: M̂ q̈ +
        gravity − cylinders + the model's friction where it opposes the motion, at the speed
        beyond the friction deadband (the compiled cycle's, with :meth:`mass` at ``q``)."""
        return np.array(self.compiled.model_torque(
            np.asarray(q, dtype=float).tolist(), np.asarray(dq, dtype=float).tolist(),
            np.asarray(ddq, dtype=float).tolist(), [float(v) for v in p_bar],
            self.mass(np.asarray(q, dtype=float)).tolist(),
        ))  # fmt: skip

    def probe_speeds(self, friction_level_nm: np.ndarray) -> np.ndarray:
        """The engagement probe's cruise speed per joint [rad/s] (the compiled cycle's)."""
        return np.array(self.compiled.probe_speeds(np.asarray(friction_level_nm).tolist()))

    def log_events(self) -> None:
        """Log what the compiled cycle said since the last call (its engagement, its probe)."""
        for warning, text in self.compiled.take_events():
            log.log(logging.WARNING if warning else logging.INFO, "%s", text)

    def answer(self, st: JointState, p_bar: Sequence[float]) -> tuple[list[float], list[float]]:
        """``(q_cmd, dq_cmd)`` answering ``st`` with cylinder pressures ``p_bar`` [bar]: the
        compiled cycle, with M̂ refreshed first (a direct call: the tests, the control
        process's Python path). Raises MessageError where the model or the estimate is
        undefined."""
        pose = self.mass_pose(st.q_rad)
        if pose is not None:
            self.refresh_mass(pose)
        try:
            return self.compiled.answer(
                st.cycle, st.flags, st.cycle_period_s, st.q_rad.tolist(), st.dq_rad_s.tolist(),
                st.q_cmd_rad.tolist(), st.dq_cmd_rad_s.tolist(), st.current_a.tolist(),
                [float(v) for v in p_bar],
            )  # fmt: skip
        except (ValueError, ArithmeticError) as exc:  # where numpy would have given NaN
            text = str(exc)
            raise MessageError(
                text if text.startswith("cycle") else f"cycle {st.cycle}: {text}"
            ) from None
        finally:
            self.log_events()
