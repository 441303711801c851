"""The let-go campaign's judgement (sim_bridge/letgo.py) on synthetic truth logs: a run-on is
counted from the motion 2-4 s after the push, a stop is not, and bad arguments are refused."""

from __future__ import annotations

import numpy as np
import pytest

from sim_bridge import letgo

DT = 0.002


def truth(creep_m_s: float) -> dict[str, np.ndarray]:
    """Teaching from 0.5 s; the tool moves along +y at 0.2 m/s during the push, then stands,
    or creeps along x at ``creep_m_s``."""
    t = np.arange(0.0, 0.5 + letgo.PROBE_S + 7.0, DT)
    s = t - 0.5 - letgo.PROBE_S  # time since the push began
    y = 0.2 * np.clip(s, 0.0, letgo.PUSH_S)
    x = creep_m_s * np.clip(s - letgo.PUSH_S, 0.0, None)
    return {"t_s": t, "teaching": (t >= 0.5).astype(float), "tool_x": x, "tool_y": y,
            "tool_z": np.zeros_like(t)}  # fmt: skip


def test_an_arm_that_stops_is_not_counted_and_its_travel_and_speed_are_measured():
    rec = letgo.judge(truth(0.0), 20.0)
    assert not rec["ran_on"] and rec["after_m"] == pytest.approx(0.0, abs=1e-12)
    assert rec["travel_m"] == pytest.approx(0.4, abs=0.002)
    assert rec["peak_m_s"] == pytest.approx(0.2, rel=1e-6)


def test_a_creep_of_a_millimetre_in_two_seconds_after_the_let_go_is_a_run_on():
    assert letgo.judge(truth(0.6e-3), 40.0)["ran_on"]
    assert not letgo.judge(truth(0.4e-3), 40.0)["ran_on"]
    lines = letgo.table([letgo.judge(truth(c), 40.0) for c in (0.0, 0.6e-3)])
    assert lines[1].split()[:3] == ["40", "2", "1"]


def test_a_log_too_short_or_never_teaching_is_refused_by_name():
    short = {k: v[: v.size // 2] for k, v in truth(0.0).items()}
    with pytest.raises(ValueError, match="truth log holds"):
        letgo.judge(short, 20.0)
    idle = {**truth(0.0), "teaching": np.zeros(truth(0.0)["t_s"].size)}
    with pytest.raises(ValueError, match="never followed"):
        letgo.judge(idle, 20.0)


@pytest.mark.parametrize("argv", [["--runs", "0"], ["--forces", "-5"], ["--control", "[1]"],
                                  ["--control", "{nope"]])  # fmt: skip
def test_bad_arguments_are_refused(argv, capsys):
    with pytest.raises(SystemExit) as e:
        letgo.main(argv)
    assert e.value.code == 2
    assert "error" in capsys.readouterr().err
