"""The seeded family of independent data sets (:mod:`.family`): arms, runs, torque, noise, files
and the scoring. No test here runs ``leadthrough analyze``; ``python -m tests.independent.family``
does.
"""

from __future__ import annotations

import json

import numpy as np
import pinocchio as pin
import pytest

from . import family as fam
from .generator import csv_header, read_csv
from .referee import read_predictions

SEEDS = range(20)
SHORT = 0.1  # duration_scale of the draws below: 4-6 s of training data


@pytest.fixture(scope="module")
def short_draws() -> dict[int, fam.Draw]:
    return {s: fam.draw(s, duration_scale=SHORT) for s in range(6)}


def _friction_from_truth(fr: dict, q: np.ndarray, dq: np.ndarray) -> np.ndarray:
    """The friction formula of the truth record, written out again."""
    tc, ts = np.array(fr["coulomb_nm"]), np.array(fr["static_nm"])
    qe, tv = np.array(fr["q_e_rad_s"]), np.array(fr["viscous_nm_s_per_rad"])
    a, b = np.array(fr["sin_kq_nm"]), np.array(fr["cos_kq_nm"])
    bracket = tc + (ts - tc) * np.exp(-np.abs(dq) / qe)
    bracket = bracket + a[:, 0] * np.sin(q) + a[:, 1] * np.sin(2 * q)
    bracket = bracket + b[:, 0] * np.cos(q) + b[:, 1] * np.cos(2 * q)
    return bracket * np.tanh(dq / fr["sign_velocity_rad_s"]) + tv * dq


def _rnea(model, q, dq, ddq) -> np.ndarray:
    data = model.createData()
    return np.array([pin.rnea(model, data, *x) for x in zip(q, dq, ddq, strict=True)])


# --------------------------------------------------------------------------- arms


@pytest.mark.parametrize("seed", SEEDS)
def test_urdf_loads_in_pinocchio_with_five_to_seven_revolute_joints(seed: int) -> None:
    arm = fam.draw_arm(seed)
    model = pin.buildModelFromXML(fam.urdf(arm))
    assert 5 <= arm.n <= 7
    assert model.nq == model.nv == arm.n
    assert list(model.names)[1:] == [f"j{i}" for i in range(1, arm.n + 1)]
    assert all(model.joints[i].shortname() == "JointModelRZ" for i in range(1, arm.n + 1))
    np.testing.assert_allclose(model.lowerPositionLimit, arm.lower)
    np.testing.assert_allclose(model.upperPositionLimit, arm.upper)
    np.testing.assert_allclose(model.velocityLimit, arm.velocity)
    for i in range(arm.n):
        origin = arm.joint_origin(i)
        np.testing.assert_allclose(
            model.jointPlacements[i + 1].rotation, origin[:3, :3], atol=1e-12
        )
        np.testing.assert_allclose(model.jointPlacements[i + 1].translation, origin[:3, 3])
        inertia = model.inertias[i + 1]
        assert inertia.mass == pytest.approx(arm.links[i].mass)
        np.testing.assert_allclose(inertia.lever, arm.com(i), atol=1e-12)
        ev = np.linalg.eigvalsh(inertia.inertia)
        assert ev[0] > 0 and ev[0] + ev[1] >= ev[2]  # positive definite, triangle inequality
    # joint 1 about the vertical, joint 2 (the shoulder) about a horizontal axis
    data = model.createData()
    pin.forwardKinematics(model, data, arm.centre)
    assert abs(data.oMi[1].rotation[2, 2]) == pytest.approx(1.0)
    assert data.oMi[2].rotation[2, 2] == pytest.approx(0.0, abs=1e-12)
    lengths = [abs(v) for j in arm.dh for v in (j.a, j.d) if v != 0.0]
    assert all(0.05 <= v <= 1.0 for v in lengths)
    assert np.all((arm.gear_ratio >= 50) & (arm.gear_ratio <= 200))
    masses = [lk.mass for lk in arm.links]
    assert masses[1] == pytest.approx(arm.mass_scale_kg) and masses[-1] < masses[1]


