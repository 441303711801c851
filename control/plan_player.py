"""The plan player (:class:`PlanPlayer`): an excitation plan (control/experiments.py) or a
taught program's replay path played as position/velocity commands, one sample per controller
cycle, built off the cycle (control/plan_builder.py); and the speed limits of a replay. The
control process (control/process.py) runs it while the gateway identifies or replays.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable

import numpy as np

from control.plan_builder import Parts, PlanBuilder, PlanRefused, build_parts
from gateway.messages import FLAG_PREV_HOLD, JointState
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
#: a fractional plan index this close to a sample is that sample
_INDEX_TOLERANCE = 1e-9


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
        self._planning_since = 0.0  #: when planning began, on :attr:`clock` [s]
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
            self._job, self._planning_since = self.builder.submit(*args), self.clock()
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
