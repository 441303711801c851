"""Hand guiding's speed monitor in the CAN driver (issue 10), independent of the control law.

ISO 10218-1 allows hand guiding at up to 250 mm/s at the tool. The control process keeps its
commands under ``[control] max_tool_speed_m_s``; this monitor checks what the arm *did*, from
the measured joint positions of every cycle, with its own kinematics (the datasheet's, as
:mod:`control.model.dynamics` builds them) and no input from the control process. A bug in the
control law, a model that lets the arm run, or an operator outpushing the law's limit all end
the same way: a held cycle, then the gateway's FAULT.

Per cycle, the speed of the tool point and of the flange is the distance each travelled over
the last ``window`` cycles over that time (the controller's cycle period): positions, not the
drives' velocities, and a window long enough that an encoder step does not read as a speed.
The monitor trips when one point is faster than the limit in ``confirm`` consecutive cycles;
the trip names the point, its speed and the limit, and stays until :meth:`SpeedMonitor.reset`.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from control.robot.description import RobotDescription

#: (q [rad]) -> (tool point, flange point) in the world [m], each (3,)
Points = Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]]


@dataclass(frozen=True)
class SpeedTrip:
    """Why the monitor tripped."""

    point: str  #: "tool" or "flange"
    speed_m_s: float
    limit_m_s: float
    cycle: int

    def message(self) -> str:
        return (
            f"the {self.point} moved at {self.speed_m_s * 1e3:.0f} mm/s (measured positions, "
            f"cycle {self.cycle}), over hand guiding's {self.limit_m_s * 1e3:.0f} mm/s"
        )


def datasheet_points(desc: RobotDescription | None = None) -> Points:
    """The tool point and the flange from the datasheet's kinematics and tool (what the
    control process's speed limit uses too, computed here on the driver's own model);
    ``desc`` the robot description when already loaded."""
    from control.model.dynamics import RigidBodyModel
    from control.robot.description import load_description

    desc = desc or load_description()
    model = RigidBodyModel.from_description(desc)
    tool_in_6 = np.array(desc.tool.position_in_link6_m, dtype=float)

    def points(q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        pose = model.world_T_tool(q)
        tool = pose[:3, 3]
        return tool, tool - pose[:3, :3] @ tool_in_6

    return points


class SpeedMonitor:
    """The monitor of the module docstring: :meth:`update` once per cycle while it applies,
    :meth:`reset` when it does not (the positions before a gap are no speed)."""

    def __init__(self, points: Points, limit_m_s: float, window: int = 3, confirm: int = 2) -> None:
        if not (math.isfinite(limit_m_s) and limit_m_s > 0):
            raise ValueError(f"speed limit {limit_m_s!r} m/s must be > 0")
        if window < 1 or confirm < 1:
            raise ValueError(f"window {window} and confirm {confirm} must be >= 1 cycle")
        self.points = points
        self.limit_m_s = float(limit_m_s)
        self.window = window
        self.confirm = confirm
        #: (cycle, tool, flange) of the newest window + 1 cycles
        self._history: deque[tuple[int, np.ndarray, np.ndarray]] = deque(maxlen=window + 1)
        self._over = 0
        self.trip: SpeedTrip | None = None
        #: the fastest point speed seen since the last reset [m/s]
        self.peak_m_s = 0.0

    def gap(self) -> None:
        """A cycle the monitor does not see (the controller not servoing): forget the
        positions, keep a trip."""
        self._history.clear()
        self._over = 0

    def reset(self) -> None:
        """Forget the positions and clear a trip."""
        self._history.clear()
        self._over = 0
        self.trip = None
        self.peak_m_s = 0.0

    def update(self, cycle: int, q_rad: np.ndarray, period_s: float) -> SpeedTrip | None:
        """Take the measured positions of ``cycle``; returns the trip (new or standing)."""
        if self.trip is not None:
            return self.trip
        tool, flange = self.points(q_rad)
        history = self._history
        if history and cycle <= history[-1][0]:
            history.clear()  # the cycle count went back: a new link
        history.append((cycle, tool, flange))
        first = history[0]
        span = (cycle - first[0]) * period_s
        if len(history) <= self.window or span <= 0.0 or not math.isfinite(span):
            return None
        v_tool = float(np.linalg.norm(tool - first[1])) / span
        v_flange = float(np.linalg.norm(flange - first[2])) / span
        point, speed = ("tool", v_tool) if v_tool >= v_flange else ("flange", v_flange)
        self.peak_m_s = max(self.peak_m_s, speed)
        if speed > self.limit_m_s:
            self._over += 1
            if self._over >= self.confirm:
                self.trip = SpeedTrip(point, speed, self.limit_m_s, cycle)
        else:
            self._over = 0
        return self.trip
