"""The lock-step plant's pace: its time runs at most ``speedup`` times as fast as the wall clock.

Lock-step (:meth:`sim_bridge.sim.VirtualCell._run_lockstep`) waits for the product's answer
to every cycle, so a slow product slows the plant; the pace is the other bound, the one a
fast product meets: the Modbus driver samples the I/O on its wall clock, and a plant faster
than ``speedup`` × the wall clock is sampled too sparsely in its own time
(``[lockstep_max_speedup]`` in :mod:`sim_bridge.config`).

A plant that fell behind the pace (the product answered late) goes on at the pace from where
it is, as a real-time controller restarts its schedule after an overrun. Catching up would run
it faster than the bound for as long as it was behind, and would load the machine most just
after it was too slow: beside a busy process at 3x that was the product's whole CPU.
"""

from __future__ import annotations


class LockstepPace:
    """When the next lock-step cycle may start, from the plant's time and the wall clock."""

    def __init__(self, speedup: float, slack_s: float, wall_s: float, plant_s: float) -> None:
        """``slack_s``: how far behind the pace [s of wall time] the plant may be before the
        pace restarts from where it is (a cycle's wall time: one late answer is no reason)."""
        if not speedup > 0:
            raise ValueError(f"speedup {speedup} must be > 0")
        self.speedup, self.slack_s = speedup, slack_s
        self._wall0, self._plant0 = wall_s, plant_s
        self.restarts = 0  #: times the plant fell behind by more than the slack

    def wait_s(self, plant_s: float, wall_s: float) -> float:
        """How long to wait [s] before the cycle at plant time ``plant_s`` starts, at wall
        time ``wall_s``: 0 at or behind the pace."""
        ahead = (plant_s - self._plant0) / self.speedup - (wall_s - self._wall0)
        if ahead > 0:
            return ahead
        if ahead < -self.slack_s:
            self._wall0, self._plant0 = wall_s, plant_s
            self.restarts += 1
        return 0.0
