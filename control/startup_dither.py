"""The admittance's start-up dither (``[control] admittance_dither``): the painter's first push
from rest breaks a joint's static friction with help (issue 47, item 2).

A joint at rest is held by its static friction, and the drive's current does not change while
the friction carries the hand's torque: the admittance sees no hand until the push alone has
broken the joint away (the demo's J2: about 60 N·m, 46 N at the tool). As Li et al. (Robotica
2025) compensate start-up torque, each joint whose reference rests gets a sine of a share of
the model's static friction level (``friction_level_nm``) on the torque the command asks of
the vendor loop; the joints' phases are spread over the period. Below the breakaway it moves
nothing by itself: the vendor loop's position stiffness (J2: some 800 N·m per mrad) keeps any
slip to tens of µrad. On every swing towards a push the hand needs only the rest of the
breakaway; the joint then slips, the loop pulls it back, and the current shows the push.

The drive gives the dither too, so the current of a cycle carries the dither that drove it:
:meth:`StartupDither.drove` is that torque, which the admittance adds back to its estimate
(``τ̂_h = τ_model − b − (K i − d)``), so a stuck joint's estimate does not swing with it.
The dither fades in over :data:`FADE_S` after the admittance starts (a step would jolt the arm)
and, per joint, out as its reference moves faster than the rest speed (to nothing at twice it).
"""

from __future__ import annotations

import math
from collections import deque

import numpy as np

#: the dither fades in over this after the admittance starts [s]: a step of the friction
#: level's share would jolt the arm
FADE_S = 0.25


class StartupDither:
    """Per joint, the dither's torque of each command and of the one that drove a state."""

    def __init__(self, share: float, hz: float, rest_rad_s: float, delay_cycles: int) -> None:
        if not (math.isfinite(share) and 0.0 <= share < 1.0):
            raise ValueError(f"start-up dither: share {share} not in [0, 1)")
        if not (math.isfinite(hz) and hz > 0.0):
            raise ValueError(f"start-up dither: {hz} Hz must be > 0")
        if not rest_rad_s > 0.0:
            raise ValueError(f"start-up dither: rest speed {rest_rad_s} rad/s must be > 0")
        self.share, self.hz, self.rest_rad_s = share, hz, rest_rad_s
        self._sent: deque[np.ndarray] = deque(maxlen=delay_cycles + 1)
        self._level = np.zeros(0)
        self._phase = 0.0
        self._gain = 0.0

    def reset(self, friction_level_nm: np.ndarray) -> None:
        """Starts again (faded out) on joints of this static friction level [N·m]."""
        self._level = np.maximum(np.asarray(friction_level_nm, dtype=float), 0.0)
        self._sent.clear()
        self._phase = 0.0
        self._gain = 0.0

    def step(self, dq_r: np.ndarray, dt_s: float) -> np.ndarray:
        """The dither's torque for the command of a cycle of ``dt_s`` [s] whose reference
        speeds are ``dq_r`` [rad/s], remembered for :meth:`drove` [N·m]."""
        n = self._level.size
        d = np.zeros(n)
        if self.share > 0.0 and n:
            self._gain = min(1.0, self._gain + dt_s / FADE_S)
            turn = 2.0 * math.pi
            self._phase = (self._phase + turn * self.hz * dt_s) % turn
            fade = np.clip(2.0 - np.abs(dq_r) / self.rest_rad_s, 0.0, 1.0)
            phases = self._phase + turn * np.arange(n) / n
            d = self._gain * self.share * fade * self._level * np.sin(phases)
        self._sent.append(d)
        return d

    def drove(self) -> np.ndarray:
        """The dither of the command that drove the state now in (``delay + 1`` back; none
        before so many were sent) [N·m]."""
        if self._sent and len(self._sent) == self._sent.maxlen:
            return self._sent[0]
        return np.zeros(self._level.size)
