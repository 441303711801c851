"""Eq. (29) on the virtual cell, every part its own process: a spray gun the commissioned model
lacks (6 kg, mounted on the plant, never declared to the product) blocks teaching at the
static-load check; one replay of a program teaches the model the gun (control/
model_adaptation.py), after which the check passes and teaching engages, and while the arm is
taught the adapted model stays where the replay left it; a control process killed and
restarted by the gateway starts from the kept mass. Judged from the control process's
telemetry and health and the gateway's status."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time

import numpy as np
import pytest

from gateway.bus import open_client
from gateway.program import ProgramWriter
from sim_bridge.commission import commissioned_stack

pytestmark = pytest.mark.stack

GUN_KG = 6.0


def write_program(path, q0: np.ndarray, seconds: float = 40.0) -> None:
    """A taught program that swings every joint around ``q0`` and back (a stand-in for a
    sprayed part: shoulder, elbow and wrist all turn)."""
    amp = np.array([0.25, 0.15, 0.15, 0.6, 0.5, 0.6])
    freq = np.array([1, 2, 3, 2, 3, 1]) * 2 * np.pi / seconds
    w = ProgramWriter(path, [f"j{j + 1}" for j in range(6)])
    w.open()
    w.teach(True, 0.0)
    t = np.arange(0.0, seconds + 1e-9, 0.02)
    for k, tk in enumerate(t):
        w.trace(float(tk), k, q0 + amp * np.sin(freq * tk))
    w.mark(float(t[-1]), len(t) - 1, q0 + amp * np.sin(freq * t[-1]), "end", "cli")
    w.close(float(t[-1]))


def test_a_replay_teaches_the_model_a_gun_it_lacked_and_teaching_leaves_it(tmp_path):
    gun = {"kind": "payload", "mass_kg": GUN_KG, "com_m": [0.0, 0.05, 0.1]}
    tele: dict = {}
    health: dict = {}

    def on_telemetry(sample) -> None:  # zenoh's thread: decode only
        tele.update(json.loads(sample.payload.to_bytes()))

    def on_health(sample) -> None:
        health.update(json.loads(sample.payload.to_bytes()))

    def wait_for(what, predicate, timeout_s: float):
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            if predicate():
                return
            time.sleep(0.1)
        raise TimeoutError(f"{what}: telemetry {tele.get('model_adaptation')}, health {health}")

    with commissioned_stack(tmp_path, sim_overrides={"effects": [gun]}) as stack:
        stack.start()
        session = open_client(stack.bus)
        subs = [
            session.declare_subscriber(stack.bus.keys.control_telemetry, on_telemetry),
            session.declare_subscriber(stack.bus.keys.health("control"), on_health),
        ]
        try:
            stack.wait_status(lambda s: s.get("can_start") is True, 40.0, "cell ready to start")
            assert stack.request("start")["ok"]
            blocked = stack.wait_status(
                lambda s: "load the model lacks" in str(s.get("reason")), 20.0, "the load check"
            )
            print(f"before the replay: {blocked['reason']}")
            wait_for("telemetry", lambda: "model_adaptation" in tele, 5.0)
            assert tele["model_adaptation"]["windows_seen"] == 0

            truth = stack.truth()
            q0 = np.array([truth[f"q{j + 1}"][-1] for j in range(6)])
            program = tmp_path / "swing.jsonl"
            write_program(program, q0)
            # 150 mm/s: at 200 mm/s on one core, held cycles' catch-up once took the tool to
            # 251 mm/s and the CAN driver's speed monitor stopped the replay
            replay = [sys.executable, "-m", "gateway.cli", "replay", str(program),
                      "--bus", stack.bus.endpoint, "--speed-mm-s", "150"]  # fmt: skip
            out = subprocess.run(replay, capture_output=True, text=True, timeout=180)
            assert out.returncode == 0, out.stdout + out.stderr

            # the enabling device is held and the check now passes: teaching engages
            stack.wait_status(lambda s: s.get("state") == "teaching", 20.0, "teaching")
            wait_for("the adapted model applied", lambda: tele["model_adaptation"]["applied"], 5)
            learned = dict(tele["model_adaptation"])
            check = health["load_check"]
            time.sleep(2.0)  # taught (the arm held still, the hand off): nothing adapts
            taught = dict(tele["model_adaptation"])

            # the control process dies; the gateway's new one starts from the kept mass
            os.kill(stack.child_pid("control"), signal.SIGKILL)
            restarted = stack.wait_status(
                lambda s: (s.get("model_adaptation") or {}).get("restored") is True,
                30.0, "a new control process with the kept mass",
            )  # fmt: skip
        finally:
            for sub in subs:
                sub.undeclare()
            session.close()
    print(f"adapted in replay: {learned}; load check after: {check}")
    assert abs(learned["mass_kg"] - GUN_KG) < 0.25 * GUN_KG, learned
    before = learned["residual_rms_identified_nm"]
    after = learned["residual_rms_adapted_nm"]
    # J2 and J3 carry the gun: scored on each window before it moved the estimate, so the
    # figure includes the estimate's climb from 0 kg (0.37-0.39 of the identified model's on
    # two cores, 0.68 on one, where more of the replay's cycles are held)
    assert after[1] < 0.8 * before[1] and after[2] < 0.8 * before[2], learned
    assert check["ok"], check
    assert taught["windows_seen"] == learned["windows_seen"], (learned, taught)
    assert taught["mass_kg"] == learned["mass_kg"]
    kept = restarted["model_adaptation"]
    print(f"after the control process was killed: {kept}")
    assert abs(kept["mass_kg"] - learned["mass_kg"]) < 1e-3, kept
    assert kept["applied"] and kept["problem"] is None, kept
