"""The simulated operator: an enabling device and a hand on the tool.

In ``force`` mode the hand pushes with a scripted force (trapezoid in time). In ``path`` mode it
behaves like a human arm following a target that moves along waypoints: a spring-damper between
target and tool, saturated at ``max_force_n`` — the force it needs is what the paper's Fig. 13
measures with its force sensor.
"""

from __future__ import annotations

from collections import deque
from typing import TYPE_CHECKING

import numpy as np

from sim_bridge.config import OperatorScript

if TYPE_CHECKING:
    from sim_bridge.plant import Plant


#: ``event_min_speed_m_s`` holds for the tool's mean speed over each of the last two such
#: windows [s] (a stop test's "speed at the release" is a mean over 80 ms before it)
EVENT_SPEED_WINDOW_S = 0.1
#: the tremor's frequency per axis, relative, and phases [rad] (:attr:`OperatorScript.tremor_m`)
_TREMOR_AXES = np.array([1.0, 1.13, 0.87])
_TREMOR_PHASES = np.array([0.0, 2.1, 4.2])


class Operator:
    def __init__(self, script: OperatorScript) -> None:
        self.s = script
        self.onset_s: float | None = None  #: sim time teaching began
        self.origin_m: np.ndarray | None = None  #: tool position at onset
        #: with ``event_min_speed_m_s``: the tool's recent positions and the sim times the
        #: release and the e-stop happened (:meth:`observe`)
        self._track: deque[tuple[float, np.ndarray]] = deque()
        self._release_at_s: float | None = None
        self._estop_at_s: float | None = None
        if script.mode == "path":
            wp = np.array(script.path, dtype=float)
            self._t, self._xyz = wp[:, 0], wp[:, 1:4]

    def mark_onset(self, t_s: float, tool_m: np.ndarray) -> None:
        if self.onset_s is None:
            self.onset_s, self.origin_m = t_s, tool_m.copy()

    def observe(self, t_s: float, tool_m: np.ndarray) -> None:
        """The tool's position at the end of each cycle: with ``event_min_speed_m_s`` the
        release and the e-stop, once due, happen at the first cycle by which the tool has
        moved that fast on average over each of the last two :data:`EVENT_SPEED_WINDOW_S`
        (in steady motion, not just breaking away)."""
        if self.s.event_min_speed_m_s <= 0 or self.onset_s is None:
            return
        track, window = self._track, EVENT_SPEED_WINDOW_S
        track.append((t_s, tool_m.copy()))
        while len(track) > 2 and t_s - track[1][0] >= 2 * window:
            track.popleft()
        if t_s - track[0][0] < 2 * window:
            return
        mid = next(p for p in reversed(track) if t_s - p[0] >= window)
        speeds = (
            float(np.linalg.norm(mid[1] - track[0][1])) / (mid[0] - track[0][0]),
            float(np.linalg.norm(tool_m - mid[1])) / (t_s - mid[0]),
        )
        if min(speeds) < self.s.event_min_speed_m_s:
            return
        tau = t_s - self.onset_s
        release, estop = self.s.release_after_s, self.s.estop_after_s
        if self._release_at_s is None and release is not None and tau >= release:
            self._release_at_s = t_s
        if self._estop_at_s is None and estop is not None and tau >= estop:
            self._estop_at_s = t_s

    def enabling(self, t_s: float) -> bool:
        if t_s < self.s.enabling_after_s:
            return False
        if self.onset_s is not None and self.s.release_after_s is not None:
            if self.s.event_min_speed_m_s > 0:
                return self._release_at_s is None or t_s < self._release_at_s
            return t_s - self.onset_s < self.s.release_after_s
        return True

    def estop_pressed(self, t_s: float) -> bool:
        """The e-stop is open now (``estop_after_s`` after onset, in motion with
        ``event_min_speed_m_s``; it latches)."""
        after = self.s.estop_after_s
        if self.s.event_min_speed_m_s > 0:
            return self._estop_at_s is not None and t_s >= self._estop_at_s
        return after is not None and self.onset_s is not None and t_s - self.onset_s >= after

    def bus_off(self, t_s: float) -> bool:
        """The host's CAN interface is bus-off now (``bus_off_after_s`` after onset, for
        ``bus_off_s``)."""
        after = self.s.bus_off_after_s
        if after is None or self.onset_s is None:
            return False
        return 0.0 <= t_s - self.onset_s - after < self.s.bus_off_s

    def mark_pressed(self, t_s: float) -> bool:
        """The teach handle's mark button is held now (``mark_at_s`` after onset)."""
        if self.onset_s is None:
            return False
        tau = t_s - self.onset_s
        return any(0.0 <= tau - m < self.s.mark_press_s for m in self.s.mark_at_s)

    def brakes_released(self, t_s: float) -> bool:
        """The brake-release switch is held (servo off only: the controller decides)."""
        after = self.s.brake_release_after_s
        return after is not None and t_s >= after

    def target_m(self, t_s: float) -> np.ndarray | None:
        """Where the hand wants the tool (path mode, after onset)."""
        if self.s.mode != "path" or self.onset_s is None or self.origin_m is None:
            return None
        tau = t_s - self.onset_s
        offset = np.array([np.interp(tau, self._t, self._xyz[:, k]) for k in range(3)])
        if self.s.tremor_m:
            w = 2.0 * np.pi * self.s.tremor_hz * tau
            offset += self.s.tremor_m * np.sin(w * _TREMOR_AXES + _TREMOR_PHASES)
        return self.origin_m + offset

    def hand(self, plant: Plant) -> np.ndarray:
        """Hand force on the tool now [N] (world frame); the plant calls it every step."""
        t = plant.t_s
        if self.onset_s is None or self.s.mode == "none" or not self.enabling(t):
            return np.zeros(3)
        if self.s.hand_off_after_s is not None and t - self.onset_s >= self.s.hand_off_after_s:
            return np.zeros(3)
        tau = t - self.onset_s
        if any(a <= tau < b for a, b in self.s.hand_off_windows_s):
            return np.zeros(3)
        if self.s.mode == "force":
            return self.force_n(t, None, None)
        return self.force_n(t, plant.tool_position_m(), plant.tool_velocity_m_s())

    def force_n(
        self, t_s: float, tool_m: np.ndarray | None, tool_vel_m_s: np.ndarray | None
    ) -> np.ndarray:
        if self.onset_s is None or not self.enabling(t_s):
            return np.zeros(3)
        s = self.s
        tau = t_s - self.onset_s
        if s.mode == "force":
            a, b = s.start_s, s.start_s + s.duration_s
            if tau <= a or tau >= b:
                return np.zeros(3)
            ramp = min(1.0, (tau - a) / s.ramp_s, (b - tau) / s.ramp_s) if s.ramp_s > 0 else 1.0
            return ramp * np.asarray(s.force_n, dtype=float)
        if s.mode == "path":
            target = self.target_m(t_s)
            assert target is not None and tool_m is not None and tool_vel_m_s is not None
            f = (
                s.hand_stiffness_n_per_m * (target - tool_m)
                - s.hand_damping_n_s_per_m * tool_vel_m_s
            )
            norm = float(np.linalg.norm(f))
            return f if norm <= s.max_force_n else f * (s.max_force_n / norm)
        return np.zeros(3)
