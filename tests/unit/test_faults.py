"""The fault campaign's figures (sim_bridge/faults.py measure) on a truth log made by hand."""

from __future__ import annotations

import numpy as np
import pytest

from sim_bridge.faults import FAULTS, after_last_command, measure

DT = 0.008


def truth_of(x: np.ndarray) -> dict[str, np.ndarray]:
    n = x.size
    return {
        "t_s": DT * np.arange(n),
        "tool_x": x,
        "tool_y": np.full(n, 0.5),
        "tool_z": np.full(n, 1.0),
    }


def drag_then_stop(v=0.15, react_s=0.05, decel=1.5, rest_s=1.5, t_fault=1.0) -> np.ndarray:
    """The tool at v along x, the fault at t_fault, still v for react_s, then a constant
    deceleration to rest, then rest."""
    t = DT * np.arange(int((t_fault + react_s + v / decel + rest_s) / DT))
    t_brake = t_fault + react_s
    tb = np.clip(t - t_brake, 0.0, v / decel)
    return v * np.minimum(t, t_brake) + v * tb - 0.5 * decel * tb**2


def test_the_figures_of_a_stop_match_its_kinematics():
    x = drag_then_stop()
    k = round(1.0 / DT)
    r = measure(truth_of(x), k)
    assert r["speed_m_s"] == pytest.approx(0.15, rel=1e-6)
    assert r["speed_before_m_s"] == pytest.approx(0.15, rel=1e-6)
    assert r["reaction_s"] == pytest.approx(0.05, abs=2 * DT)
    assert r["stop_s"] == pytest.approx(0.05 + 0.1, abs=3 * DT)
    assert r["travel_after_reaction_m"] == pytest.approx(0.15**2 / 3.0, rel=0.15)
    assert r["travel_m"] == pytest.approx(0.15 * 0.05 + 0.0075, rel=0.1)
    assert r["peak_m_s"] == pytest.approx(0.15, rel=1e-6) and r["tail_m"] < 1e-9


def test_an_arm_that_never_rests_has_no_stop_and_a_creep_shows_in_the_tail():
    t = DT * np.arange(400)
    r = measure(truth_of(0.02 * t), 100)  # 20 mm/s on and on
    assert r["stop_s"] is None and r["tail_m"] == pytest.approx(0.01, rel=0.05)
    with pytest.raises(ValueError, match="not inside the truth log"):
        measure(truth_of(0.02 * t), 398)


def test_every_fault_has_a_bound_and_names_its_cause_where_a_gateway_is_left():
    names = [f.name for f in FAULTS]
    assert len(set(names)) == len(names)
    for f in FAULTS:
        assert 0 < f.max_travel_m <= 0.1
        assert (f.inject is None) == bool(f.operator), f"{f.name}: scripted or injected, not both"
        assert f.state is None or f.state in ("ready", "stopped", "fault")


def test_the_stop_after_the_last_command_is_timed_from_that_command():
    """Commands (a finite latency) until 1.0 s, then none; the tool at 0.2 m/s keeps on for
    one cycle, then decelerates at 12.5 m/s² to rest (16 ms, 1.6 mm + 1.6 mm)."""
    x = drag_then_stop(v=0.2, react_s=DT, decel=12.5, t_fault=1.0)
    truth = truth_of(x)
    last = round(1.0 / DT)
    truth["latency_s"] = np.where(np.arange(x.size) <= last, 0.002, np.nan)
    r = after_last_command(truth, last + 3)  # the harness's injection can come after it
    assert r["last_command_s"] == pytest.approx(-3 * DT)
    assert r["speed_at_last_command_m_s"] == pytest.approx(0.2, rel=1e-6)
    assert r["stop_after_command_s"] == pytest.approx(DT + 0.016, abs=DT)
    assert r["travel_after_command_m"] == pytest.approx(0.2 * DT + 0.2**2 / 25.0, rel=0.05)
    assert r["travel_after_missed_m"] == pytest.approx(0.2**2 / 25.0, rel=0.1)
    truth["latency_s"][:] = np.nan  # no command near the fault: nothing to time
    assert after_last_command(truth, last)["stop_after_command_s"] is None


def test_the_speed_before_a_fault_is_not_read_from_the_stop_that_follows_it():
    """A fault that stops the arm within a cycle or two: the speed centred on the injection
    row already holds the stop; the speed over the rows before it is the arm's at the fault."""
    x = drag_then_stop(react_s=0.0, decel=15.0)
    k = round(1.0 / DT)
    r = measure(truth_of(x), k)
    assert r["speed_before_m_s"] == pytest.approx(0.15, rel=1e-6)
    assert r["speed_m_s"] < 0.9 * 0.15
