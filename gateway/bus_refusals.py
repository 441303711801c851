"""Counting what the locked bus refuses: each put, declaration or query its access-control
list denies, per identity, action and key (issue 10).

zenoh refuses such a message at the router's ingress and reports it only as a trace event.
The locked bus's router is compiled (gateway/router, :class:`gateway.bus.LockedRouter`) and
counts those events in memory; :class:`BusRefusals` reads the counts at the gateway's tick,
logs a warning per identity at most once a second while its refusals grow, and gives
`leadthrough status` the total and each entry.

What zenoh decides per message, and so what is counted (zenoh 1.10.2, measured): a put on a
key expression the sender did not declare is decided, and refused, put by put; for a key
expression a session declares (a publisher, a subscriber), zenoh decides every action on it
at the declaration, counts the denied ones then, and later drops that publisher's puts
without a decision event. So a forger's ``session.put`` is counted put by put, a forger's
declared publisher once per action at its declaration; and each product process shows one
or two entries per key it subscribes to (the actions it may not take on it: ``control`` may
not put joint states), which are decisions, not attempts. `leadthrough status` names the
most refused entries first.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable

from gateway.ratelog import RateLimitedLog

log = logging.getLogger("leadthrough.gateway.bus")

#: (identity, action, key, count) for each entry refused so far
Entries = list[tuple[str, str, str, int]]


class BusRefusals:
    """The refusals ``source`` (the router's :meth:`~gateway.bus.LockedRouter.refusals`)
    has counted, as of the last :meth:`poll`; thread-safe."""

    def __init__(
        self, source: Callable[[], Entries], clock: Callable[[], float] = time.monotonic
    ) -> None:
        self._source = source
        self._lock = threading.Lock()
        self._counts: dict[tuple[str, str, str], int] = {}
        self._say = RateLimitedLog(log, 1.0, clock)

    def poll(self) -> None:
        """Take in the router's counts; warn of each entry that grew (rate-limited per
        identity)."""
        grown = []
        with self._lock:
            for identity, action, key, n in self._source():
                entry = (str(identity), str(action), str(key))
                if n > self._counts.get(entry, 0):
                    self._counts[entry] = int(n)
                    grown.append((*entry, int(n)))
        for identity, action, key, n in grown:
            self._say(
                logging.WARNING, identity,
                "bus refused %s from %r on %s (%d so far)", action, identity, key, n,
            )  # fmt: skip

    @property
    def total(self) -> int:
        with self._lock:
            return sum(self._counts.values())

    def summary(self) -> dict[str, object]:
        """For ``leadthrough status``: the total and each (identity, action, key)'s count."""
        with self._lock:
            by = [
                {"identity": i, "action": a, "key": k, "count": n}
                for (i, a, k), n in sorted(self._counts.items())
            ]
        return {"total": sum(e["count"] for e in by), "by": by}
