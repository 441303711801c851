"""Counting what the locked bus refuses: each put, declaration or query its access-control
list denies, per identity, action and key (issue 10).

zenoh refuses such a message at the router's ingress and reports it nowhere but in its own
trace log: the Python wheel (zenoh 1.10.2) is built without the ``stats`` feature, and its
Rust log does not reach Python's ``logging``. The gateway hosts the router, so it turns that
log on for the access-control module alone and reads it. The log goes to the process's
standard output (file descriptor 1): :class:`StdoutTap` puts a pipe there and a thread reads
it, line by line. A refusal line, e.g. ::

    … access_control: 94bd… on Interface(lo)+Username(operator)+Transport(Tcp)+94bd… is
    unauthorized to Put (ingress) on lt/cmd/joints

is counted (:class:`BusRefusals`); every other line goes on to where standard output went
before, unchanged. A refusal costs the router one formatted line and this thread one regular
expression; a flood of forged puts is counted, and logged at most once a second per identity.

What zenoh logs, and so what is counted (zenoh 1.10.2, measured): each message on a key
expression the sender did not declare, once per message; for a key expression a session
declares (a publisher, a subscriber), zenoh decides every action on it once, at the
declaration, logs the denied ones then, and later drops that publisher's puts without a
line. So a forger's ``session.put`` is counted put by put, a forger's declared publisher once
per action at its declaration; and each product process shows one or two entries per key it
subscribes to (the actions it may not take on it: ``control`` may not put joint states), which
are decisions, not attempts. `leadthrough status` names the most refused entries first.

Only in the gateway, only on a locked bus, once per process (zenoh's log is global). With
``RUST_LOG`` set, zenoh takes that filter instead of this one, and the count stays at zero
unless it keeps ``zenoh::net::routing::interceptor::access_control=trace``.
"""

from __future__ import annotations

import logging
import os
import re
import threading
import time
from collections import Counter
from collections.abc import Callable

from gateway.ratelog import RateLimitedLog

log = logging.getLogger("leadthrough.gateway.bus")

#: zenoh's log filter: the access-control list's decisions, nothing else
ZENOH_LOG_FILTER = "zenoh::net::routing::interceptor::access_control=trace"
#: one refusal in that log
REFUSAL = re.compile(r"is unauthorized to (?P<action>\w+) \((?P<flow>\w+)\) on (?P<key>\S+)")
IDENTITY = re.compile(r"Username\((?P<identity>[^)]*)\)")
ANSI = re.compile(r"\x1b\[[0-9;]*m")
#: an identity that authenticated without a user name (a certificate only)
UNNAMED = "(no user name)"


class BusRefusals:
    """The refusals seen so far; thread-safe."""

    def __init__(self, clock: Callable[[], float] = time.monotonic) -> None:
        self._lock = threading.Lock()
        self._counts: Counter[tuple[str, str, str]] = Counter()
        self._say = RateLimitedLog(log, 1.0, clock)

    def feed(self, line: str) -> bool:
        """Count ``line`` if it is a refusal; whether it was."""
        text = ANSI.sub("", line)
        found = REFUSAL.search(text)
        if found is None:
            return False
        who = IDENTITY.search(text)
        identity = who["identity"] if who else UNNAMED
        key = (identity, found["action"], found["key"])
        with self._lock:
            self._counts[key] += 1
            n = self._counts[key]
        self._say(
            logging.WARNING, identity,
            "bus refused %s from %r on %s (%d so far)", found["action"], identity, found["key"], n,
        )  # fmt: skip
        return True

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


class StdoutTap:
    """File descriptor 1 through a pipe: each line to ``on_line``, which says whether it kept
    the line; the others go on to the original standard output."""

    def __init__(self, on_line: Callable[[str], bool]) -> None:
        self._on_line = on_line
        self.original_fd = -1  #: the standard output before the tap (children get it)
        self._thread: threading.Thread | None = None

    def start(self) -> None:
        read_fd, write_fd = os.pipe()
        self.original_fd = os.dup(1)
        os.dup2(write_fd, 1)
        os.close(write_fd)
        self._thread = threading.Thread(
            target=self._read, args=(read_fd,), name="bus-refusals", daemon=True
        )
        self._thread.start()

    def _read(self, read_fd: int) -> None:
        with os.fdopen(read_fd, "rb", buffering=0) as pipe:
            pending = b""
            while chunk := pipe.read(65536):
                *lines, pending = (pending + chunk).split(b"\n")
                passed = [ln for ln in lines if not self._kept(ln)]
                if passed:
                    self._write(b"".join(ln + b"\n" for ln in passed))
            if pending and not self._kept(pending):
                self._write(pending)

    def _kept(self, line: bytes) -> bool:
        try:
            return self._on_line(line.decode("utf-8", "replace"))
        except Exception as exc:  # a counting bug must not swallow the process's output
            log.debug("refusal line not counted: %r", exc)
            return False

    def _write(self, data: bytes) -> None:
        view = memoryview(data)
        while view:
            try:
                view = view[os.write(self.original_fd, view) :]
            except OSError:  # the terminal or journal is gone: nothing to pass on to
                return


_lock = threading.Lock()
_installed: tuple[BusRefusals, StdoutTap] | None = None


def count_bus_refusals() -> tuple[BusRefusals, StdoutTap]:
    """Start counting this process's router's refusals (once per process; later calls return
    the same counter and tap). Call before the router opens."""
    global _installed
    with _lock:
        if _installed is None:
            import zenoh

            refusals = BusRefusals()
            tap = StdoutTap(refusals.feed)
            tap.start()
            zenoh.init_log_from_env_or(ZENOH_LOG_FILTER)
            _installed = (refusals, tap)
        return _installed
