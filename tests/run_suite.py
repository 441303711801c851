"""`make test`'s pytest: the tests that need the machine run beside the others, which yield to them.

Two pytest processes on a machine with two CPUs or more:

- **machine**: the tests that need the machine to themselves, one at a time at normal priority:
  the stack tier (the whole product as processes on a virtual cell that shares this machine;
  ``-m stack``), what loads every CPU on purpose (``-m exclusive``: tests/slow_machine.py's
  spinners, which beside the stack tier would be a fault injected into another test) and what
  keeps wall-clock deadlines of about 0.1 s inside its own process (``-m deadline``: a virtual
  CiA 402 drive's heartbeat, sent from a thread of the test's process: once, niced beside
  the stack tier and a referee at normal priority, it went 0.16-0.18 s without the CPU and the
  host rightly called the drives lost);
- **rest**: the pure and in-process tiers, at niceness :data:`REST_NICENESS`.

The rest is a competing CPU load the stack tier must stand (issue 45), but one that yields: the
product's cycle and the virtual controller run at SCHED_FIFO and are not touched by niceness,
while the cell's threads at normal priority (zenoh's runtime, the `identify` recorder) get about
ten times the CPU of the rest's (CFS weights 1024 : 110). The niceness did not mend the faults
of two pytest-xdist workers (sessions 87, 88, "no fresh joint state from the CAN driver"): those
came from the lock-step virtual controller at normal priority, which stalled beside the family
acceptance at niceness 10 as at 0, and now runs at SCHED_FIFO (sim_bridge/sim.py).

On one CPU (``taskset -c 0 make test``; the affinity is counted) a second process adds no CPU,
only a load on the one the stack tier runs on: one pytest process runs everything, one test at
a time. ``--serial`` asks for that anywhere.

    python tests/run_suite.py [--serial] [-- PYTEST_ARGS ...]

Each process's output is printed line by line with its name in front; the exit status is the
first non-zero of the two (0 when both passed). At the end each process's failures and its
summary line are printed again (:data:`RECAP`): the process that finished first printed them many
minutes before, and a log read from its tail (CI's) must still name the failing test.
Both get ``PYTEST_ARGS`` and ``-m 'not campaign'`` (the long campaigns are `make acceptance`).
"""

from __future__ import annotations

import argparse
import os
import re
import subprocess
import sys
import threading
from typing import IO

#: niceness of the rest's pytest process (and every process it starts): half of the 0..19 range,
#: as the product's own background workers (control/plan_builder.py, gateway/recorder.py)
REST_NICENESS = 10
#: the tests that need the machine to themselves (pytest ``-m`` expressions)
MACHINE = "(stack or exclusive or deadline) and not campaign"
REST = "not stack and not exclusive and not deadline and not campaign"
ALL = "not campaign"
#: the start of a line printed again at the end: pytest's short summary of each failure and error
RECAP = ("FAILED ", "ERROR ")
#: pytest's last line: "N passed, M failed ... in S s", between rows of "=" when not quiet
SUMMARY = re.compile(r"^=* ?(\d+ [a-z]+|no tests ran)\b.* in [0-9.]+s\b")


def _forward(name: str, stream: IO[str], lock: threading.Lock, recap: list[str]) -> None:
    for line in stream:
        with lock:
            sys.stdout.write(f"[{name}] {line}")
            sys.stdout.flush()
        if line.startswith(RECAP) or SUMMARY.match(line):
            recap.append(f"[{name}] {line.rstrip()}")


def _niced() -> None:
    os.nice(REST_NICENESS)


def run_two(pytest: list[str], extra: list[str]) -> int:
    """The machine and rest processes side by side; the first non-zero exit status."""
    lock = threading.Lock()
    recap: list[str] = []
    procs: list[tuple[str, subprocess.Popen[str]]] = []
    threads = []
    try:
        for name, marks, pre in (("machine", MACHINE, None), ("rest", REST, _niced)):
            proc = subprocess.Popen(
                [*pytest, "-m", marks, *extra],
                stdout=subprocess.PIPE,
                stderr=subprocess.STDOUT,
                text=True,
                preexec_fn=pre,
                env={**os.environ, "PYTHONUNBUFFERED": "1"},  # each line as it is written
            )
            procs.append((name, proc))
            assert proc.stdout is not None
            t = threading.Thread(
                target=_forward, args=(name, proc.stdout, lock, recap), daemon=True
            )
            t.start()
            threads.append(t)
        codes = [proc.wait() for _, proc in procs]
    finally:
        for _, proc in procs:
            if proc.poll() is None:
                proc.terminate()
                proc.wait(30.0)
        for t in threads:
            t.join(5.0)
    print("run_suite: each process's failures and summary, again:")
    for line in recap:
        print(line)
    for (name, _), code in zip(procs, codes, strict=True):
        print(f"run_suite: {name}: pytest exit status {code}")
    return next((c for c in codes if c != 0), 0)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--serial", action="store_true", help="one pytest process, one test at a time")
    p.add_argument("pytest_args", nargs="*", help="passed to pytest (after --)")
    args = p.parse_args(argv)
    pytest = [sys.executable, "-m", "pytest"]
    if args.serial or len(os.sched_getaffinity(0)) < 2:
        return subprocess.call([*pytest, "-m", ALL, *args.pytest_args])
    return run_two(pytest, args.pytest_args)


if __name__ == "__main__":
    sys.exit(main())
