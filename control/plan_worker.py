"""The plan builder's worker process (control/plan_builder.py starts it).

It lowers its own CPU priority (:data:`WORKER_NICENESS`) as its very first step, before it
imports anything: the imports (numpy, pinocchio, the planners) are most of a worker's start-up,
about a second of CPU on a slow cell PC, and at the cycle's own priority they competed with it
for the cores. Then it builds each plan that comes over its request pipe with
:func:`control.plan_builder.build_parts` and sends back the outcome and the build's log records.

    python -m control.plan_worker REQUEST_FD REPLY_FD
"""

import contextlib
import os
import sys

#: niceness of the worker process: the scheduler prefers the cycle's processes over it when a
#: core is shared (10: half of the 0..19 range; a planner that waits costs a pause, a cycle that
#: waits costs lost commands)
WORKER_NICENESS = 10


def _lower_priority() -> None:
    with contextlib.suppress(OSError):  # not permitted here: it runs on at its given priority
        os.nice(WORKER_NICENESS)


if __name__ == "__main__":
    _lower_priority()

import logging  # noqa: E402
from multiprocessing.connection import Connection  # noqa: E402
from typing import Any  # noqa: E402


class _Captured(logging.Handler):
    """The build's log records, to be logged again by the control process (the worker has
    no log of its own)."""

    def __init__(self) -> None:
        super().__init__(logging.INFO)
        self.records: list[tuple[str, int, str]] = []

    def emit(self, record: logging.LogRecord) -> None:
        self.records.append((record.name, record.levelno, record.getMessage()))


def serve(requests: Connection, replies: Connection) -> None:
    """Build each plan that comes over ``requests``, send back the outcome (``("ok", parts)``,
    ``("refused", why)`` or ``("error", what)``) and the log records over ``replies``, until
    the control process closes its end."""
    captured = _Captured()
    root = logging.getLogger()
    root.addHandler(captured)
    root.setLevel(logging.INFO)
    # imported now, not while the first plan waits
    import control.experiments
    import control.taught_path  # noqa: F401
    from control.plan_builder import PlanRefused, build_parts

    while True:
        try:
            job_id, args = requests.recv()
        except (EOFError, OSError):
            return
        captured.records = []
        try:
            outcome: tuple[str, Any] = ("ok", build_parts(*args))
        except PlanRefused as exc:
            outcome = ("refused", str(exc))
        except Exception as exc:  # a fault of ours: the plan fails with it, the worker stays
            outcome = ("error", f"{type(exc).__name__}: {exc}")
        try:
            replies.send((job_id, outcome, captured.records))
        except (OSError, ValueError):
            return


if __name__ == "__main__":
    serve(
        Connection(int(sys.argv[1]), writable=False), Connection(int(sys.argv[2]), readable=False)
    )
