"""Plausibility of the measured positions (issue 10): a cycle whose joint position jumped
further than the arm can move is not a measurement.

LTC-1's feedback frames carry no CRC of their own (classic CAN's frame CRC guards the wire), so
a broken node on the bus, a controller whose encoder glitched, or a forger that knows the
protocol can put a wrong position into a complete, well-formed cycle. Published, it would be
followed: the control process commands where it thinks the arm is, and the driver's
following-error check compares that command with the same wrong position. So each cycle's
positions are compared with the last cycle accepted: a joint that moved more than
``max_speed_rad_s`` × the time between them (the counter's cycles × the reported period), plus
``tolerance_rad`` for quantisation, drops the cycle like a corrupt one. The reference stays
the last accepted cycle, so one wrong cycle costs one cycle, the true one after it is taken,
and an offset that stays (a re-homed encoder) is taken once the allowance has grown to it;
until then the cycles are lost and the lost-cycle policy stops the arm.

A wrong position that stays within the allowance is not caught here; the command offset it
causes is bounded by the allowance plus the following-error limit.
"""

from __future__ import annotations

import numpy as np


class FeedbackPlausibility:
    """Per-joint position steps against the arm's maximum speed. ``max_speed_rad_s`` 0 turns
    the check off."""

    def __init__(self, max_speed_rad_s: float, tolerance_rad: float = 1e-4) -> None:
        self.max_speed_rad_s = float(max_speed_rad_s)
        self.tolerance_rad = float(tolerance_rad)
        self._q: np.ndarray | None = None
        self._cycle = 0
        self.dropped = 0  #: cycles refused (monotonic)

    def check(self, cycle: int, q_rad: np.ndarray, period_s: float) -> str | None:
        """None when ``q_rad`` (of widened cycle number ``cycle``) is plausible, and it becomes
        the reference; else why not (the reference stays)."""
        if self.max_speed_rad_s <= 0:
            return None
        q = np.asarray(q_rad, dtype=float)
        if self._q is None or period_s <= 0 or cycle <= self._cycle:
            self._q, self._cycle = q.copy(), cycle
            return None
        allowed = self.max_speed_rad_s * (cycle - self._cycle) * period_s + self.tolerance_rad
        step = np.abs(q - self._q)
        worst = int(np.argmax(step))
        if step[worst] <= allowed:
            self._q, self._cycle = q.copy(), cycle
            return None
        self.dropped += 1
        return (
            f"cycle {cycle}: J{worst + 1} measured {q[worst]:+.4f} rad, "
            f"{step[worst]:.4f} rad from cycle {self._cycle}'s {self._q[worst]:+.4f}; the arm "
            f"moves at most {allowed:.4f} rad in that time ({self.max_speed_rad_s:g} rad/s)"
        )
