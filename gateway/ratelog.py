"""A logger that says a repeated thing once per period and counts what it held back."""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable


class RateLimitedLog:
    """At most one record per key and ``period_s``; the next one says how many were held back.

    ``clock`` returns monotonic seconds (tests inject one). Safe to call from several threads.
    """

    def __init__(self, logger: logging.Logger, period_s: float, clock: Callable[[], float]) -> None:
        self._log, self._period_s, self._clock = logger, period_s, clock
        self._last: dict[str, float] = {}
        self._suppressed: dict[str, int] = {}
        self._lock = threading.Lock()

    def __call__(self, level: int, key: str, msg: str, *args: object) -> None:
        now = self._clock()
        with self._lock:
            last = self._last.get(key)
            if last is not None and now - last < self._period_s:
                self._suppressed[key] = self._suppressed.get(key, 0) + 1
                return
            self._last[key] = now
            suppressed = self._suppressed.pop(key, 0)
        if suppressed:
            msg += f" (+{suppressed} similar in the last {self._period_s:g} s)"
        self._log.log(level, msg, *args)

    def reset(self, key: str) -> None:
        """Forget ``key`` so its next occurrence is logged at once (after a recovery)."""
        with self._lock:
            self._last.pop(key, None)
            self._suppressed.pop(key, None)
