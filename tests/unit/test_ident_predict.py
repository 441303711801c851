"""``leadthrough predict``: an identified model's torque on every row of a measured file.

The expected torque is computed here with pinocchio's RNEA on the URDF and the friction written
out by hand, not by the model's regressor: predict must read the states off the file (filtered,
differentiated, at jittered times, across gaps) so that the model's torque is the truth's.
"""

from __future__ import annotations

import argparse

import numpy as np
import pinocchio as pin
import pytest

from control.identification.datafile import Measurements, read_measurements, write_measurements
from control.identification.model import IdentifiedModel
from control.identification.predict import MIN_STRETCH_ROWS, predict_rows
from control.identification.predict_cli import cli_main, configure_parser
from control.identification.rigid import RobotRegressor
from control.identification.terms import EffectTerm, FrictionTerm
from gateway.errors import DataFileError
from gateway.robot.description import load_description
from gateway.robot.urdf import to_urdf

RATE_HZ = 500.0
VISCOUS_NM_S_PER_RAD = 40.0
#: Agreement asked of predict on noise-free data [N·m], against joint torques up to ~600 N·m:
#: the 20 Hz position filter passes the motion (below 1 Hz) to a part in 1e6; the states at
#: jittered times are interpolated on a 2 ms grid (second order: (2 ms)²/8 × d⁴q/dt⁴ ≈ 40
#: rad/s⁴ gives 2e-5 rad/s² in ddq, times inertias below 100 kg·m²: 2e-3 N·m); at the ends the
#: degree-5 run-on (preprocess.EDGE_POLY_DEGREE) reproduces ddq to ~1e-4 of its amplitude.
ATOL_NM = 0.02


def _model(delay_s: float = 0.0) -> tuple[IdentifiedModel, str]:
    desc = load_description()
    xml = to_urdf(desc)
    reg = RobotRegressor(xml, tuple(desc.gravity_m_s2))
    terms = [FrictionTerm(j, "simple", 0.01, 1.0) for j in range(reg.n)]
    coefs = [np.array([0.0, VISCOUS_NM_S_PER_RAD, 0.0]) for _ in range(reg.n)]
    effects = []
    if delay_s:
        effects.append((EffectTerm("time_delay", (), {"delay_s": delay_s}), np.zeros(0), "both"))
    meta = {"urdf_xml": xml, "position_cutoff_hz": 20.0, "torque_cutoff_hz": 40.0}
    model = IdentifiedModel(
        reg, reg.base.base_values(reg.parameters()), "simple", terms, coefs, effects, "", meta
    )
    return model, xml


def _motion(t: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A smooth motion (0.2-0.7 Hz per joint), exact q, dq, ddq at times ``t``."""
    f = 0.2 + 0.1 * np.arange(n)
    a = 0.3 / (1 + 0.2 * np.arange(n))
    w = 2 * np.pi * f
    arg = np.outer(t, w) + 0.5 * np.arange(n)
    return a * np.sin(arg), a * w * np.cos(arg), -a * w**2 * np.sin(arg)


def _truth(xml: str, q: np.ndarray, dq: np.ndarray, ddq: np.ndarray) -> np.ndarray:
    m = pin.buildModelFromXML(xml)
    m.gravity.linear = np.array(load_description().gravity_m_s2)
    d = m.createData()
    rigid = np.array([pin.rnea(m, d, a, b, c) for a, b, c in zip(q, dq, ddq, strict=True)])
    return rigid + VISCOUS_NM_S_PER_RAD * dq


#: From positions alone, the run-on at a stretch's ends reproduces ddq to 1.5e-3 of its
#: amplitude (a 0.7 Hz sine at 500 Hz, degree 5, noise-free): the inertial torque's share of
#: the error there is bounded by this fraction of max |M(q) ddq|.
EDGE_DDQ_FRACTION = 2e-3


def _inertial_peak(xml: str, q: np.ndarray, ddq: np.ndarray) -> np.ndarray:
    """max over rows of |M(q) ddq| per joint [N·m] (RNEA without velocity and gravity)."""
    m = pin.buildModelFromXML(xml)
    m.gravity.linear = np.zeros(3)
    d = m.createData()
    zero = np.zeros(m.nv)
    return np.max(np.abs([pin.rnea(m, d, a, zero, c) for a, c in zip(q, ddq, strict=True)]), 0)


def _file(
    seed: int = 3, jitter_s: float = 4e-4
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, slice]:
    """12 s at 500 Hz, time stamps jittering ±``jitter_s``, a 0.5 s gap at 4 s, then a stretch
    of too few rows for the filter between two gaps at 8 s. Returns t, q, dq, ddq and the
    short stretch's rows."""
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, 12.0, 1.0 / RATE_HZ)
    t = t + rng.uniform(-jitter_s, jitter_s, t.size)
    t[0] = 0.0
    keep = ~((t > 4.0) & (t < 4.5)) & ~((t > 8.0) & (t < 8.5)) & ~((t > 8.52) & (t < 9.0))
    t = t[keep]
    short = np.flatnonzero((t >= 8.5) & (t <= 8.52))
    q, dq, ddq = _motion(t, 6)
    return t, q, dq, ddq, slice(int(short[0]), int(short[-1]) + 1)


def test_predict_answers_every_row_of_a_jittered_file_with_gaps_with_the_truths_torque():
    model, xml = _model()
    t, q, dq, ddq, short = _file()
    want = _truth(xml, q, dq, ddq)
    m = Measurements(t, q, dq, want, None, "synthetic.csv")
    got = predict_rows(model, m)
    assert got.shape == want.shape
    declined = ~np.isfinite(got).all(axis=1)
    assert short.stop - short.start < MIN_STRETCH_ROWS
    np.testing.assert_array_equal(np.flatnonzero(declined), np.arange(short.start, short.stop))
    assert declined.mean() <= 0.05
    scale = np.abs(want).max(axis=0)
    assert np.all(scale > 10 * ATOL_NM)
    np.testing.assert_allclose(got[~declined], want[~declined], rtol=0, atol=ATOL_NM)


