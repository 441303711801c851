"""tests/slow_machine.py: a command under the emulation runs its CPU-bound work that many times
slower, SCHED_FIFO threads included, and no spinning thread outlives it."""

from __future__ import annotations

import os
import re
import subprocess
import sys
import time
from pathlib import Path

import pytest
import slow_machine

SCRIPT = Path(slow_machine.__file__)
#: CPU work the timed command does [s of this machine's CPU]
WORK_S = 0.3
FACTOR = 3.0

pytestmark = [
    pytest.mark.skipif(
        not slow_machine.fifo_permitted(), reason="this OS refuses SCHED_FIFO to this user"
    ),
    # its spinners take every CPU at SCHED_FIFO: never beside the stack tier (tests/conftest.py)
    pytest.mark.exclusive,
]


def _timed(fifo: int, pinned: bool, wrap: list[str]) -> float:
    """Wall time of WORK_S of CPU time spent by one thread at SCHED_FIFO ``fifo`` (0: normal),
    ``pinned`` to one CPU or free to move between them, run under ``wrap``."""
    cpu = min(os.sched_getaffinity(0))
    code = (
        "import os, time\n"
        f"if {pinned}: os.sched_setaffinity(0, {{{cpu}}})\n"
        f"if {fifo}: os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param({fifo}))\n"
        "t0 = time.monotonic(); c0 = time.thread_time()\n"
        f"while time.thread_time() - c0 < {WORK_S}: pass\n"
        "print(time.monotonic() - t0)\n"
    )
    out = subprocess.run([*wrap, sys.executable, "-c", code], capture_output=True, text=True,
                         timeout=60, check=True)  # fmt: skip
    return float(out.stdout.strip().splitlines()[-1])


@pytest.mark.parametrize("pinned", [True, False], ids=["pinned", "free_to_move"])
@pytest.mark.parametrize("fifo", [0, 40], ids=["normal", "sched_fifo_40"])
def test_cpu_work_takes_factor_times_as_long_whatever_its_priority_and_cpu(fifo, pinned):
    # every CPU this test may use is slowed: a thread free to move finds no faster one
    wrap = [sys.executable, str(SCRIPT), "--factor", str(FACTOR), "--"]
    wall = _timed(fifo, pinned, wrap)
    # The thread measures its own CPU time, and the spinner makes up for its wake-up latency,
    # so the wall time is WORK_S × FACTOR; the bounds leave a tenth below (timer granularity)
    # and a quarter above for the rest of this machine's load, which also takes the CPU.
    assert FACTOR * WORK_S * 0.9 <= wall <= FACTOR * WORK_S * 1.25, wall


def test_as_slow_as_a_loop_time_slows_this_machine_by_what_its_own_loop_lacks():
    target = 2.0 * slow_machine.loop_time_s()  # about twice as slow as this machine is now
    out = subprocess.run(
        [sys.executable, str(SCRIPT), "--as-slow-as", f"{target:.3f}", "--", sys.executable,
         "-c", "pass"],
        capture_output=True, text=True, timeout=120, check=True,
    )  # fmt: skip
    own = re.search(r"10 M-iteration loop ([\d.]+) s; [\d.]+ s asks for ([\d.]+)x", out.stdout)
    emulated = re.search(r"the loop now takes ([\d.]+) s", out.stdout)
    assert own and emulated, out.stdout
    own_s, factor, emulated_s = float(own[1]), float(own[2]), float(emulated[1])
    # the factor is what the wrapper's own measurement lacks; both are printed to two
    # decimals, the loop time of about 0.5 s so to within 1 % each way, the factor to 0.005
    assert factor == pytest.approx(slow_machine.factor_for(own_s, target), rel=0.03)
    # Slower under the emulation, by more than half the factor. Not closer: this is one run
    # of the loop against the best of three, and this machine's own loop drifted from 0.36
    # to 0.57 s within 40 minutes (2026-12-04); a fresh clone's run measured 1.32x the target
    # under a 1.25x bound. How much slower the emulation makes CPU work is the test above's,
    # on the thread's own CPU time.
    assert emulated_s > 0.5 * factor * own_s, out.stdout


def test_no_spinner_outlives_the_command_even_when_the_wrapper_is_killed():
    # the command exits at its stdin's end: when this test closes the pipe it inherited
    command = [sys.executable, "-c", "import sys; sys.stdin.read()"]
    wrapper = subprocess.Popen(
        [sys.executable, str(SCRIPT), "--factor", "2", "--", *command],
        stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True,
    )  # fmt: skip
    try:
        assert wrapper.stdout is not None
        assert "slower" in wrapper.stdout.readline()
        spinners = [p for p in _children(wrapper.pid) if "steal(" in _cmdline(p)]
        assert spinners, "the emulation started no spinner"
        wrapper.kill()  # SIGKILL: no cleanup runs in the wrapper
        wrapper.wait()
        deadline = time.monotonic() + 5.0
        while any(_alive(p) for p in spinners) and time.monotonic() < deadline:
            time.sleep(0.05)
        assert not any(_alive(p) for p in spinners), "a spinner outlived its wrapper"
    finally:
        wrapper.kill()
        wrapper.wait()
        assert wrapper.stdin is not None and wrapper.stdout is not None
        wrapper.stdin.close()  # the orphaned command ends
        wrapper.stdout.close()


def _children(pid: int) -> list[int]:
    from sim_bridge import proc_stat

    return proc_stat.children(pid, zombies=False)


def _cmdline(pid: int) -> str:
    try:
        return Path(f"/proc/{pid}/cmdline").read_bytes().replace(b"\0", b" ").decode()
    except OSError:
        return ""


def _alive(pid: int) -> bool:
    from sim_bridge import proc_stat

    return proc_stat.state(pid) not in (None, "Z")
