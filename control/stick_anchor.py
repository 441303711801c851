"""The admittance's stick anchor (``[control] admittance_stick = "anchor"``): what a resting
joint's friction carries is taken off its hand torque estimate, and nothing more.

At rest a joint's friction holds whatever share of its load it was left with when it stopped,
anywhere within its static level, and the motor current cannot tell that share from a hand.
The stick zone (``"zone"``) dead-zones the estimate of a joint at rest by the model's friction
level, symmetric about zero; but the estimate of a stuck joint already lacks what the friction
holds (the drive does not feel a push the friction takes), so a push must break the friction
away and then exceed the zone as well: about twice the static level. On plant seed 102 J1 (about
50 N·m static) stayed stuck for 14 s under 76 N·m of the hand (teach-bench, 2026-12-01).

While a joint is stuck and its reference rests, the drive's torque follows the command alone:
the hand, the model's error and the friction's share change nothing it gives. The estimate
``τ̂ = τ_model − K i − b`` then stays where the joint stopped, whatever the hand does, until
the push breaks the friction away: the joint slips, the vendor loop pulls it back, and the
estimate moves by what the push exceeds the friction by. So the anchor is the (low-passed)
estimate at the moment the joint came to rest, followed slowly while the estimate stays within
the dead zone of it (a drift of the model's share as other joints move, the cylinders), and a
joint at rest is pushed by ``τ̂ − anchor``: it moves once the hand has broken it away, not a
static level later. The anchor fades out as the joint slides, as the stick zone does.
"""

from __future__ import annotations

import numpy as np

#: within the dead zone of its anchor, a resting joint's estimate is followed with this time
#: constant [s]: slower than a push that has broken the friction away changes it (the vendor
#: loop's integral pulls a slipping joint back within tens of ms), faster than the model's
#: share drifts as the other joints move through a pass (seconds)
FOLLOW_S = 1.0
#: a joint that has just come to rest takes its estimate as its anchor for this long [s]: as it
#: stops, the model's friction leaves the estimate and the drive's feedforward leaves the
#: current a loop delay apart, and the friction takes up its share (a few cycles, and the
#: estimate's low-pass); a push in that moment waits for it
SETTLE_S = 0.5


class StickAnchor:
    """Per joint, the estimate a resting joint stopped with (module docs)."""

    def __init__(self, n: int, filter_hz: float) -> None:
        if n <= 0:
            raise ValueError(f"stick anchor: {n} joints")
        if not filter_hz > 0:
            raise ValueError(f"stick anchor: filter {filter_hz} Hz must be > 0")
        self.filter_hz = filter_hz
        self.anchor = np.zeros(n)
        self._filtered: np.ndarray | None = None
        self._rested_s = np.zeros(n)

    def reset(self) -> None:
        """Forget the anchors (the admittance starts again)."""
        self.anchor[:] = 0.0
        self._filtered = None
        self._rested_s[:] = 0.0

    def hand(
        self, tau_h: np.ndarray, resting: np.ndarray, band: np.ndarray, dt_s: float
    ) -> tuple[np.ndarray, np.ndarray]:
        """``(τ̂ − anchor, settled)`` per joint [N·m]: ``settled`` the joints that have rested
        longer than :data:`SETTLE_S`, for which the difference is the push (elsewhere it means
        nothing). ``resting``: the joints at rest this cycle. A joint that has just come to
        rest takes its filtered estimate as its anchor for :data:`SETTLE_S`; then, while it
        rests, the anchor follows the estimate within ``band`` of it over :data:`FOLLOW_S`
        and stays where it is beyond."""
        a = 1.0 - np.exp(-2.0 * np.pi * self.filter_hz * dt_s)
        if self._filtered is None:
            self._filtered = tau_h.copy()
        else:
            self._filtered += a * (tau_h - self._filtered)
        f = self._filtered
        self._rested_s = np.where(resting, self._rested_s + dt_s, 0.0)
        settled = self._rested_s > SETTLE_S
        near = settled & (np.abs(f - self.anchor) <= band)
        rate = np.where(settled, np.where(near, min(dt_s / FOLLOW_S, 1.0), 0.0), 1.0)
        self.anchor = self.anchor + rate * (f - self.anchor)
        return tau_h - self.anchor, settled
