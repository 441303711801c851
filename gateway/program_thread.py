"""The taught program written off the gateway's tick (issue 45): one thread owns the file.

The gateway's tick publishes the lifecycle the drivers need fresh every 0.25 s, answers the
operator and watches the links. It also wrote the taught program (gateway/program.py), and a
program is synced to disk: the trace every :data:`~gateway.program.TRACE_SYNC_S`, each mark
before its reply. A small file's ``fsync`` waits for the filesystem's journal, which waits for
whatever else is being written back: on this class of machine, beside a process writing 1.5 GB
with ``conv=fsync``, a 100-byte append's ``fsync`` took p50 0.7 ms, p99 477 ms, at most 507 ms;
in a demo beside that load the tick stood still 0.13-1.6 s at a time in the program's
``fsync``, and the operator's requests timed out (2026-12-02).

Here the tick hands each call of :class:`~gateway.program.TeachRecorder` (a session's start,
the newest joint state, a mark) to one thread, in order, and returns. A mark's caller gets a
:class:`~concurrent.futures.Future` that is done once the mark is on disk, so an operator's
``mark`` is still answered only then, without holding the tick. A session's thread starts with
its first call and ends after the session's file is closed.

What a disk that misbehaves does is unchanged for the operator: a write the disk refuses ends
teaching with a fault (:meth:`ProgramThread.failure`), and so does a write it has not finished
after :data:`STALL_S` (:meth:`ProgramThread.stalled_s`), since a program that is not reaching
the disk is not being kept.
"""

from __future__ import annotations

import logging
import queue
import threading
import time
from collections.abc import Callable
from concurrent.futures import Future
from pathlib import Path
from typing import Any

import numpy as np

from gateway.program import Mark, ProgramError, TeachRecorder

log = logging.getLogger("leadthrough.gateway")

#: a write to the program the disk has not finished after this long ends teaching [s]: five
#: times the slowest small-file ``fsync`` measured under a competing writer (1.6 s, module
#: docs), and short enough that the painter does not go on teaching a path the disk is not
#: keeping for longer than a corner's pause
STALL_S = 8.0
#: the gateway waits at most this long for the file to be closed when it stops [s]
CLOSE_WAIT_S = 10.0


