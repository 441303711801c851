"""Cylinder pressure set-points scheduled from the arm's pose (issue 9; the paper's Fig. 14).

The assist cylinders on J2 and J3 push with a torque ``a(q) p`` (eqs. 10, 12: linear in the
pressure, the lever ``a`` a function of the joint's own angle). At fixed set-points they
balance gravity at one pose only; elsewhere the motors carry the rest, and what the motors
carry is what a drive-gain error (±10 % on a real drive: the product measures torque as the
datasheet's K times the current) or a model error turns into a force the painter feels, and
what heats the motors. The schedule asks each cylinder for ``share`` of the static load the
identified model gives on its joint at the arm's pose, as a ridge-regularised inverse of
the lever::

    p* = clip(share · g_j(q) · a_j(q) / (a_j(q)² + L²), p_min, p_max)

(``g`` is the model's torque at rest without the cylinders: rigid-body gravity and the
accepted position effects; L = ``min_lever_nm_per_bar``). Where the lever is long, p* is
``share · g / a``; a short one asks for less (pressure on a short lever buys little torque).
A cylinder only pushes: where gravity pulls the other way it is asked for ``p_min``. Where
the lever crosses zero (the crank near the upright: on the GR630ST -15 to +10 N·m per bar
along a raster, against 400-700 N·m of load) the set-point changes from one end of the range
to the other, but only where the lever is under 1 N·m/bar, so whatever the pressure lags
there costs a few N·m. ``share`` < 1 leaves the motor a one-signed share of the load, so the
gears stay preloaded on one flank and a pressure that lags the pose never makes the motor
torque cross zero (backlash) in slow motion.

The set-point then follows p* through a first-order filter (``time_constant_s``: the arm
moves along a path in seconds, the valves and the gas follow in about a second, so a faster
set-point would only be chased) and a rate limit (``rate_bar_per_s``): the zero-moment law
compensates the *measured* pressures each cycle, so a change of the cylinders' torque reaches
the painter only through the transmitters' lag and the model's cylinder error, and both are
smaller the slower the pressure moves. Outside teaching and replay the set-points stay where
they are (a braked or held arm does not need them to move) except during identification,
where they ramp back to the configured fixed values (its experiments are planned for them).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

from control.model.cylinders import torque_per_pa
from gateway.robot.description import BAR_TO_PA, CylinderSpec


@dataclass(frozen=True)
class ScheduleSettings:
    #: the share of a cylinder joint's static load the cylinder is asked for
    share: float = 0.8
    #: the valves' range asked for [bar]
    min_bar: float = 0.5
    max_bar: float = 8.0
    #: the set-point's filter time constant [s] and rate limit [bar/s]
    time_constant_s: float = 1.0
    rate_bar_per_s: float = 2.0
    #: L: a lever well under this asks for little pressure (module docstring) [N·m/bar]
    min_lever_nm_per_bar: float = 5.0

    def check(self) -> None:
        if not (math.isfinite(self.share) and 0.0 <= self.share <= 1.0):
            raise ValueError(f"pressure schedule share {self.share} not in [0, 1]")
        if not (0.0 <= self.min_bar <= self.max_bar <= 10.0):
            raise ValueError(f"pressure schedule range {self.min_bar}-{self.max_bar} bar "
                             "not within 0-10 bar")  # fmt: skip
        if not (self.time_constant_s > 0 and self.rate_bar_per_s > 0):
            raise ValueError("pressure schedule time constant and rate limit must be > 0")
        if not self.min_lever_nm_per_bar > 0:
            raise ValueError("pressure schedule min_lever_nm_per_bar must be > 0")


class PressureSchedule:
    """Set-points per cylinder (in the description's order) from the arm's pose (module
    docstring). :meth:`update` once per publication."""

    def __init__(
        self,
        cylinders: Sequence[CylinderSpec],
        settings: ScheduleSettings,
        fixed_bar: Sequence[float],
    ) -> None:
        settings.check()
        if len(fixed_bar) != len(cylinders):
            raise ValueError(f"{len(fixed_bar)} fixed set-points for {len(cylinders)} cylinders")
        self.cylinders = tuple(cylinders)
        self.settings = settings
        self.fixed_bar = tuple(float(p) for p in fixed_bar)
        self.setpoint_bar = list(self.fixed_bar)
        self._last_s: float | None = None

    def target_bar(self, q_rad: Sequence[float], static_nm: Sequence[float]) -> list[float]:
        """p* per cylinder at pose ``q_rad`` with the model's static load ``static_nm`` (the
        torque at rest without cylinders) [bar]."""
        st = self.settings
        out = []
        for spec in self.cylinders:
            j = spec.joint_index
            lever = float(torque_per_pa(spec, q_rad[j])) * BAR_TO_PA  # N·m per bar
            p = st.share * static_nm[j] * lever / (lever * lever + st.min_lever_nm_per_bar**2)
            out.append(min(max(p, st.min_bar), st.max_bar))  # pushes only, within the valves
        return out

    def update(self, target_bar: Sequence[float] | None, now_s: float) -> tuple[float, ...]:
        """Move the set-points towards ``target_bar`` (None: the fixed set-points) over the
        time since the last call; returns them [bar]."""
        st = self.settings
        dt = 0.0 if self._last_s is None else max(0.0, now_s - self._last_s)
        self._last_s = now_s
        goal = self.fixed_bar if target_bar is None else target_bar
        alpha = 1.0 - math.exp(-dt / st.time_constant_s)
        most = st.rate_bar_per_s * dt
        for k, (p, g) in enumerate(zip(self.setpoint_bar, goal, strict=True)):
            if not math.isfinite(g):
                continue  # a target the model could not give: stay
            step = alpha * (g - p)
            self.setpoint_bar[k] = p + min(max(step, -most), most)
        return tuple(self.setpoint_bar)

    def hold(self, now_s: float) -> tuple[float, ...]:
        """The set-points unchanged (the clock moves on: no jump at the next update)."""
        self._last_s = now_s
        return tuple(self.setpoint_bar)
