"""A harness killed with kill -9 leaves no virtual cell behind: its simulator and gateway (in
sessions of their own) stop, and the gateway's children with the gateway
(gateway/parent_death.py). Before, a killed `leadthrough teach-bench` left five processes
running the arm."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest

from sim_bridge.harness import running_with_argument

pytestmark = pytest.mark.stack

REPO = Path(__file__).resolve().parents[2]
#: the gateway's stop (brakes, then its children each get SIGTERM) and the simulator's [s]
GONE_S = 15.0

HARNESS = textwrap.dedent(
    """
    import sys, time
    from pathlib import Path
    from sim_bridge.harness import Stack
    stack = Stack(Path(sys.argv[1]))
    stack.start()
    stack.wait_status(lambda s: s.get("can_start") is True, 60.0, "cell ready to start")
    print(" ".join(str(pid) for pid in stack.product_pids()), stack.sim.pid, flush=True)
    time.sleep(120)
    """
)


def _running(workdir: Path) -> dict[int, str]:
    """The harness's processes still alive: those started with the cell's config (the gateway
    and its children) or its truth file (the simulator)."""
    return {**running_with_argument(workdir / "cell.toml"),
            **running_with_argument(workdir / "truth.toml")}  # fmt: skip


def test_killing_the_harness_stops_its_simulator_gateway_and_drivers(tmp_path):
    workdir = tmp_path / "cell"
    proc = subprocess.Popen([sys.executable, "-c", HARNESS, str(workdir)], cwd=REPO,
                            stdout=subprocess.PIPE, text=True)  # fmt: skip
    try:
        pids = [int(p) for p in proc.stdout.readline().split()]
        # the gateway, the CAN driver, the Modbus driver, control, and the simulator
        assert len(pids) >= 5, pids
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait(5)
        deadline = time.monotonic() + GONE_S
        while _running(workdir) and time.monotonic() < deadline:
            time.sleep(0.1)
        left = _running(workdir)
        assert not left, f"still running {GONE_S} s after the harness was killed: {left}"
    finally:
        proc.kill()
        proc.wait()
        for pid in _running(workdir):
            os.kill(pid, signal.SIGKILL)
