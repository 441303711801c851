"""Controlled stops in the CAN driver (issue 10): a ramp to standstill, then a monitored hold.

Releasing the enabling device, or the gateway's lifecycle leaving a commanding state for READY
(the operator's stop), is an ordinary stop with the drives powered: IEC 60204-1 stop category 2.
A hold set at the position the arm has reached would be a velocity step: the vendor's position
loop would brake the arm as hard as its current limit allows and pull it back to where the hold
was latched. Instead :class:`StopRamp` continues the last command sent along its own path with
the velocity falling linearly to zero, every joint over the same time (the longest any joint
needs at its ``[can] stop_deceleration_rad_s2``), so the tool keeps its direction while it
slows down; then the driver holds the ramp's end.

While the driver holds with the servo on, :class:`StandstillMonitor` watches the measured
positions: after ``standstill_settle_s`` every joint stays within ``standstill_band_rad`` of the
hold, or, ``standstill_confirm_cycles`` cycles in a row out of it, the monitor trips (a drive
that cannot hold the arm). The driver then asks for the brakes (category 0: nothing else is
left) and reports the trip; the gateway faults until a reset.

Faults are not controlled stops: a stale lifecycle or I/O state, the e-stop chain, a controller
fault or the speed monitor hold at once, as before (``drivers/can/core.py``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class StopRamp:
    """The command path of one controlled stop, started at ``cycle`` from ``q0_rad`` moving
    at ``dq0_rad_s``; ``duration_s`` the time to standstill, ``period_s`` the cycle."""

    cycle: int
    q0_rad: np.ndarray
    dq0_rad_s: np.ndarray
    duration_s: float
    period_s: float

    @classmethod
    def start(
        cls,
        cycle: int,
        q_rad: np.ndarray,
        dq_rad_s: np.ndarray,
        deceleration_rad_s2: np.ndarray,
        period_s: float,
    ) -> StopRamp:
        """A ramp from (``q_rad``, ``dq_rad_s``) at ``cycle``: every joint reaches zero
        velocity at the same time, the longest ``|dq| / deceleration`` of them."""
        q = np.asarray(q_rad, dtype=float)
        dq = np.asarray(dq_rad_s, dtype=float)
        duration = float(np.max(np.abs(dq) / np.asarray(deceleration_rad_s2, dtype=float)))
        return cls(cycle, q.copy(), dq.copy(), duration, float(period_s))

    @property
    def end_rad(self) -> np.ndarray:
        """Where the ramp stops: ``q0 + dq0 · T / 2``."""
        return self.q0_rad + 0.5 * self.duration_s * self.dq0_rad_s

    def at(self, cycle: int) -> tuple[np.ndarray, np.ndarray, bool]:
        """(q [rad], dq [rad/s], done) of the ramp at ``cycle``; done once the velocity is
        zero (then q is the end)."""
        tau = max(cycle - self.cycle, 0) * self.period_s
        if tau >= self.duration_s:
            return self.end_rad, np.zeros_like(self.dq0_rad_s), True
        fall = 1.0 - tau / self.duration_s
        q = self.q0_rad + self.dq0_rad_s * (tau - 0.5 * tau * tau / self.duration_s)
        return q, self.dq0_rad_s * fall, False


@dataclass(frozen=True)
class StandstillTrip:
    """Why the standstill monitor tripped."""

    joint: int  #: 0-based
    deviation_rad: float
    band_rad: float
    cycle: int

    def message(self) -> str:
        return (
            f"joint {self.joint + 1} left its hold by {self.deviation_rad * 1e3:.1f} mrad "
            f"(cycle {self.cycle}), over the standstill band of {self.band_rad * 1e3:.1f} mrad: "
            "the drives do not hold the arm"
        )


class StandstillMonitor:
    """Monitored standstill while the driver holds with the servo on (module docstring)."""

    def __init__(self, band_rad: float, settle_s: float, confirm_cycles: int) -> None:
        self.band_rad = float(band_rad)
        self.settle_s = float(settle_s)
        self.confirm = int(confirm_cycles)
        self.trip: StandstillTrip | None = None
        self._since_s: float | None = None
        self._hold: np.ndarray | None = None
        self._out = 0

    def watch(self, hold_rad: np.ndarray, now: float) -> None:
        """The driver holds at ``hold_rad`` from ``now`` (a new hold restarts the settling)."""
        if self._hold is None or not np.array_equal(self._hold, hold_rad):
            self._hold, self._since_s, self._out = np.array(hold_rad, dtype=float), now, 0

    def idle(self) -> None:
        """Not holding with the servo on (commanded, on the brakes, or no hold yet)."""
        self._hold, self._since_s, self._out = None, None, 0

    def update(self, q_rad: np.ndarray, cycle: int, now: float) -> StandstillTrip | None:
        """One measured cycle; the trip (latched) or None."""
        if self.trip is not None or self._hold is None or self._since_s is None:
            return self.trip
        if now - self._since_s < self.settle_s:
            return None
        deviation = np.abs(np.asarray(q_rad, dtype=float) - self._hold)
        k = int(np.argmax(deviation))
        # NaN counts as out: a position nobody can vouch for
        if deviation[k] <= self.band_rad and np.isfinite(deviation).all():
            self._out = 0
            return None
        self._out += 1
        if self._out >= self.confirm:
            self.trip = StandstillTrip(k, float(deviation[k]), self.band_rad, cycle)
        return self.trip

    def reset(self) -> None:
        """Clear a trip (the gateway has stopped the cell) and forget the hold."""
        self.trip = None
        self.idle()
