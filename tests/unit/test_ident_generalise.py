"""Rules that make the identification hold on data it was not built on (issue 8): the measured
noise floor, filtering model and measurement alike, bounded extrapolation, the friction family
chosen on held-out data, plain least squares per joint, thermal drift as a friction change."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import signal
from scipy.integrate import quad

from control.identification.datafile import Measurements
from control.identification.dh_urdf import PANDA_DH_ROWS, urdf_from_dh
from control.identification.effect_rules import chi2_threshold
from control.identification.envelope import Envelope
from control.identification.families import choose_family
from control.identification.fit import FrictionFit
from control.identification.lsq import Evaluation, Solution
from control.identification.model import IdentifiedModel, PlainJoint, plain_columns
from control.identification.preprocess import filter_noise_gain, prepare, white_noise_std
from control.identification.rigid import RobotRegressor
from control.identification.terms import Context, EffectTerm, FrictionTerm


def _recording(sigma: float, seconds: float = 30.0, rate_hz: float = 1000.0) -> Measurements:
    """A smooth joint motion with a friction-like torque (steps at each reversal) + noise."""
    rng = np.random.default_rng(4)
    t = np.arange(round(seconds * rate_hz)) / rate_hz
    q = 0.8 * np.sin(2 * np.pi * 0.3 * t) + 0.3 * np.sin(2 * np.pi * 0.71 * t)
    dq = np.gradient(q, t)
    tau = 20.0 * q + 5.0 * np.sign(dq) + sigma * rng.standard_normal(t.size)
    return Measurements(t, q[:, None], dq[:, None], tau[:, None], None, source="one.csv")


def test_noise_floor_is_measured_and_carried_through_the_filter():
    sigma = 0.7
    data = prepare(_recording(sigma), rate_hz=200.0, torque_cutoff_hz=40.0)
    assert data.raw_noise_nm[0] == pytest.approx(sigma, rel=0.05)
    # the floor is the std of the noise left after the torque filter, at the file's rate
    noise = np.random.default_rng(1).standard_normal(200_000) * sigma
    sos = signal.butter(4, 40.0, fs=1000.0, output="sos")
    expected = np.std(signal.sosfiltfilt(sos, noise))
    assert data.noise_nm[0] == pytest.approx(expected, rel=0.06)
    # |H|² of a Butterworth run forward and back is (1 + (f/fc)^8)^-2: its noise bandwidth
    enbw = quad(lambda x: (1 + x**8) ** -2, 0, np.inf)[0]
    assert filter_noise_gain(40.0, 1000.0) == pytest.approx(2 * enbw * 40 / 1000, rel=0.01)
    # one χ² degree of freedom: the raw variance over the decimation factor (1000 → 200 Hz)
    assert data.noise_dof_nm2[0] == pytest.approx(data.raw_noise_nm[0] ** 2 / 5, rel=1e-9)
    # the steps of the friction reversals do not inflate the estimate
    assert white_noise_std(np.cumsum(np.ones((500, 1)), axis=0))[0] == 0.0


def test_model_columns_go_through_the_same_filter_as_the_torque():
    """Without decimation the filtered column matches the filtered measurement exactly; with
    decimation (1 kHz → 200 Hz) the step's timing is only known to a sample, so the match is
    approximate — still far closer than the unfiltered step."""
    for rate_hz, tolerance in ((1000.0, 1e-6), (200.0, 0.5)):
        data = prepare(_recording(0.0), rate_hz=rate_hz, torque_cutoff_hz=40.0)
        step = np.sign(data.dq)
        filtered = data.tau - 20.0 * data.q - 5.0 * data.lowpass(step)
        unfiltered = data.tau - 20.0 * data.q - 5.0 * step
        assert np.sqrt(np.mean(unfiltered**2)) > 0.3
        assert np.sqrt(np.mean(filtered**2)) < tolerance * np.sqrt(np.mean(unfiltered**2))


def test_friction_stays_bounded_outside_the_training_envelope_and_a_spring_extrapolates():
    env = Envelope(np.array([-1.0]), np.array([1.0]), np.array([-0.5]), np.array([0.5]))
    q = np.array([[0.0], [0.0], [5.0]])
    dq = np.array([[0.5], [50.0], [0.5]])
    ctx = Context(q, dq, dq, envelope=env)
    term = FrictionTerm(0, "eq15", 0.01, 100.0)
    cols = term.columns(ctx)[0]
    np.testing.assert_allclose(cols[1], cols[0])  # 100x the velocity: the edge's value
    spring = EffectTerm("spring", (0,)).columns(ctx)[0]
    assert spring[2, 0] == 5.0  # Hooke's law is physics: q = 5 rad, past the envelope's 1 rad
    raw = FrictionTerm(0, "eq15", 0.01, 100.0).columns(Context(q, dq, dq))[0]
    assert abs(raw[1, -1]) > 100 * abs(cols[1, -1])  # without the envelope dq|dq| explodes
    assert env.outside(q, dq).ravel().tolist() == [False, True, True]
    back = Envelope.from_json(env.to_json())
    np.testing.assert_array_equal(back.q_max, env.q_max)


def test_thermal_drift_is_a_friction_level_changing_in_time():
    t = np.array([0.0, 10.0, 10.0])
    dq = np.array([[0.2], [0.2], [-0.2]])
    ctx = Context(np.zeros((3, 1)), dq, dq, t)
    cols = EffectTerm("thermal_drift", (0,)).columns(ctx)[0]
    np.testing.assert_allclose(cols, [[0.0, 0.0], [10.0, 2.0], [-10.0, -2.0]])
    params = EffectTerm("thermal_drift", (0,)).parameters(np.array([-0.3, -0.01]))
    assert params == {"rate_nm_per_s": -0.3, "viscous_rate_nm_per_rad": -0.01}


def _fit(kind: str, cv_mse: list[float]) -> FrictionFit:
    ev = Evaluation(np.zeros(2), np.asarray(cv_mse) * 100, 3, 100, Solution({}, 3))
    return FrictionFit(kind, [], np.ones(2), ev)


def test_friction_family_is_chosen_on_held_out_error_joint_by_joint():
    # eq15 is best on the big joint only; eq14 is close there and far better on the small one
    fits = {
        "eq15": _fit("eq15", [100.0, 0.04]),
        "eq14": _fit("eq14", [104.0, 0.01]),
        "simple": _fit("simple", [130.0, 0.02]),
    }
    assert choose_family(fits) == "eq14"
    fits["eq14"] = _fit("eq14", [300.0, 0.01])
    assert choose_family(fits) == "simple"


def test_significance_threshold_grows_with_columns_and_candidates():
    assert chi2_threshold(1, 1, 0.01) == pytest.approx(6.635, rel=1e-3)
    assert chi2_threshold(2, 1, 0.01) > chi2_threshold(1, 1, 0.01)
    assert chi2_threshold(1, 100, 0.01) > chi2_threshold(1, 1, 0.01)


def test_a_joint_kept_on_plain_least_squares_uses_its_own_parameters(tmp_path):
    xml = urdf_from_dh(PANDA_DH_ROWS[:3], "modified", "three")
    reg = RobotRegressor(xml)
    nb = reg.base.n_base
    rng = np.random.default_rng(2)
    beta = rng.normal(size=nb)
    terms = [FrictionTerm(j, "simple", 0.01, 1.0) for j in range(3)]
    coefs = [np.array([1.0, 0.5, 0.0])] * 3
    env = Envelope(-np.ones(3), np.ones(3), -np.ones(3), np.ones(3))
    plain = {1: PlainJoint(1, rng.normal(size=nb), 2.0, 0.3)}
    model = IdentifiedModel(
        reg, beta, "simple", terms, coefs, [], "", {"urdf_xml": xml}, env, plain
    )
    q, dq, ddq = rng.uniform(-1, 1, (3, 5, 3))
    dq[0] = 3.0  # outside the envelope: held at its edge
    got = model.torque_nm(q, dq, ddq)
    y = reg.base_regressor(q, dq, ddq)
    ctx = Context(q, dq, ddq, None, y, envelope=env)
    np.testing.assert_allclose(got[:, 1], plain_columns(ctx, 1)[1] @ plain[1].coef)
    np.testing.assert_allclose(got[:, 0], y[0] @ beta + model.friction_nm(q, dq)[:, 0])
    assert model.friction_nm(q, dq)[0, 1] == pytest.approx(2.0 + 0.3 * 1.0)
    model.save(tmp_path / "model.json")
    back = IdentifiedModel.load(tmp_path / "model.json")
    np.testing.assert_allclose(back.torque_nm(q, dq, ddq), got, rtol=1e-12)
