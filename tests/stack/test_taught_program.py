"""A taught program on the virtual cell, every part its own process: the simulated operator drags
the tool along an L-shaped path and presses the teach handle's mark button, an operator marks a
waypoint from the command line, the gateway is killed with SIGKILL mid-session, and the program
it was writing is then replayed by a new gateway. Judged from the program file and the
simulator's truth log."""

from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
import time

import numpy as np
import pytest

from control.taught_path_kinematics import path_error_m
from drivers.can.config import CanDriverConfig
from gateway.program import read_program
from gateway.robot.description import load_description
from sim_bridge.commission import commissioned_stack
from sim_bridge.harness import Stack

pytestmark = pytest.mark.stack

#: after onset [s, m]: still, 0.15 m along +x at 0.1 m/s, still, 0.1 m down, still
PATH = [[0.0, 0, 0, 0], [0.5, 0, 0, 0], [2.0, 0.15, 0, 0], [2.8, 0.15, 0, 0],
        [3.8, 0.15, 0, -0.1], [4.3, 0.15, 0, -0.1]]  # fmt: skip
HANDLE_MARKS_S = (0.3, 2.4, 4.0)
STATE_WINDOW_S = CanDriverConfig().state_window_s
#: p95 tool distance of the taught path's points from the replayed path [m]: the tremor
#: filter, the vendor loop's lag and one cycle of command delay on a path ~0.4 m long. Measured
#: 0.13 mm on this machine; without the load's command offset (control/zero_moment_law.py
#: ``hold_offset``) the arm sagged 3-4 mm under the vendor loop's finite stiffness.
REPLAY_TOLERANCE_M = 0.001


def _marks_made(stack: Stack, count: int, timeout_s: float) -> dict:
    return stack.wait_status(
        lambda s: s.get("program", {}).get("marks", 0) >= count, timeout_s, f"{count} marks"
    )


def test_taught_program_survives_kill_9_of_the_gateway_and_replays_along_the_path(tmp_path):
    operator = {"mode": "path", "path": PATH, "mark_at_s": list(HANDLE_MARKS_S),
                "hand_off_after_s": PATH[-1][0] + 0.5}  # fmt: skip
    with commissioned_stack(tmp_path, sim_overrides={"operator": operator}) as stack:
        stack.start()
        stack.wait_status(lambda s: s.get("can_start") is True, 40.0, "cell ready to start")
        reply = stack.request("start", program="l_path")
        assert reply["ok"], reply
        program = tmp_path / "programs" / "l_path.jsonl"
        assert reply["program"]["path"] == str(program)
        stack.wait_status(lambda s: s.get("state") == "teaching", 10.0, "teaching")
        _marks_made(stack, 1, 10.0)
        cli = [sys.executable, "-m", "gateway.cli", "mark", "--bus", stack.bus.endpoint]
        out = subprocess.run([*cli, "--label", "corner"], capture_output=True, text=True,
                             timeout=20)  # fmt: skip
        # The command line's mark falls between the handle's: which ones depends on how long
        # the command takes to start (2.1 s between the first two handle marks; on a slow
        # machine it came after the second, 2026-12-04). Its reply names its place.
        found = re.search(r"mark (\d+) recorded", out.stdout)
        assert out.returncode == 0 and found, out.stdout + out.stderr
        cli_at = int(found.group(1)) - 1
        assert 1 <= cli_at <= len(HANDLE_MARKS_S), out.stdout
        _marks_made(stack, 4, 15.0)
        time.sleep(1.0)  # the hand lets go; teaching goes on
        assert stack.gateway is not None
        os.kill(stack.gateway.pid, signal.SIGKILL)
        stack.gateway.wait()

        # Every mark is on disk, in order, the command line's with its label.
        taught = read_program(program)
        sources = ["handle"] * len(HANDLE_MARKS_S)
        sources.insert(cli_at, "cli")
        assert [m.source for m in taught.marks] == sources
        assert taught.marks[cli_at].label == "corner"
        # the trace is the newest state of each of the CAN driver's state windows (50 Hz)
        assert taught.n_segments == 1 and np.ptp(taught.t_s) > 4.0
        assert taught.t_s.size > 0.6 * np.ptp(taught.t_s) / STATE_WINDOW_S, taught.t_s.size
        xyz = np.array([m.q_rad for m in taught.marks])
        assert np.ptp(xyz, axis=0).max() > 0.05, "the marks are all at one pose"

        # A new gateway replays it (the enabling device is still held).
        stack.restart_gateway()
        # The controller may have faulted on its host's lost heartbeat: reset clears that.
        seen = stack.wait_status(
            lambda s: s.get("can_start") is True or s.get("state") == "fault", 40.0, "gateway up"
        )
        if seen["state"] == "fault":
            assert "controller reports FAULT" in seen["reason"], seen["reason"]
            assert stack.request("reset")["ok"]
        stack.wait_status(lambda s: s.get("can_start") is True, 20.0, "cell ready again")
        assert stack.request("start", program="after_restart")["ok"]
        # READY until the arm is still after servo-on, then TEACHING (the enabling is held)
        stack.wait_status(lambda s: s.get("state") == "teaching", 15.0, "settled")
        rows_before = stack.truth()["t_s"].size
        replay = [sys.executable, "-m", "gateway.cli", "replay", str(program),
                  "--bus", stack.bus.endpoint, "--speed-mm-s", "80"]  # fmt: skip
        out = subprocess.run(replay, capture_output=True, text=True, timeout=90)
        assert out.returncode == 0, out.stdout + out.stderr
        assert "done" in out.stdout
        truth = stack.truth()
    desc = load_description()
    q_replayed = np.stack([truth[f"q{j + 1}"][rows_before:] for j in range(6)], axis=1)
    error = path_error_m(desc, q_replayed, taught.q_rad)
    print(f"taught path points from the replayed path: p95 {error * 1e3:.2f} mm")
    assert error < REPLAY_TOLERANCE_M
