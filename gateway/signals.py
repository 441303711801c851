"""SIGTERM and SIGINT as a stop request, without a lock in the signal handler.

A Python signal handler runs in the main thread between two bytecodes, also while that thread
holds a lock. ``threading.Event.wait`` holds its condition's lock whenever it wakes, so a
handler that calls ``Event.set`` can block on a lock its own thread holds, and the process
hangs and ignores every later signal. A burst of signals makes it likely (1 in 20 processes
hung under 300 SIGTERMs). It happened in a whole-stack test: ``kill -9`` of the gateway sent its
CAN driver SIGTERM (``PR_SET_PDEATHSIG``) while the driver's main thread was in
``Event.wait``. The driver hung with its loop thread still running, and kept heartbeating the
controller and answering its cycles next to the new gateway's driver. The arm ran away at four
times the planned speed until the speed monitor tripped.

Here the handler does nothing in Python. CPython's C-level handler writes the signal's number
to a pipe (:func:`signal.set_wakeup_fd`), and a watcher thread reads it and sets the event,
where taking the lock is safe::

    stop = threading.Event()
    with StopSignals(stop):
        while not stop.wait(0.1):
            ...

Outside the main thread (a process run in-process by a test) it installs nothing: signals are
the main thread's.
"""

from __future__ import annotations

import contextlib
import os
import signal
import threading
from types import FrameType, TracebackType

#: the signals that ask a process to stop
STOP_SIGNALS = (signal.SIGTERM, signal.SIGINT)


def _noted(signum: int, frame: FrameType | None) -> None:
    """The Python-level handler: nothing. The C-level handler has already written the
    signal's number to the wakeup pipe, which is what a Python handler is needed for."""


class StopSignals:
    """While entered, each of ``signals`` sets ``event``; :attr:`signum` is the last one."""

    def __init__(
        self, event: threading.Event, signals: tuple[signal.Signals, ...] = STOP_SIGNALS
    ) -> None:
        self.event = event
        self.signals = tuple(signals)
        self.signum: int | None = None  #: the last stop signal received
        self._previous: dict[int, object] = {}
        self._previous_fd = -1
        self._pipe: tuple[int, int] | None = None
        self._closing = False
        self._thread: threading.Thread | None = None

    def __enter__(self) -> StopSignals:
        if threading.current_thread() is not threading.main_thread():
            return self
        read_fd, write_fd = os.pipe()
        os.set_blocking(write_fd, False)  # set_wakeup_fd requires it
        self._pipe = (read_fd, write_fd)
        try:
            self._previous_fd = signal.set_wakeup_fd(write_fd, warn_on_full_buffer=False)
            for signum in self.signals:
                self._previous[signum] = signal.signal(signum, _noted)
        except BaseException:
            self._restore()
            raise
        self._thread = threading.Thread(target=self._watch, name="stop-signals", daemon=True)
        self._thread.start()
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self._restore()

    def _watch(self) -> None:
        assert self._pipe is not None
        read_fd = self._pipe[0]
        wanted = {int(s) for s in self.signals}
        while True:
            try:
                data = os.read(read_fd, 64)
            except OSError:
                return
            got = [b for b in data if b in wanted]
            if got:
                self.signum = got[-1]
                self.event.set()
            if not data or self._closing:
                return

    def _restore(self) -> None:
        """Put back the handlers and the wakeup descriptor, stop the watcher, close the pipe."""
        for signum, handler in self._previous.items():
            signal.signal(signum, handler)  # type: ignore[arg-type]
        self._previous.clear()
        if self._pipe is None:
            return
        read_fd, write_fd = self._pipe
        with contextlib.suppress(ValueError):
            signal.set_wakeup_fd(self._previous_fd)
        self._closing = True
        if self._thread is not None:
            with contextlib.suppress(OSError):
                os.write(write_fd, b"\0")  # no signal has number 0: wakes the watcher only
            self._thread.join()
            self._thread = None
        os.close(read_fd)
        os.close(write_fd)
        self._pipe = None
