"""The plan player (:class:`PlanPlayer`): an excitation plan (control/experiments.py) or a
taught program's replay path played as position/velocity commands, one sample per controller
cycle, built off the cycle (control/plan_builder.py) and played by compiled code
(control/rt/src/law/plan_play.rs); and the speed limits of a replay. The control process
(control/process.py) runs it while the gateway identifies or replays: its compiled loop plays
the built plan from zenoh's thread (control/rt/src/py_cycle_loop.rs, issue 48).
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable

import numpy as np

from control import _rt
from control.plan_builder import Parts, PlanBuilder, PlanRefused, build_parts
from gateway.messages import JointState
from gateway.program import MAX_JOINT_SPEED_RAD_S as MAX_REPLAY_JOINT_SPEED_RAD_S
from gateway.program import MAX_SPEED_MM_S
from gateway.robot.description import RobotDescription

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


class PlanPlayer:
    """Plays an excitation plan (control/experiments.py) or a taught program's replay path as
    position/velocity commands, one sample per controller cycle, starting from the position
    the robot is holding.

    The plan is built off the cycle (control/plan_builder.py) when a ``builder`` is given:
    meanwhile the player is ``planning`` and every cycle is answered with the plan's first
    sample, the pose the robot holds, at rest, by the compiled loop (a plan of that one sample
    sits in :attr:`play` until the built one replaces it; Python answers only a state the loop
    passes on). The owner's slow loop calls :meth:`poll` to take the built plan (so does
    :meth:`command`). A plan not built within :attr:`MAX_PLANNING_S` fails.
    Without a builder (pure tests) :meth:`start` builds it in place. A built plan goes into
    :attr:`play` (``control._rt.PlanPlay``), which plays it as described below: from the
    control process's compiled loop, which answers the states with it, or from
    :meth:`command`.

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
    #: the plan fails when it is not built within this long [s] of the wall clock; the arm
    #: holds meanwhile, so the limit only ends a wait for a worker that cannot finish (one
    #: that dies fails the plan at once). The demo's replay path built in 1.5-2.3 s in the
    #: worker on one shared core (2026-12-01, issue 45's demos under taskset -c 0);
    #: commissioning's 275 s excitation plan in 3.0 s on one core beside a busy process, and in
    #: 26.5 s there with the virtual controller at SCHED_FIFO above the product (the worker,
    #: niced, gets what the cycle and the busy process leave, 2026-12-03): four times that
    MAX_PLANNING_S = 120.0

    def __init__(
        self,
        lower_rad: np.ndarray,
        upper_rad: np.ndarray,
        desc: RobotDescription | None = None,
        builder: PlanBuilder | None = None,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.lower, self.upper = lower_rad, upper_rad
        #: the wall clock planning is timed on (the builder computes in wall time)
        self.clock = clock
        self.desc = desc  #: the robot, for a taught program's tool path (plan key "replay")
        self.builder = builder
        self.plan_id: str | None = None
        #: idle | planning | failed (before a plan was built) | played (:attr:`play` has it)
        self._phase = "idle"
        self._reason = ""
        self.start_cycle = 0
        self.period_s = 0.0
        self.q = self.dq = np.zeros((0, len(lower_rad)))
        self._labels: list[tuple[str, str]] = []  #: each segment's (label, role)
        #: the built plan, played here or by the compiled loop (control/rt/src/py_plan_play.rs)
        self.play = _rt.PlanPlay()
        self._logged = "idle"  #: the state last logged (the compiled play changes it silently)
        self._q0 = np.zeros(len(lower_rad))  #: where the plan starts, held while planning
        self._job: int | None = None  #: the builder's job of the plan being built
        self._planning_since = 0.0  #: when planning began, on :attr:`clock` [s]
        self.planning_s = 0.0  #: how long the plan took to build [s] (reported)
        #: one thread at a time takes the builder's outcome (:meth:`poll` on the slow loop,
        #: :meth:`command` on the cycle's callback); the other goes on without waiting
        self._taking = threading.Lock()

    # --- where the plan is: the compiled play's once it has the plan --------------------------
    def _status(self) -> tuple | None:
        """One reading of the compiled play's status (None: the plan is not played there).
        It is played on the compiled loop's thread: what one answer reports comes from one
        reading, so its state, sample and segment cycles agree."""
        return self.play.status() if self._phase == "played" else None

    def _state_of(self, status: tuple | None) -> str:
        return self._phase if status is None else status[0]

    def _reason_of(self, status: tuple | None) -> str:
        return self._reason if status is None else status[1]

    def _segments_of(self, status: tuple | None) -> list[dict]:
        cycles = [(-1, -1)] * len(self._labels) if status is None else status[5]
        return [
            {"label": label, "role": role, "start_cycle": None if a < 0 else a,
             "end_cycle": None if b < 0 else b}
            for (label, role), (a, b) in zip(self._labels, cycles, strict=True)
        ]  # fmt: skip

    @property
    def state(self) -> str:
        """idle | planning | running | done | failed."""
        return self._state_of(self._status())

    @property
    def reason(self) -> str:
        return self._reason_of(self._status())

    @property
    def k(self) -> int:
        """The plan sample to play next."""
        status = self._status()
        return 0 if status is None else status[2]

    @property
    def repeats(self) -> int:
        """Samples sent again after a hold."""
        status = self._status()
        return 0 if status is None else status[4]

    @property
    def segments(self) -> list[dict]:
        """Each segment's label, role and the cycles that carried out its first and last
        sample (None: not yet), for the export."""
        return self._segments_of(self._status())

    def start(self, plan: dict, st: JointState, period_s: float) -> None:
        with self._taking:  # not while the slow loop takes the last plan's outcome
            self._start(plan, st, period_s)

    def _start(self, plan: dict, st: JointState, period_s: float) -> None:
        self.play.clear()  # the compiled loop plays nothing until this plan is built
        self.plan_id, self._phase, self._reason = str(plan.get("plan_id")), "idle", ""
        self._logged = "idle"
        self.start_cycle, self.period_s = st.cycle, period_s
        self._labels, self.planning_s = [], 0.0
        self._q0 = st.q_cmd_rad.copy()
        limits = {
            "max_speed_m_s": MAX_REPLAY_SPEED_M_S,
            "max_joint_speed_rad_s": MAX_REPLAY_JOINT_SPEED_RAD_S,
            "max_point_speed_m_s": MAX_REPLAY_POINT_SPEED_M_S,
        }
        args = (plan, self._q0.copy(), self.lower, self.upper, period_s, self.LIMIT_MARGIN_RAD,
                self.desc, limits)  # fmt: skip
        if self.builder is not None:
            self._phase = self._logged = "planning"
            self._job, self._planning_since = self.builder.submit(*args), self.clock()
            self._hold_while_planning()
            log.info("excitation plan %s: planning", self.plan_id)
            return
        try:
            self._install(build_parts(*args))
        except PlanRefused as exc:
            self.fail(str(exc))

    def _hold_while_planning(self) -> None:
        """The compiled loop answers the cycles while the plan is built, with a plan of one
        sample: where the plan will start, at rest (what :meth:`command` answers meanwhile),
        so no Python is on the cycle then either (issue 48). On an emulated machine 3.5 times
        slower (tests/slow_machine.py) the demo's replay took 25-30 s to plan (the worker gets
        what the cycle's threads leave), all of it answered by Python before; the CAN driver's
        late answers meanwhile did not fall with this (26 and 29 warnings a run: that machine
        lacks CPU, 2026-12-07). Its pause limit is the planning's: the driver holding it is
        no reason to fail a plan not built yet."""
        n = len(self._q0)
        try:
            self.play.install(self._q0.tolist(), [0.0] * n, n, [1], self.period_s,
                              self.MAX_PLANNING_S, RESUME_ACCEL_RAD_S2)  # fmt: skip
        except ValueError as exc:  # a held pose that is not finite: Python answers, as before
            log.warning("excitation plan %s: the hold while planning stays in Python: %s",
                        self.plan_id, exc)  # fmt: skip

    def poll(self) -> None:
        """While planning: take the built plan if it came (the compiled loop plays it from
        its next cycle), or fail the plan when it takes too long. Called by the owner's slow
        loop; cheap otherwise."""
        if self._phase != "planning" or not self._taking.acquire(blocking=False):
            return
        try:
            if self._phase == "planning":
                self._planned()
        finally:
            self._taking.release()

    def drop(self) -> None:
        """Forget the plan (another is coming): the compiled loop plays nothing of it, and
        the player is idle until :meth:`start`."""
        with self._taking:  # an outcome taken meanwhile would install the dropped plan
            self.play.clear()
            self._job, self._phase, self._reason = None, "idle", ""

    def fail(self, why: str) -> None:
        """The plan ends here, failed, with ``why``; nothing more is sent for it."""
        self._job = None
        if self._phase == "played":
            self.play.fail(why)
        else:
            self.play.clear()  # the hold while planning ends too: nothing is sent for it
            self._phase, self._reason = "failed", why
        self._log_state(self._status())

    def _install(self, parts: Parts) -> None:
        self._labels = [(label, role) for label, role, _q, _dq in parts]
        self.q = np.vstack([p[2] for p in parts])
        self.dq = np.vstack([p[3] for p in parts])
        self._job = None
        try:
            self.play.install(
                self.q.ravel().tolist(), self.dq.ravel().tolist(), self.q.shape[1],
                [len(p[2]) for p in parts], self.period_s, self.MAX_PAUSE_S, RESUME_ACCEL_RAD_S2,
            )  # fmt: skip
        except ValueError as exc:
            self.fail(f"the plan cannot be played: {exc}")
            return
        self._phase = self._logged = "played"
        log.info("excitation plan %s: %d segments, %.1f s (built in %.2f s)", self.plan_id,
                 len(parts), len(self.q) * self.period_s, self.planning_s)  # fmt: skip

    def _log_state(self, status: tuple | None) -> None:
        """Log the plan's end (done or failed) once, whoever played it (``status``: a reading
        of :meth:`_status`)."""
        state = self._state_of(status)
        if state == self._logged or state not in ("done", "failed"):
            return
        self._logged = state
        if state == "done":
            log.info("excitation plan %s done (%d samples sent again after a hold)",
                     self.plan_id, 0 if status is None else status[4])  # fmt: skip
        else:
            log.error("excitation plan %s failed: %s", self.plan_id, self._reason_of(status))

    def _planned(self) -> None:
        """While planning: take the builder's outcome if it came, or fail the plan when it
        takes too long (one thread at a time: :attr:`_taking`)."""
        assert self.builder is not None and self._job is not None
        # wall time, not cycles: the worker computes in wall time, and a lock-stepped
        # virtual plant runs its cycles up to three times as fast (sim_bridge/commission.py):
        # counted in cycles, 30 s of planning was 10 s of the worker's (2026-12-03)
        self.planning_s = self.clock() - self._planning_since
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

    def command(self, st: JointState) -> tuple[np.ndarray, np.ndarray] | None:
        """This cycle's sample (q [rad], dq [rad/s]), or None when nothing is to be sent."""
        if self._phase == "planning":
            self.poll()
            if self._phase == "planning":
                return self._q0, np.zeros_like(self._q0)  # held where the plan will start
        if self._phase != "played":
            return None
        sample = self.play.command(st.cycle, st.flags)
        self._log_state(self._status())
        return None if sample is None else (np.array(sample[0]), np.array(sample[1]))

    def report(self) -> dict:
        """Where the plan is, from one reading of the compiled play's status."""
        status = self._status()
        self._log_state(status)
        return {
            "plan_id": self.plan_id,
            "state": self._state_of(status),
            "reason": self._reason_of(status),
            "progress": (0 if status is None else status[2]) / max(len(self.q), 1),
            "start_cycle": self.start_cycle,
            "repeated_samples": 0 if status is None else status[4],
            "planning_s": round(self.planning_s, 3),
            "segments": self._segments_of(status),
        }
