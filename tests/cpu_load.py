"""Run a command beside a competing CPU load: the suite's way to prove on a fast machine what a
slow cell PC does (issue 45). `make test-loaded` runs the stack tier this way.

One busy process is pinned to each CPU named by ``--cores`` (default: CPU 0), at the product's
own priority, for as long as the command runs. One busy process on one of two cores leaves the
product (and the virtual cell, which shares the machine in tests) about one and a half cores.
A busy process on every core leaves half of each to the processes at normal priority; the
virtual controller (SCHED_FIFO 60, sim_bridge/harness.py) and the product's processes at
``[realtime]`` priority run ahead of them (`leadthrough demo` beside one on each core: 4 of 4
runs done; beside four on each, 2 of 2, 2026-12-01). ``--taskset CPUS`` also
pins the command (and every process it starts) to those CPUs, as ``taskset -c`` does.

    python tests/cpu_load.py [--cores 0] [--taskset 0] -- COMMAND ...

Exits with the command's exit status; the busy processes end with it (also on Ctrl-C).
"""

from __future__ import annotations

import argparse
import os
import signal
import subprocess
import sys
from collections.abc import Callable


def cpu_list(text: str) -> list[int]:
    """An argparse type: a comma-separated list of CPUs this process may use."""
    try:
        cpus = sorted({int(c) for c in text.split(",") if c.strip()})
    except ValueError:
        why = f"{text!r}: a comma-separated list of CPU numbers"
        raise argparse.ArgumentTypeError(why) from None
    allowed = os.sched_getaffinity(0)
    if not cpus or not set(cpus) <= allowed:
        raise argparse.ArgumentTypeError(f"{text!r}: this process may use CPUs {sorted(allowed)}")
    return cpus


def _busy(cpu: int) -> subprocess.Popen:
    """A process that spins on ``cpu`` until killed."""
    code = f"import os\nos.sched_setaffinity(0, {{{cpu}}})\nwhile True:\n    pass\n"
    return subprocess.Popen([sys.executable, "-c", code], stdin=subprocess.DEVNULL)


def run_beside(
    command: list[str],
    helpers: list[subprocess.Popen],
    preexec_fn: Callable[[], None] | None = None,
) -> int:
    """Run ``command`` to its end (Ctrl-C passes to it as SIGINT) and return its exit status;
    the ``helpers`` (load or spinning processes already started) are killed and reaped after
    it, also when it could not start."""
    try:
        child = subprocess.Popen(command, preexec_fn=preexec_fn)
        try:
            return child.wait()
        except KeyboardInterrupt:
            child.send_signal(signal.SIGINT)
            return child.wait()
    finally:
        for h in helpers:
            h.kill()
        for h in helpers:
            h.wait()
            if h.stdout is not None:
                h.stdout.close()


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--cores", type=cpu_list, default=[min(os.sched_getaffinity(0))],
                   help="CPUs to load, one busy process each (default: the first)")  # fmt: skip
    p.add_argument("--taskset", type=cpu_list, default=None, help="pin the command to these CPUs")
    p.add_argument("command", nargs=argparse.REMAINDER, help="-- then the command to run")
    args = p.parse_args(argv)
    command = args.command[1:] if args.command[:1] == ["--"] else args.command
    if not command:
        p.error("no command given (put it after --)")
    busy = [_busy(cpu) for cpu in args.cores]
    pin = None if args.taskset is None else set(args.taskset)
    print(f"cpu_load: {len(busy)} busy process(es) on CPU(s) {args.cores}; command on "
          f"{'any CPU' if pin is None else f'CPU(s) {sorted(pin)}'}", flush=True)  # fmt: skip
    preexec = None if pin is None else lambda: os.sched_setaffinity(0, pin)
    return run_beside(command, busy, preexec_fn=preexec)


if __name__ == "__main__":
    sys.exit(main())