def test_both_dh_conventions_appear_and_describe_the_same_arm() -> None:
    arms = [fam.draw_arm(s) for s in SEEDS]
    assert {a.convention for a in arms} == {"standard", "modified"}
    assert {a.n for a in arms} == {5, 6, 7}
    rng = np.random.default_rng(1)
    for arm in arms[:6]:
        std, mod = (arm.with_convention(c) for c in ("standard", "modified"))
        assert fam.urdf(std) != fam.urdf(mod)
        models = [pin.buildModelFromXML(fam.urdf(a)) for a in (std, mod)]
        q, dq, ddq = (rng.uniform(-1.5, 1.5, (4, arm.n)) for _ in range(3))
        t_std, t_mod = (_rnea(m, q, dq, ddq) for m in models)
        np.testing.assert_allclose(t_mod, t_std, atol=1e-9 * np.abs(t_std).max())


def test_rates_vary_and_masses_span_the_family() -> None:
    rates = {fam.draw_settings(s)["rate_hz"] for s in SEEDS}
    assert len(rates) >= 4 and rates <= set(fam.RATES_HZ)
    scales = [fam.draw_arm(s).mass_scale_kg for s in SEEDS]
    assert min(scales) < 3.0 and max(scales) > 60.0
    assert all(1.0 <= m <= 150.0 for m in scales)
    cases = [fam.draw_case(s) for s in range(200)]
    assert 0.15 < cases.count("null") / len(cases) < 0.35
    assert set(cases) == set(fam.CASES)


# --------------------------------------------------------------------------- runs


def test_draw_is_deterministic_per_seed() -> None:
    a, b = fam.draw(3, duration_scale=SHORT), fam.draw(3, duration_scale=SHORT)
    assert a.urdf == b.urdf and a.truth == b.truth and a.case == b.case
    for run_a, run_b in ((a.train, b.train), (a.test, b.test)):
        for name in ("t", "q", "dq", "tau", "tau_clean"):
            np.testing.assert_array_equal(getattr(run_a, name), getattr(run_b, name))
    c = fam.draw(4, duration_scale=SHORT)
    assert c.urdf != a.urdf


def test_motion_stays_within_joint_and_velocity_limits(short_draws) -> None:
    for d in short_draws.values():
        for run in (d.train, d.test):
            assert np.all(run.q_true >= d.arm.lower) and np.all(run.q_true <= d.arm.upper)
            assert np.all(np.abs(run.dq_true) <= d.arm.velocity)


def test_the_counterbalance_case_springs_the_gravity_joint_and_leaves_its_range() -> None:
    """Only when asked for: never among the default draws."""
    assert "counterbalance" not in {fam.draw_case(s) for s in range(200)}
    for seed in (0, 1, 2):
        d = fam.draw(seed, case="counterbalance", duration_scale=SHORT)
        (effect,) = d.truth["effects"]
        j = effect["joints"][0] - 1
        assert effect["name"] == "spring" and j == fam.gravity_joint(d.train.tau_rigid)
        assert 100.0 <= effect["parameters"]["noise_multiple"] <= 1000.0
        assert j + 1 in d.truth["outside_envelope"]["joints"]
        lo, hi = d.train.q_true[:, j].min(), d.train.q_true[:, j].max()
        out = (d.test.q_true[:, j] < lo) | (d.test.q_true[:, j] > hi)
        assert out.mean() > 0.05, "the test run never leaves the spring joint's range"


