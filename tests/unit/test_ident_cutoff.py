"""The position/velocity cutoff chosen from the data (:mod:`control.identification.cutoff`):
a noisy measured velocity, whose derivative is the acceleration, pulls it down; a clean one
leaves the highest candidate."""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest

from control.identification.cutoff import candidates, choose_cutoff
from control.identification.datafile import Measurements
from control.identification.preprocess import prepare
from control.identification.rigid import RobotRegressor

PENDULUM = """<robot name="pendulum">
  <link name="base"/>
  <link name="arm">
    <inertial><origin xyz="0.5 0 0"/><mass value="40"/>
      <inertia ixx="0.1" ixy="0" ixz="0" iyy="4" iyz="0" izz="4"/></inertial>
  </link>
  <joint name="j1" type="revolute"><parent link="base"/><child link="arm"/>
    <axis xyz="0 1 0"/><limit lower="-2" upper="2" effort="1000" velocity="2"/></joint>
</robot>"""


def _recording(dq_noise: float, rate_hz: float = 500.0, seconds: float = 60.0) -> Measurements:
    rng = np.random.default_rng(11)
    t = np.arange(round(seconds * rate_hz)) / rate_hz
    w = 2 * np.pi * np.array([0.11, 0.23, 0.37])
    amp = np.array([0.6, 0.25, 0.12])
    phase = np.outer(t, w) + np.array([0.0, 1.0, 2.0])
    q = (amp * np.sin(phase)).sum(axis=1)
    dq = (amp * w * np.cos(phase)).sum(axis=1)
    ddq = -(amp * w**2 * np.sin(phase)).sum(axis=1)
    model = pin.buildModelFromXML(PENDULUM)
    data = model.createData()
    tau = np.array(
        [
            pin.rnea(model, data, np.r_[a], np.r_[b], np.r_[c])[0]
            for a, b, c in zip(q, dq, ddq, strict=True)
        ]
    )
    tau += 8.0 * np.sign(dq) + 3.0 * dq + 0.3 * rng.standard_normal(t.size)
    dq_meas = dq + dq_noise * rng.standard_normal(t.size)
    return Measurements(t, q[:, None], dq_meas[:, None], tau[:, None], None, source="p.csv")


def _choose(m: Measurements):
    reg = RobotRegressor(PENDULUM)
    return choose_cutoff(
        reg,
        lambda c, edge, tc: prepare(m, 200.0, c, tc, edge),
        200.0,
        500.0,
        2e-3,
        5,
        lambda _line: None,
    )


def test_candidates_stay_below_the_rates():
    assert max(candidates(200.0, 1000.0)) == 40.0
    assert max(candidates(200.0, 50.0)) <= 20.0
    assert candidates(200.0, 4.0) == (1.6,)


def test_noisy_velocity_pulls_the_cutoff_down_and_clean_one_keeps_it_high():
    noisy = _choose(_recording(3e-3))
    clean = _choose(_recording(0.0))
    assert clean.cutoff_hz == max(clean.candidates_hz)
    assert noisy.cutoff_hz <= 8.0
    # the choice is the best candidate (up to the tie tolerance), every candidate scored
    score = noisy.relative_mse.sum(axis=1)
    assert score[list(noisy.candidates_hz).index(noisy.cutoff_hz)] <= 1.01 * score.min()
    assert score[-1] > 1.5 * score.min(), "40 Hz lets the velocity noise into ddq"
    doc = noisy.to_json()
    assert doc["cutoff_hz"] == noisy.cutoff_hz and len(doc["score"]) == len(noisy.candidates_hz)


@pytest.mark.parametrize("rate_hz", [100.0, 1000.0])
def test_other_sample_rates_work(rate_hz):
    m = _recording(1e-3, rate_hz=rate_hz, seconds=40.0)
    reg = RobotRegressor(PENDULUM)
    choice = choose_cutoff(
        reg, lambda c, e, tc: prepare(m, 200.0, c, tc, e), 200.0, rate_hz, 2e-3, 5, print
    )
    assert max(choice.candidates_hz) <= 0.4 * min(200.0, rate_hz)
    assert choice.cutoff_hz in choice.candidates_hz


@pytest.mark.parametrize("seconds", [4.0, 12.0])
def test_short_files_drop_the_low_cutoffs_they_cannot_hold(tmp_path, seconds):
    """A 2 Hz candidate trims 2.5 s at each end: a 4 s file cannot hold it, so the candidates
    start higher; a 12 s file holds them all. analyze runs and says what it compared."""
    from control.identification.analyze import analyze
    from control.identification.datafile import write_measurements
    from control.identification.stages import AnalyzeOptions

    for name, shift in (("train", 0.0), ("test", 7.0)):
        m = _recording(1e-3, rate_hz=250.0, seconds=seconds)
        write_measurements(
            tmp_path / f"{name}.csv", Measurements(m.t + shift, m.q, m.dq, m.tau, None, name)
        )
    (tmp_path / "p.urdf").write_text(PENDULUM)
    summary = analyze(
        tmp_path / "p.urdf",
        [tmp_path / "train.csv"],
        [tmp_path / "test.csv"],
        tmp_path / "out",
        AnalyzeOptions(plots=False, find_effects=False),
        progress=lambda _line: None,
    )
    choice = summary["cutoff_hz"]["choice"]
    lowest = min(choice["candidates_hz"])
    assert (lowest > 2.0) if seconds < 5.0 else (lowest == 2.0)
    assert summary["cutoff_hz"]["position"] == choice["cutoff_hz"] in choice["candidates_hz"]


def test_a_test_file_cut_short_by_gaps_keeps_the_cutoffs_it_can_hold(tmp_path):
    """A long training file would allow 2 Hz, but the test file's gap-free stretches (holds
    and coasts cut a recording of the cell) are 3 s each: a cutoff chosen below what they hold
    would trim the whole test file away. The candidates start where every file keeps rows, and
    the lowest left is one they hold; the test file's values play no part."""
    from control.identification.analyze import analyze
    from control.identification.datafile import write_measurements
    from control.identification.preprocess import keeps_a_stretch
    from control.identification.stages import AnalyzeOptions

    train = _recording(1e-3, rate_hz=125.0, seconds=30.0)
    write_measurements(tmp_path / "train.csv", Measurements(*_fields(train, 0.0), "train"))
    test = _recording(1e-3, rate_hz=125.0, seconds=9.0)
    keep = (test.t % 3.0) > 0.2  # a 0.2 s gap every 3 s
    cut = Measurements(test.t[keep], test.q[keep], test.dq[keep], test.tau[keep], None, "test")
    write_measurements(tmp_path / "test.csv", Measurements(*_fields(cut, 40.0), "test"))
    assert not keeps_a_stretch(cut, 2.0) and keeps_a_stretch(cut, 8.0)
    (tmp_path / "p.urdf").write_text(PENDULUM)
    lines: list[str] = []
    summary = analyze(
        tmp_path / "p.urdf",
        [tmp_path / "train.csv"],
        [tmp_path / "test.csv"],
        tmp_path / "out",
        AnalyzeOptions(plots=False, find_effects=False),
        progress=lines.append,
    )
    lowest = min(summary["cutoff_hz"]["choice"]["candidates_hz"])
    assert keeps_a_stretch(cut, lowest) and lowest > 2.0
    assert any("left out" in line and "test.csv" in line for line in lines), lines


def _fields(m: Measurements, shift_s: float) -> tuple:
    return m.t + shift_s, m.q, m.dq, m.tau, None
