"""Lost command cycles, and the policy that stops the arm when there are too many (issue 10).

A cycle is *lost* when forwarding was allowed (nothing blocked it: lifecycle, enabling device,
controller, monitors) and no valid command for it came by its answer deadline, so the driver
answered it itself. One lost cycle costs the operator nothing: the driver coasts on the last
command (core.py). Many say the control process, its host or the zenoh link is failing, and
an arm commanded that way is not under control. The rules, after industrial external-control
interfaces (KUKA RSI's limit of late packets, EKI/EAC-style counters), are in ``[can]``:

- ``lost_cycle_answer``: ``"coast"`` (default) answers a lost cycle with the last forwarded
  command moved on by its own velocity while that command is at most ``deadline_s`` old,
  then with a hold; ``"hold"`` holds at once, never extrapolating;
- ``lost_cycles_max_consecutive`` N: N lost cycles in a row trip;
- ``lost_cycles_max_per_window`` M within ``lost_cycles_window_s``: M lost cycles within the
  window trip (a link that loses every other cycle never reaches N in a row).

0 turns a rule off. A trip latches: forwarding is blocked (``blocked_lost``), the driver stops
the arm as for a released enabling device (the drives are sound, only the command source
failed: a ramp from the last forwarded command while it is recent, else a hold, servo on),
reports ``lost_cycles_trip`` in its health, and the gateway faults. It clears when the cell is
stopped; the operator re-arms.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass

#: ``lost_cycle_answer`` values
COAST_ANSWER, HOLD_ANSWER = "coast", "hold"


@dataclass(frozen=True)
class LostCyclesTrip:
    rule: str  #: "consecutive" or "window"
    count: int
    window_s: float

    def message(self) -> str:
        if self.rule == "consecutive":
            return f"{self.count} command cycles lost in a row"
        return f"{self.count} command cycles lost within {self.window_s:g} s"


class LostCycles:
    """The counters of the module docstring; :meth:`record` once per answered cycle."""

    def __init__(self, max_consecutive: int, max_per_window: int, window_s: float) -> None:
        if max_consecutive < 0 or max_per_window < 0 or not window_s > 0:
            raise ValueError(
                f"lost-cycle limits {max_consecutive}, {max_per_window} must be >= 0 and the "
                f"window {window_s!r} s > 0"
            )
        self.max_consecutive = int(max_consecutive)
        self.max_per_window = int(max_per_window)
        self.window_s = float(window_s)
        self.trip: LostCyclesTrip | None = None
        self.lost = 0  #: lost cycles since start (health)
        self.consecutive = 0
        self._recent: deque[float] = deque()

    def record(self, lost: bool, now: float) -> LostCyclesTrip | None:
        """Take one answered cycle (``lost``: the driver answered it itself while forwarding
        was allowed); returns a trip when this cycle made one (a standing trip is kept)."""
        if not lost:
            self.consecutive = 0
            return None
        self.lost += 1
        self.consecutive += 1
        recent = self._recent
        recent.append(now)
        while recent and now - recent[0] > self.window_s:
            recent.popleft()
        if self.trip is not None:
            return None
        if self.max_consecutive and self.consecutive >= self.max_consecutive:
            self.trip = LostCyclesTrip("consecutive", self.consecutive, self.window_s)
        elif self.max_per_window and len(recent) >= self.max_per_window:
            self.trip = LostCyclesTrip("window", len(recent), self.window_s)
        return self.trip

    def reset(self) -> None:
        """The cell is stopped: clear a trip and the counts towards one."""
        self.trip = None
        self.consecutive = 0
        self._recent.clear()
