"""The sensorless admittance (``[control] strategy = "admittance"``) on the virtual cell, every
part its own process: without a hand the arm stays where it is; a push moves the tool along
the push and, once the hand lets go, the arm stops and stays. Judged from the simulator's truth
log (the hand's force and the tool's position are the plant's)."""

from __future__ import annotations

import numpy as np
import pytest
from test_stack import rest_without_operator, tool_xyz

from sim_bridge import letgo

pytestmark = pytest.mark.stack

ADMITTANCE = {"control": {"strategy": "admittance"}}


#: the engagement probe's length and the time its joints take to stick after it [s]
PROBE_S = letgo.PROBE_S


def test_without_a_hand_the_admittance_holds_the_arm_within_a_millimetre(tmp_path):
    """The plant has true stiction: a residual b taken at rest held the share of the load
    friction carried there, and once the joints slid the share read as a hand (1 m in 5 s).
    The engagement probe measures b sliding both ways; the stick zone keeps the share a
    joint at rest carries from reading as a hand. The probe moves the tool a few mm and
    back; after it the arm stays."""
    truth, window, _ = rest_without_operator(tmp_path, None, ADMITTANCE)
    t = truth["t_s"][window] - truth["t_s"][window[0]]
    xyz = tool_xyz(truth, window)
    probe = np.linalg.norm(xyz[t <= PROBE_S] - xyz[0], axis=1)
    after = xyz[t >= PROBE_S]
    drift_m = float(np.linalg.norm(after - after[0], axis=1).max())
    back_m = float(np.linalg.norm(after[0] - xyz[0]))
    print(f"admittance: the probe moved the tool {probe.max() * 1e3:.2f} mm and left it "
          f"{back_m * 1e3:.2f} mm from its start; then {drift_m * 1e3:.3f} mm of drift in "
          f"{t[-1] - PROBE_S:.1f} s without operator force")  # fmt: skip
    assert probe.max() < 10e-3, f"the probe moved the tool {probe.max() * 1e3:.1f} mm"
    assert back_m < 1e-3, f"the probe left the tool {back_m * 1e3:.2f} mm from its start"
    assert drift_m < 1e-3, f"tool drifted {drift_m * 1e3:.3f} mm after the probe"


#: 20 N, a light push: the one that ran on most (4 of 51 let-gos before the Stribeck hold, 0 of
#: 54 since). 40-60 N run the tool at the speed limit, where the joints' decelerations couple
#: most; many runs of every force are the campaign's (`python -m sim_bridge.letgo`)
PUSH_N = 20.0


def test_a_push_moves_the_tool_along_it_and_the_arm_stops_when_the_hand_lets_go(tmp_path):
    """The hand pushes for 2 s once the engagement probe is over (a painter waits for it;
    the operator's status says when it runs and when it is over), then lets go."""
    rec = letgo.run(PUSH_N, tmp_path, 0, {})
    phases = rec["phases"]
    print(f"engagement phases in the status: {phases}")
    assert "probing" in phases and phases[-1] == "following", phases
    d = np.array(rec["push_m"])
    print(f"tool displacement after a 2 s, {PUSH_N:.0f} N push along +y: {np.round(d * 1e3, 1)} mm")
    assert d[1] > 0.01, f"tool moved {d * 1e3} mm under a {PUSH_N:.0f} N +y push"
    assert d[1] / np.linalg.norm(d) > 0.7, f"motion {d * 1e3} mm is far off +y"
    # A 20 N push on a light admittance would run the tool at over 0.5 m/s: the reference is
    # held at 220 mm/s, under hand guiding's 250 mm/s (ISO 10218-1), which the arm must keep.
    print(f"tool speed: max {rec['peak_m_s'] * 1e3:.0f} mm/s")
    assert rec["peak_m_s"] <= 0.25, f"the tool reached {rec['peak_m_s'] * 1e3:.0f} mm/s"
    # the push's ramp ends 2 s after it started: the arm stops within 2 s
    print(f"tool motion 2-4 s after the push ended: {rec['after_m'] * 1e3:.3f} mm")
    assert not rec["ran_on"], "the arm kept moving after the hand let go"
