"""Run a command on an emulated slower machine: the suite's way to try on a fast machine what a
slow cell PC or CI machine does (issue 45: machines of this class differ up to 3x in
single-core speed).

One thread per CPU runs at SCHED_FIFO 99, pinned to its CPU, and takes the first
``1 - 1/factor`` of every :data:`PERIOD_S` by spinning, the same stretch on every CPU; it
sleeps for the rest. Every
other thread of the machine, the product's SCHED_FIFO cycle threads and the virtual
controller included, then gets ``1/factor`` of each CPU in slices shorter than a control
cycle: its work takes ``factor`` times as long, as on a CPU that much slower. (A busy process
at normal priority, `tests/cpu_load.py`, leaves the product's SCHED_FIFO threads a fast
machine.) A 10 M-iteration Python loop (the guide's measure of a machine of this class, 0.56-1.62
s) took 1.12 s at ``--factor 3`` and 0.85 s at 2, against 0.61 s alone minutes apart; this
machine's own figure varied from 0.34 to 0.61 s that day (2026-12-04). What the emulation
does not slow: memory and I/O bandwidth. What it adds: the other
threads run in windows of ``1/factor`` ms (plus the spinner's wake-up latency), so a thread
that needs a CPU at once waits up to ``1 - 1/factor`` ms more than on a slower CPU.

    python tests/slow_machine.py [--factor 3] [--cpus 0,1] -- COMMAND ...

SCHED_FIFO needs root or an rtprio limit; without it the emulation is refused (exit 2), never
silently skipped. The kernel's real-time throttling (``/proc/sys/kernel/sched_rt_runtime_us``,
by default 95 % of each second per CPU) bounds what all SCHED_FIFO threads together take: with
a factor above 20 the spinning would be throttled, so factors are 1 to 20. Exits with the
command's exit status; the spinning threads end with it (also on Ctrl-C).
"""

from __future__ import annotations

import argparse
import os
import signal
import subprocess
import sys
import time

from cpu_load import cpu_list  # this script's folder is on the path, as for the tests

#: The emulation's slice [s]: each CPU is taken for the first 1 - 1/factor of every period.
#: Shorter than the product's control cycle (4-8 ms) and the virtual controller's answer window,
#: so a cycle's work is spread over several periods as on a slower CPU, not stopped for a whole
#: cycle; long enough that a wake-up's latency (tens of microseconds) is a small part of it.
PERIOD_S = 0.001
#: SCHED_FIFO priority of the spinning threads: above every thread of the product (40) and of
#: the virtual controller (60), as a slower CPU slows them all.
STEAL_PRIORITY = 99
MAX_FACTOR = 20.0


def _factor(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r}: a number") from None
    if not 1.0 <= value <= MAX_FACTOR:
        raise argparse.ArgumentTypeError(f"{text!r}: from 1 to {MAX_FACTOR:g}")
    return value


def steal(cpu: int, share: float, parent: int, period_s: float = PERIOD_S) -> None:
    """In this process: go to SCHED_FIFO :data:`STEAL_PRIORITY`, pin to ``cpu`` and spin for
    the first ``share`` of every ``period_s`` of CLOCK_MONOTONIC (periods at its multiples, so
    every CPU's spinner takes the same stretch: a thread cannot hop to another CPU's free
    stretch and run faster than a slow core would), sleeping for the rest, until process
    ``parent`` is gone (a spinner left behind would slow the machine for good). A sleep ends
    later than asked by the wake-up's latency (21 us median, 86 us at the 99th percentile at
    SCHED_FIFO 99 here, 2026-12-04), which the spinning thread loses of its share: the
    emulation is that much faster than asked. (Waking early to make up for it, by the latency
    last measured, can lock a CPU up: one oversleep of a few ms puts the estimate above the
    sleep, and the thread never sleeps again to measure a shorter one. A test run with it hung
    60 s, 2026-12-04.)"""
    # the priority first: pinned at normal priority to a CPU a SCHED_FIFO thread holds, this
    # process would never run again to raise it
    os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(STEAL_PRIORITY))
    os.sched_setaffinity(0, {cpu})
    print("ready", flush=True)
    clock = time.monotonic
    while os.getppid() == parent:
        k = int(clock() / period_s)
        busy_until = (k + share) * period_s
        while clock() < busy_until:
            pass
        if (left := (k + 1) * period_s - clock()) > 0:
            time.sleep(left)


def _spinner(cpu: int, share: float) -> subprocess.Popen:
    code = f"import sys\nsys.path.insert(0, {os.path.dirname(__file__)!r})\n"
    code += f"from slow_machine import steal\nsteal({cpu}, {share!r}, {os.getpid()})\n"
    return subprocess.Popen(
        [sys.executable, "-c", code], stdin=subprocess.DEVNULL, stdout=subprocess.PIPE, text=True
    )


def _ready(spinner: subprocess.Popen) -> bool:
    """The spinner took its CPU (it says so once it runs at its priority, pinned)."""
    assert spinner.stdout is not None
    return spinner.stdout.readline().strip() == "ready"


def fifo_permitted() -> bool:
    """This user may run a thread at SCHED_FIFO :data:`STEAL_PRIORITY`."""
    code = f"import os; os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param({STEAL_PRIORITY}))"
    return subprocess.run([sys.executable, "-c", code], capture_output=True).returncode == 0


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--factor", type=_factor, default=3.0,
                   help="how many times slower every CPU is to be (default 3)")  # fmt: skip
    p.add_argument("--cpus", type=cpu_list, default=sorted(os.sched_getaffinity(0)),
                   help="CPUs to slow (default: all this process may use)")  # fmt: skip
    p.add_argument("command", nargs=argparse.REMAINDER, help="-- then the command to run")
    args = p.parse_args(argv)
    command = args.command[1:] if args.command[:1] == ["--"] else args.command
    if not command:
        p.error("no command given (put it after --)")
    if not fifo_permitted():
        p.exit(2, f"{p.prog}: SCHED_FIFO {STEAL_PRIORITY} refused: run as root or raise the "
                  "rtprio limit; no emulation without it\n")  # fmt: skip
    share = 1.0 - 1.0 / args.factor
    spinners = [_spinner(cpu, share) for cpu in args.cpus] if share > 0 else []
    if not all(_ready(s) for s in spinners):  # the command starts on the slowed machine
        for s in spinners:
            s.kill()
            s.wait()
        p.exit(2, f"{p.prog}: a spinning thread did not start\n")
    print(f"slow_machine: CPU(s) {args.cpus} {args.factor:g}x slower "
          f"({share:.0%} of every {PERIOD_S * 1e3:g} ms taken at SCHED_FIFO {STEAL_PRIORITY})",
          flush=True)  # fmt: skip
    try:
        child = subprocess.Popen(command)
        try:
            return child.wait()
        except KeyboardInterrupt:
            child.send_signal(signal.SIGINT)
            return child.wait()
    finally:
        for s in spinners:
            s.kill()
        for s in spinners:
            s.wait()
            if s.stdout is not None:
                s.stdout.close()


if __name__ == "__main__":
    sys.exit(main())