@pytest.mark.parametrize("case", [*fam.CASES, *fam.CASE_ALIASES, *fam.EXPLICIT_CASES])
def test_noise_free_torque_is_rnea_plus_friction_plus_the_effect(case: str) -> None:
    d = fam.draw(1, case=case, duration_scale=SHORT)
    truth, n = d.truth, d.n
    model = pin.buildModelFromXML(d.urdf)
    for run in (d.train, d.test, d.holdout):
        rigid = _rnea(model, run.q_true, run.dq_true, run.ddq_true)
        friction = _friction_from_truth(truth["friction"], run.q_true, run.dq_true)
        np.testing.assert_allclose(run.tau_nominal, rigid + friction, rtol=1e-9, atol=1e-9)
    (effect,) = truth["effects"] or [None]
    name = effect["name"] if effect else "null"
    p = effect["parameters"] if effect else {}
    for role, run in (("train", d.train), ("test", d.test), ("holdout", d.holdout)):
        expected = run.tau_nominal.copy()
        if name == "payload" and (role != "train" or effect["appeared"] == fam.ALL_ALONG):
            loaded = pin.buildModelFromXML(d.urdf)
            rot = d.arm.flange()[:3, :3]
            extra = pin.Inertia(
                p["mass_kg"],
                np.array(p["com_m"]),
                rot @ np.array(p["inertia_about_com_kgm2"]) @ rot.T,
            )
            loaded.inertias[n] = loaded.inertias[n] + extra
            expected = _rnea(loaded, run.q_true, run.dq_true, run.ddq_true) + (
                run.tau_nominal - _rnea(model, run.q_true, run.dq_true, run.ddq_true)
            )
        elif name == "spring":
            j = effect["joints"][0] - 1
            expected[:, j] += p["k_nm_per_rad"] * (run.q_true[:, j] - p["q0_rad"])
        elif name == "position_ripple":
            j = effect["joints"][0] - 1
            arg = p["cycles_per_rev"] * run.q_true[:, j] + p["phase_rad"]
            expected[:, j] += p["amplitude_nm"] * np.sin(arg)
        elif name == "time_delay":
            exc = d.excitations[0 if role == "train" else 1]
            q, dq, ddq = exc.evaluate(run.t - p["delay_s"])
            expected = _rnea(model, q, dq, ddq) + _friction_from_truth(truth["friction"], q, dq)
        elif name == "thermal_drift" and role != "train":
            for j, r in zip(effect["joints"], p["rate_nm_per_s"], strict=True):
                expected[:, j - 1] += r * run.t * np.tanh(run.dq_true[:, j - 1] / 1e-4)
        elif name == "wrist_coupling":
            expected[:, n - 1] += p["coefficient"] * run.tau_nominal[:, p["from_joint"] - 1]
        np.testing.assert_allclose(run.tau_clean, expected, rtol=1e-9, atol=1e-9)
    if name != "null":
        assert effect["main_parameter"] == fam.MAIN_PARAMETER[name]
        assert effect["appeared"] in (fam.ALL_ALONG, fam.BETWEEN)
    if name == "thermal_drift":
        # the drift runs on through the holdout the referee keeps
        span = truth["duration_s"]["test"] + truth["duration_s"]["holdout"]
        drop = -np.array(p["rate_nm_per_s"]) * span
        np.testing.assert_allclose(
            drop / np.array(p["coulomb_nm_before"]), p["drop_fraction_at_end"]
        )
        np.testing.assert_array_equal(d.train.tau_clean, d.train.tau_nominal)


def test_measured_channels_carry_the_drawn_noise(short_draws) -> None:
    for d in short_draws.values():
        noise = d.truth["noise"]
        lsb = noise["dq_lsb_rad_s"]
        for run in (d.train, d.test):
            step = np.array(noise["q_step_rad"])
            assert np.all(np.abs(run.q - run.q_true) <= 0.5 * step * (1 + 1e-9))
            counts = run.q / step
            np.testing.assert_allclose(counts, np.round(counts), atol=1e-6)
            np.testing.assert_allclose(run.dq / lsb, np.round(run.dq / lsb), atol=1e-6)
            want_dq = np.sqrt(np.array(noise["dq_noise_std_rad_s"]) ** 2 + lsb**2 / 12.0)
            got_dq = np.std(run.dq - run.dq_true, axis=0)
            np.testing.assert_allclose(got_dq, want_dq, rtol=0.1)
            got_tau = np.std(run.tau - run.tau_clean, axis=0)
            np.testing.assert_allclose(got_tau, noise["torque_noise_std_nm"], rtol=0.1)
        sigma = np.array(noise["torque_noise_std_nm"])
        peak = np.array(d.truth["peak_rigid_torque_nm"])
        assert np.all(sigma >= fam.TORQUE_NOISE_MIN_NM)
        assert np.all((sigma <= 0.02 * peak * 1.0001) | (sigma == fam.TORQUE_NOISE_MIN_NM))
        dq_std = np.array(noise["dq_noise_std_rad_s"])
        assert np.all((dq_std >= 1e-4) & (dq_std <= 3e-3))


