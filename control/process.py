"""`leadthrough control`: the zero-moment lead-through control process.

For every JointState it has the lead-through law compute a position/velocity command
(control/zero_moment_law.py, control/admittance_law.py) or plays a plan (control/plan_player.py).
It publishes a command only while the gateway says TEACHING and the cylinder pressures are fresh;
otherwise it stays silent and the CAN driver holds position. While the arm is held at rest it
checks that the model carries the arm's static load (control/load_check.py) and reports the
verdict in its health; the gateway starts teaching only on a passing one.
"""

from __future__ import annotations

import argparse
import logging
import math
import threading
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from control import _rt
from control.admittance_law import AdmittanceController
from control.cell_config import load_control_config
from control.config import ControlConfig
from control.declared_model import DeclaredModel
from control.load_check import REST_RAD_S, LoadCheck, static_load_check
from control.mass_refresh import MassRefresh
from control.plan_builder import PlanBuilder
from control.plan_player import PlanPlayer
from control.pressure_schedule import PressureSchedule, ScheduleSettings
from control.process_adaptation import ProcessAdaptation
from control.zero_moment_law import ZeroMomentController
from gateway import bus_security as security
from gateway.bus import (
    BusConfig,
    declare_loop_publisher,
    open_peer,
    peer_config_entries,
    undeclare_all,
)
from gateway.errors import ConfigError, MessageError
from gateway.guide_modes import guide_problem
from gateway.message_factories import make_joint_command
from gateway.messages import (
    COMMANDING,
    HEALTH_RATE_HZ,
    PLAYING,
    SERVO_ON,
    IoState,
    JointCommand,
    JointState,
    Lifecycle,
    LifecycleMsg,
    LifecycleOrder,
    PressureSetpoint,
    encode_json,
)
from gateway.ratelog import RateLimitedLog
from gateway.realtime import below_the_cycle
from gateway.robot.description import load_description
from gateway.runner import run_service

log = logging.getLogger("leadthrough.control")

PRESSURE_PUBLISH_PERIOD_S = 0.1
#: the pressure schedule follows the pose in teaching and replay only while a joint moves
#: faster than this [rad/s] (:meth:`ControlProcess.pressure_setpoints`)
SCHEDULE_MOVING_RAD_S = 0.01
#: the static-load check runs at most this often [s] (the gateway accepts one up to 0.5 s old)
LOAD_CHECK_PERIOD_S = 0.1


def _finite_or_none(values: Sequence[float]) -> list[float | None]:
    """5 significant digits, None where not finite (JSON has no NaN)."""
    return [float(f"{v:.5g}") if math.isfinite(v) else None for v in values]