def test_without_measured_velocity_predict_differentiates_the_positions():
    """On regular time stamps: positions read at jittered ones are put on the grid by linear
    interpolation, whose error (Δ²/8 × q'', 3e-6 rad here) the second derivative amplifies by
    (2π × 20 Hz)²; the jittered file is tested with a measured velocity."""
    model, xml = _model()
    t, q, dq, ddq, _ = _file(jitter_s=0.0)
    want = _truth(xml, q, dq, ddq)
    got = predict_rows(model, Measurements(t, q, None, want, None, "no_dq.csv"))
    ok = np.isfinite(got).all(axis=1)
    bound = ATOL_NM + EDGE_DDQ_FRACTION * _inertial_peak(xml, q, ddq)
    assert np.all(np.abs(got[ok] - want[ok]) <= bound), np.abs(got[ok] - want[ok]).max(0) / bound


def test_a_delayed_model_answers_each_row_with_the_states_delay_earlier():
    delay = 0.01
    model, xml = _model(delay)
    t, q, dq, _, _ = _file()
    m = Measurements(t, q, dq, np.zeros_like(q), None, "delayed.csv")
    got = predict_rows(model, m)
    ok = np.isfinite(got).all(axis=1)
    # declined: the rows within the delay of a stretch's start (their states were not
    # recorded) and the short stretch
    starts = np.r_[0, np.flatnonzero(np.diff(t) > 0.1) + 1]
    for s in starts[:2]:
        assert not ok[s] and ok[s + int(1.5 * delay * RATE_HZ)]
    assert (~ok).mean() <= 0.05
    want = _truth(xml, *_motion(t - delay, 6))
    np.testing.assert_allclose(got[ok], want[ok], rtol=0, atol=ATOL_NM)


def _parse(argv: list[str]) -> argparse.Namespace:
    p = argparse.ArgumentParser()
    configure_parser(p)
    return p.parse_args(argv)


def test_the_command_writes_t_and_one_torque_per_joint_for_every_input_row(tmp_path, capsys):
    model, xml = _model()
    model.save(tmp_path / "model.json")
    t, q, dq, ddq, short = _file()
    write_measurements(tmp_path / "run.csv", Measurements(t, q, dq, 0 * q, None, "run.csv"))
    out = tmp_path / "pred" / "run_pred.csv"
    argv = ["--model", str(tmp_path / "model.json"), "--data", str(tmp_path / "run.csv")]
    assert cli_main(_parse([*argv, "--out", str(out)])) == 0
    lines = out.read_text().splitlines()
    assert lines[0] == "t,tau1,tau2,tau3,tau4,tau5,tau6"
    rows = np.array([[float(v) for v in line.split(",")] for line in lines[1:]])
    assert rows.shape == (t.size, 7)
    np.testing.assert_allclose(rows[:, 0], read_measurements(tmp_path / "run.csv").t, rtol=1e-9)
    assert np.isnan(rows[short, 1:]).all() and np.isfinite(np.delete(rows, short, 0)).all()
    ok = np.isfinite(rows[:, 1])
    np.testing.assert_allclose(rows[ok, 1:], _truth(xml, q, dq, ddq)[ok], atol=ATOL_NM)
    said = capsys.readouterr().out
    assert f"{t.size - (short.stop - short.start)} of {t.size} rows predicted" in said


def test_a_file_of_another_robot_is_refused_naming_it(tmp_path):
    model, _ = _model()
    t = np.arange(0.0, 2.0, 1 / RATE_HZ)
    q = np.zeros((t.size, 7))
    m = Measurements(t, q, None, q, None, "seven.csv")
    with pytest.raises(DataFileError, match=r"seven.csv:1: has 7 joints.*model has 6"):
        predict_rows(model, m)


def test_a_model_fitted_without_its_cylinders_needs_the_pressures(tmp_path):
    model, _ = _model()
    model.metadata["cylinders_removed"] = True
    t, q, dq, _, _ = _file()
    with pytest.raises(DataFileError, match="no pressure columns"):
        predict_rows(model, Measurements(t, q, dq, 0 * q, None, "nop.csv"))


def test_the_scored_raw_rows_start_at_the_analysis_sample_the_figures_start_at():
    """analyze scores the rest of the test run after the rows case (B) used: in raw rows, the
    files after the one holding that analysis sample, and that file from its time on."""
    from control.identification.heldout import TestFile, scored_rows

    def file(t0: float, rows: int) -> Measurements:
        t = t0 + np.arange(rows) / RATE_HZ
        z = np.zeros((rows, 2))
        return Measurements(t, z, None, z, None, f"f{t0}")

    files = [TestFile(file(0.0, 100), 20), TestFile(file(0.0, 150), 30)]
    analysis_t = np.r_[np.arange(20) * 0.01 + 0.05, np.arange(30) * 0.01 + 0.05]
    every = scored_rows(files, analysis_t, 0)
    assert [r.all() for r in every] == [True, True]
    in_second = scored_rows(files, analysis_t, 25)  # analysis sample 5 of the second file
    assert not in_second[0].any()
    np.testing.assert_array_equal(in_second[1], files[1].measurements.t >= 0.1)
    in_first = scored_rows(files, analysis_t, 10)
    np.testing.assert_array_equal(in_first[0], files[0].measurements.t >= 0.15)
    assert in_first[1].all()