def test_the_measurement_chain_is_applied_as_drawn_and_changes_nothing_else() -> None:
    plain, chained = (
        fam.draw(2, duration_scale=SHORT),
        fam.draw(2, duration_scale=SHORT, chain=True),
    )
    mc = chained.truth["measurement_chain"]
    assert mc["applied"] and not plain.truth["measurement_chain"]["applied"]
    assert {k: v for k, v in mc.items() if k != "applied"} == fam.draw_chain(
        2, np.array(plain.truth["peak_rigid_torque_nm"])
    )
    k, b = np.array(mc["gain"]), np.array(mc["offset_nm"])
    peak = np.array(plain.truth["peak_rigid_torque_nm"])
    assert np.all(np.abs(k - 1.0) <= fam.CHAIN_GAIN) and np.any(np.abs(k - 1.0) > 0.005)
    assert np.all(np.abs(b) <= fam.CHAIN_OFFSET_FRACTION * peak) and np.any(b != 0.0)
    assert chained.urdf == plain.urdf
    for a, c in ((plain.train, chained.train), (plain.test, chained.test),
                 (plain.holdout, chained.holdout)):  # fmt: skip
        assert a is not None and c is not None
        # the sensor reads k τ + b, then its own noise: the same noise samples as without
        np.testing.assert_allclose(c.tau_clean, k * a.tau_clean + b, rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(c.tau - c.tau_clean, a.tau - a.tau_clean, atol=1e-9)
        for name in ("q", "dq", "tau_nominal", "tau_rigid", "friction"):
            np.testing.assert_array_equal(getattr(c, name), getattr(a, name))


def test_test_run_leaves_the_training_envelope_by_the_drawn_share(short_draws) -> None:
    for d in short_draws.values():
        rec = d.truth["outside_envelope"]
        lo, hi = d.train.q.min(axis=0), d.train.q.max(axis=0)
        dlo, dhi = d.train.dq.min(axis=0), d.train.dq.max(axis=0)
        q, dq = d.test.q, d.test.dq
        out = ((q < lo) | (q > hi) | (dq < dlo) | (dq > dhi)).any(axis=1)
        assert out.mean() == pytest.approx(rec["share_measured"])
        assert 0.10 <= rec["target"] <= 0.50
        assert 0.10 - 0.01 <= rec["share_measured"] <= 0.50 + 0.01
        assert abs(rec["share_measured"] - rec["target"]) <= 0.03
        assert 1 <= len(rec["joints"]) <= d.n


def test_friction_is_dissipative(short_draws) -> None:
    rng = np.random.default_rng(2)
    for d in short_draws.values():
        n = d.n
        q = rng.uniform(-np.pi, np.pi, (20000, n))
        dq = rng.normal(0.0, 1.0, (20000, n)) * rng.choice([1e-4, 1e-2, 1.0], (20000, n))
        assert np.all(d.friction.torque(q, dq) * dq >= 0.0)
        for run in (d.train, d.test):
            assert np.all(run.friction * run.dq_true >= 0.0)
        fr = d.truth["friction"]
        fourier = np.abs(fr["sin_kq_nm"]).sum(axis=1) + np.abs(fr["cos_kq_nm"]).sum(axis=1)
        assert np.all(fourier < np.array(fr["coulomb_nm"]))


def test_write_draw_writes_what_analyze_reads(tmp_path, short_draws) -> None:
    d = short_draws[2]
    paths = fam.write_draw(tmp_path / "draw", d)
    names = {p.name for p in paths.values()}
    assert names == {"train.csv", "test.csv", "holdout.csv", "robot.urdf", "truth.json"}
    header = paths["train"].read_text().splitlines()[0].split(",")
    assert header == csv_header(d.n)
    back = read_csv(paths["test"])
    np.testing.assert_allclose(back["tau"], d.test.tau, rtol=1e-11, atol=1e-12)
    np.testing.assert_allclose(back["q"], d.test.q, rtol=1e-11, atol=1e-12)
    truth = json.loads(paths["truth"].read_text())
    assert truth["effects"] == d.truth["effects"]
    clean = np.array(truth["noise_free_torque_nm"]["test"])
    np.testing.assert_allclose(clean, d.test.tau_clean, rtol=1e-9, atol=1e-12)
    # the holdout continues the test run where analyze's file ends
    held = read_csv(paths["holdout"])
    np.testing.assert_allclose(held["tau"], d.holdout.tau, rtol=1e-11, atol=1e-12)
    step = d.test.t[1] - d.test.t[0]
    assert held["t"][0] == pytest.approx(d.test.t[-1] + step)
    assert d.holdout.t.size == pytest.approx(d.test.t.size / 2, abs=2)
    model = pin.buildModelFromXML(paths["urdf"].read_text())
    assert model.nq == d.n and "payload" not in paths["urdf"].read_text()


# --------------------------------------------------------------------------- scoring


def _summary(effects, **extra) -> dict:
    return {"effects": effects, "plain_ls_joints": [], **extra}


def _pred(d: fam.Draw, factor) -> np.ndarray:
    """Predictions on the holdout run whose error is ``factor`` (per joint) × its own noise:
    the after-RMS is then ``factor`` × the floor, exactly."""
    f = np.broadcast_to(np.asarray(factor, dtype=float), (d.n,))
    return d.holdout.tau - f * d.holdout.noise


def test_score_is_computed_from_the_predictions_on_the_raw_holdout() -> None:
    d = fam.draw(1, case="spring", duration_scale=SHORT)
    (spring,) = d.truth["effects"]
    j = spring["joints"][0]
    k = spring["parameters"]["k_nm_per_rad"]
    floor = np.sqrt(np.mean(d.holdout.noise**2, axis=0))
    plain_res = 3.0 * d.holdout.noise  # a plain fit three times the noise
    good = np.full(d.n, 1.5)

    def found(k_value: float, joint: int = j) -> list[dict]:
        return [{"name": "spring", "joints": [joint], "parameters": {"k_nm_per_rad": k_value}}]

    # the summary's own figures are not read: a fabricated rms_after changes nothing
    lie = _summary(found(1.1 * k), rms_after=[0.0] * d.n)
    rec = fam.score(d, lie, _pred(d, good), plain_res)
    assert rec["analyze_rms_after"] == pytest.approx((1.5 * floor).tolist())
    assert rec["floor_nm"] == pytest.approx(floor.tolist())
    assert rec["plain_ls_nm"] == pytest.approx((3.0 * floor).tolist())
    c = rec["criteria"]
    assert c["effect_named_or_absorbed"] and c["named"] and not c["absorbed"]
    assert c["after_within_2x_floor"] and c["never_worse_than_plain_ls"]
    assert c["affected_joints"] == [j]
    # absorbed: nothing accepted, the joint at the floor
    c = fam.score(d, _summary([]), _pred(d, good), plain_res)["criteria"]
    assert c["effect_named_or_absorbed"] and c["absorbed"]
    # main parameter 30 % off, wrong joint, or above 2x the floor
    c = fam.score(d, _summary(found(1.3 * k)), _pred(d, good), plain_res)["criteria"]
    assert not c["effect_named_or_absorbed"]
    other = j % d.n + 1
    c = fam.score(d, _summary(found(k, other)), _pred(d, good), plain_res)["criteria"]
    assert not c["effect_named_or_absorbed"]
    high = good.copy()
    high[j - 1] = 2.5
    c = fam.score(d, _summary([]), _pred(d, high), plain_res)["criteria"]
    assert not c["after_within_2x_floor"] and not c["effect_named_or_absorbed"]
    # worse than plain LS on one joint (not an affected one): only that verdict fails
    worse = good.copy()
    worse[other - 1] = 3.1
    c = fam.score(d, _summary(found(k)), _pred(d, worse), plain_res)["criteria"]
    assert not c["never_worse_than_plain_ls"] and c["effect_named_or_absorbed"]
    # a few declined rows are left out of every figure alike; more than 5 % fail the draw
    few = _pred(d, good)
    few[: int(0.04 * few.shape[0])] = np.nan
    rec = fam.score(d, _summary(found(k)), few, plain_res)
    assert rec["criteria"]["after_within_2x_floor"] and rec["declined_share"] < 0.05
    many = _pred(d, good)
    many[: int(0.06 * many.shape[0]) + 1] = np.nan
    rec = fam.score(d, _summary(found(k)), many, plain_res)
    assert any("declined" in p for p in rec["problems"])
    # analyze or predict failed, or what they wrote is unusable: every verdict fails
    for summary, pred, error in (
        (None, None, "exit 1: Traceback"),
        (_summary("none"), _pred(d, good), None),
        (_summary([]), None, None),
        (_summary([]), _pred(d, good), "predictions unusable: header"),
    ):
        rec = fam.score(d, summary, pred, plain_res, error)
        assert rec["problems"]
        verdicts = [rec["criteria"].get(key) for key, _, _ in fam.ACCEPTANCE]
        assert verdicts.count(False) == 3 and verdicts.count(None) == 1  # effect draw


def test_the_referee_reads_predictions_only_for_the_rows_and_times_predicted(tmp_path) -> None:
    t = np.arange(5) * 0.01
    path = tmp_path / "pred.csv"
    path.write_text("t,tau1,tau2\n" + "".join(f"{v:g},1.5,nan\n" for v in t))
    pred = read_predictions(path, t, 2)
    assert pred.shape == (5, 2) and np.all(pred[:, 0] == 1.5) and np.isnan(pred[:, 1]).all()
    with pytest.raises(ValueError, match="header"):
        read_predictions(path, t, 3)
    with pytest.raises(ValueError, match="values"):
        read_predictions(path, t[:4], 2)
    with pytest.raises(ValueError, match="times"):
        read_predictions(path, t + 0.5, 2)


def test_criteria_null_and_multi_joint_effects() -> None:
    n, floor = 6, [0.1] * 6
    ok = fam.criteria([], n, [], [0.15] * n, floor, [0.3] * n)
    assert ok["null_accepts_nothing"] and ok["after_within_2x_floor"]
    assert ok["affected_joints"] == list(range(1, 7))
    extra = [{"name": "stribeck", "joints": [2], "parameters": {"amplitude_nm": 0.1}}]
    assert not fam.criteria([], n, extra, [0.15] * n, floor, [0.3] * n)["null_accepts_nothing"]
    rates = [-0.01, -0.02]
    thermal = fam._effect(
        "thermal_drift", [2, 5], fam.BETWEEN, "rate_nm_per_s", rate_nm_per_s=rates,
        coulomb_rate_nm_per_s=rates,
    )  # fmt: skip
    per_joint = [
        {"name": "thermal_drift", "joints": [2], "parameters": {"rate_nm_per_s": -0.011}},
        {"name": "thermal_drift", "joints": [5], "parameters": {"rate_nm_per_s": -0.019}},
    ]
    assert fam.criteria([thermal], n, per_joint, [0.15] * n, floor, [0.3] * n)["named"]
    payload = fam._effect("payload", range(1, 7), fam.BETWEEN, "mass_kg", mass_kg=2.0)
    five = [{"name": "payload", "joints": [1, 2, 3, 4, 5], "parameters": {"mass_kg": 2.2}}]
    assert not fam.criteria([payload], n, five, [0.15] * n, floor, [0.3] * n)["named"]
    assert fam.criteria([payload], n, five, [0.15] * n, floor, [0.3] * n, [6])["named"]
    rows = fam.acceptance(
        [
            {"seed": 0, "case": "null", "criteria": ok},
            {"seed": 1, "problems": ["family failed"], "criteria": {}},
        ]
    )
    by = {r["criterion"]: r for r in rows}
    assert by["null_accepts_nothing"]["pass"] and by["null_accepts_nothing"]["draws"] == 1
    assert by["effect_named_or_absorbed"]["failing_seeds"] == [1]
    assert by["never_worse_than_plain_ls"]["share"] == 0.5