class ProgramThread:
    """:class:`~gateway.program.TeachRecorder` driven from one thread of its own (module docs).

    Called from the gateway's tick (and its operator requests); every method returns without
    waiting for the disk, but :meth:`close`."""

    def __init__(self, cell: str = "") -> None:
        self._rec = TeachRecorder(cell)
        self._queue: queue.SimpleQueue[tuple[Callable[[], Any], Future | None]] = (
            queue.SimpleQueue()
        )
        self._lock = threading.Lock()
        self._thread: threading.Thread | None = None
        #: a session is open: prepared and not yet ended (the tick's view)
        self._active = False
        #: the program's path as the tick last set or learnt it
        self._path: Path | None = None
        self._snapshot: dict[str, Any] = self._rec.status()
        #: when the call the thread is running began (None: idle) [s, monotonic]
        self._busy_since: float | None = None
        self._failure: ProgramError | None = None

    # --- the tick's side -------------------------------------------------------------------
    @property
    def path(self) -> Path | None:
        """The session's program (before teaching began, the one it will be)."""
        with self._lock:
            return self._path

    def prepare(self, path: Path) -> None:
        """A session starts (operator `start`): its program will be ``path``."""
        with self._lock:
            if not self._snapshot["open"]:
                self._path = path
            self._active = True
        self._submit(lambda: self._rec.prepare(path), None)

    def follow(self, teaching: bool, session: bool, reason: str, t_s: float | None,
               cycle: int | None, q_rad: np.ndarray | None) -> None:  # fmt: skip
        """One gateway tick (:meth:`TeachRecorder.follow`); nothing to do outside a session."""
        with self._lock:
            if not (session or self._active):
                return
            self._active = session
        q = None if q_rad is None else np.array(q_rad, dtype=float)
        self._submit(lambda: self._follow(teaching, session, reason, t_s, cycle, q), None)

    def mark(self, t_s: float, cycle: int, q_rad: np.ndarray, label: str, source: str) -> Future:
        """A waypoint (:meth:`TeachRecorder.mark`): the future's result is ``(mark, path)``
        once it is on disk; its exception a :class:`ProgramError` (no program open, a bad
        label, or the disk refused it: then :meth:`failure` has it too)."""
        done: Future = Future()
        q = np.array(q_rad, dtype=float)
        self._submit(lambda: self._mark(t_s, cycle, q, label, source), done)
        return done

    def status(self) -> dict[str, Any]:
        """As :meth:`TeachRecorder.status`, as of the last call the thread finished."""
        with self._lock:
            return {**self._snapshot, "path": None if self._path is None else str(self._path)}

    def failure(self) -> ProgramError | None:
        """The disk's refusal, once (None: none since the last call). The program is closed
        as far as the disk allows and the session has no program any more."""
        with self._lock:
            failure, self._failure = self._failure, None
            return failure

    def stalled_s(self, now_s: float) -> float:
        """How long the call the thread is running has been waiting [s] (0: none runs)."""
        with self._lock:
            return 0.0 if self._busy_since is None else max(now_s - self._busy_since, 0.0)

    def abandon(self) -> None:
        """The tick has ended teaching with a fault over this program: what is queued still
        reaches the file, then the session's program is closed and forgotten."""
        with self._lock:
            self._active = False
        self._submit(self._drop, None)

    def close(self, t_s: float | None, reason: str, timeout_s: float = CLOSE_WAIT_S) -> None:
        """The gateway stops: the session's program is closed (its last segment ended at
        ``t_s``), waiting for the disk up to ``timeout_s``."""
        with self._lock:
            active, self._active = self._active, False
            thread = self._thread
        if active:
            self._submit(lambda: self._follow(False, False, reason, t_s, None, None), None)
            with self._lock:
                thread = self._thread
        if thread is not None:
            thread.join(timeout_s)
            if thread.is_alive():
                log.error("taught program: the disk did not finish its writes within %.0f s "
                          "of the gateway stopping", timeout_s)  # fmt: skip

    # --- the thread's side -----------------------------------------------------------------
    def _submit(self, call: Callable[[], Any], done: Future | None) -> None:
        with self._lock:
            self._queue.put((call, done))
            if self._thread is None:
                self._thread = threading.Thread(
                    target=self._run, name="taught-program", daemon=True
                )
                self._thread.start()

    def _run(self) -> None:
        while True:
            with self._lock:
                if self._queue.empty() and not self._active and not self._snapshot["open"]:
                    self._thread = None  # the session's file is closed: a new one starts anew
                    return
            try:
                item = self._queue.get(timeout=0.5)
            except queue.Empty:
                continue
            call, done = item
            with self._lock:
                self._busy_since = time.monotonic()
            try:
                result = call()
            except ProgramError as exc:
                if done is not None:
                    done.set_exception(exc)
            except Exception as exc:  # a bug must not end the thread with the tick waiting
                log.exception("taught program: unexpected error")
                if done is not None:
                    done.set_exception(ProgramError(f"taught program: {exc}"))
            else:
                if done is not None:
                    done.set_result(result)
            finally:
                with self._lock:
                    self._busy_since = None

    def _follow(self, teaching: bool, session: bool, reason: str, t_s: float | None,
                cycle: int | None, q: np.ndarray | None) -> None:  # fmt: skip
        try:
            self._rec.follow(teaching, session, reason, t_s, cycle, q)
        except ProgramError as exc:
            self._failed(exc)
            raise
        finally:
            self._update()

    def _mark(
        self, t_s: float, cycle: int, q: np.ndarray, label: str, source: str
    ) -> tuple[Mark, Path | None]:
        w = self._rec.writer
        try:
            return self._rec.mark(t_s, cycle, q, label, source), self._rec.path
        except ProgramError as exc:
            if w is not None and not w.is_open:  # the disk refused it, not the operator's input
                self._failed(exc)
            raise
        finally:
            self._update()

    def _failed(self, exc: ProgramError) -> None:
        self._drop()
        with self._lock:
            self._failure = self._failure or exc
            self._active = False

    def _drop(self) -> None:
        rec = self._rec
        w, rec.writer, rec.pending = rec.writer, None, None
        if w is not None:
            try:
                w.close()
            except ProgramError as exc:
                log.warning("taught program: closing it after a failure: %s", exc)
        self._update()

    def _update(self) -> None:
        status = self._rec.status()
        with self._lock:
            self._snapshot = status
            if self._rec.path is not None:
                self._path = self._rec.path
            elif not self._active:
                self._path = None