class ControlProcess(ProcessAdaptation):
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
        #: the admittance's M̂ of the identified model, off the cycle (control/mass_refresh.py)
        self._mass_refresh: MassRefresh | None = None
        #: the newest state Python handled: (cycle, q, dq)
        self._last_state: tuple[int, np.ndarray, np.ndarray] | None = None
        #: the latest static-load check and when it was made (monotonic [s])
        self.load_check: LoadCheck | None = None
        self.load_check_s = -1e9
        #: why the newest held state was not checked (None: it was, or it came too soon after
        #: the last check): the operator's status names it while teaching waits for a check
        self.load_waiting: str | None = None
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
        # eq. (29) in replay, and the adapted mass kept (control/process_adaptation.py)
        self._init_adaptation()

    def open(self) -> None:
        self.session = open_peer(self.bus, security.CONTROL)
        s = self.session
        self._pub_cmd = declare_loop_publisher(s, self.keys.joint_command)
        # Both laws' teaching cycles are compiled, and the plans play compiled (without a
        # model too: an identification's).
        law = None
        if isinstance(self.ctl, AdmittanceController):
            law = self.ctl.compiled
            self._mass_refresh = MassRefresh(self.ctl, lambda: self._last_pose()[0])
            self._mass_refresh.start()
        elif self.ctl is not None:
            law = self.ctl._cycle
        self._loop = _rt.CycleLoop(
            peer_config_entries(self.bus, security.CONTROL), self.keys.joint_state,
            self.keys.joint_command, law, self._on_state_bytes, self.player.play,
            law is not None and self.adaptation is not None,
        )  # fmt: skip
        self._subs = [
            s.declare_subscriber(self.keys.io_state, self._on_io),
            s.declare_subscriber(self.keys.lifecycle, self._on_lifecycle),
        ]

    def close(self) -> None:
        if self._mass_refresh is not None:
            self._mass_refresh.stop()
        if self._loop is not None:
            self._loop.close()
        undeclare_all([*self._subs, self._pub_cmd])
        self._subs, self._pub_cmd = [], None
        if self.session is not None:
            self.session.close()
            self.session = None
        self.plan_builder.close()
        self._saver.shutdown(wait=True)  # the adapted mass on disk before the process ends
        self._check_saved()

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
                    self._apply_guide(msg)
                    self._drop_stale_plan(msg)
                    if self._loop is not None:
                        self._loop.set_lifecycle(
                            msg.state == Lifecycle.TEACHING, self.lifecycle_rx_s,
                            self.cfg.lifecycle_timeout_s, self._playing(msg),
                        )  # fmt: skip
            if dropped is not None:
                self._ratelog(
                    logging.WARNING, f"lifecycle_{dropped}", "lifecycle seq %d %s dropped: %s",
                    msg.seq, msg.state.name, dropped,
                )  # fmt: skip

    def _drop_stale_plan(self, msg: LifecycleMsg) -> None:
        """``msg`` names a plan other than the player's: the player drops its own, so that
        the compiled loop plays nothing of it and the next state comes to
        :meth:`_on_state_bytes`, which starts the new one (lock held)."""
        plan = msg.extra.get("plan") if msg.state in PLAYING else None
        if isinstance(plan, dict) and str(plan.get("plan_id")) != self.player.plan_id:
            self.player.drop()

    @staticmethod
    def _playing(msg: LifecycleMsg) -> str | None:
        """What the compiled loop may play under ``msg``: "identifying" or "replaying" (it
        plays only what its slot holds: :meth:`_drop_stale_plan`), else None."""
        return msg.state.name.lower() if msg.state in PLAYING else None

    def _apply_guide(self, msg: LifecycleMsg) -> None:
        """The constrained guide the gateway's lifecycle names (``guide``, the operator's
        `leadthrough start --guide`), else the config's; the law takes a new one's reference
        at its next cycle. A name that is not a guide keeps the one in force (lock held)."""
        ctl = self.ctl
        if ctl is None:
            return
        guide = msg.extra.get("guide", self.cfg.guide)
        if guide == ctl.guide:
            return
        problem = guide_problem(guide)
        if problem is not None:
            self.stats["bad_messages"] += 1
            self._ratelog(
                logging.ERROR, "lifecycle_guide", "lifecycle seq %d: %s; the guide stays %s",
                msg.seq, problem, ctl.guide,
            )  # fmt: skip
            return
        ctl.guide = guide
        log.info("guide → %s", guide)

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
        following = st.controller_state in SERVO_ON
        period = st.cycle_period_s or self.cfg.default_cycle_period_s
        if mode is None or not following:
            if ctl is not None:
                ctl.disengage()
                if following:
                    ctl.observe_hold(st)
            if not following:
                self.load_waiting = f"the drives do not hold the arm ({st.controller_state.name})"
            elif io is None:
                self.load_waiting = "no pressures from the Modbus driver yet"
            elif now - io.stamp_s > self.cfg.io_timeout_s:
                self.load_waiting = (
                    f"the pressures are {now - io.stamp_s:.2f} s old "
                    f"(over {self.cfg.io_timeout_s:g} s)"
                )
            else:
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
            self.load_waiting = None
            return
        speed = np.abs(st.dq_rad_s)
        if float(np.max(speed)) > REST_RAD_S:
            j = int(np.argmax(speed))
            self.load_waiting = (
                f"the arm is not at rest: J{j + 1} at {speed[j] * 1e3:.1f} mrad/s "
                f"(rest: below {REST_RAD_S * 1e3:g})"
            )
            return
        self.load_waiting = None
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

    def run(self, notifier: Any = None) -> None:
        """The slow loop (pressure set-points, health, telemetry) until :attr:`stop_event`."""
        s = self.session
        assert s is not None
        below_the_cycle("control")  # the cycle's threads exist (open): they keep its priority
        period = 1.0 / HEALTH_RATE_HZ
        while not self.stop_event.wait(min(period, PRESSURE_PUBLISH_PERIOD_S)):
            now = self.clock()
            self.player.poll()  # a plan built off the cycle: the compiled loop plays it next
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
                "load_check_waiting": self.load_waiting,
                "model_adaptation": adapted,
                "guide": self._guide_report(),
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

    def _guide_report(self) -> dict[str, Any] | None:
        """The constrained guide in force and the last cycle's deviation from it."""
        if self.ctl is None:
            return None
        off_m, turned_rad = self.ctl.guide_deviation()
        return {
            "mode": self.ctl.guide,
            "deviation_mm": round(1000.0 * off_m, 2),
            "rotation_deg": round(math.degrees(turned_rad), 3),
        }

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

    return run_service("control", build, place=getattr(args, "place", None))
