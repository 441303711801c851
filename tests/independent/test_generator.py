"""The independent data generator: arm, excitation, torque, effects, files, plain-LS baseline.

No test here runs ``leadthrough analyze``; ``python -m tests.independent.table`` does.
"""

from __future__ import annotations

import dataclasses
import json
import math

import mujoco
import numpy as np
import pinocchio as pin
import pytest

from . import generator as g
from .arm import ARM, PAYLOAD, ArmSpec, mjcf, urdf
from .baseline import plain_ls, run_arrays
from .table import compare, describe_effect


def _mujoco_inverse(xml: str, q: np.ndarray, dq: np.ndarray, ddq: np.ndarray) -> np.ndarray:
    model = mujoco.MjModel.from_xml_string(xml)
    data = mujoco.MjData(model)
    out = np.empty_like(q)
    for i in range(q.shape[0]):
        data.qpos[:], data.qvel[:], data.qacc[:] = q[i], dq[i], ddq[i]
        mujoco.mj_inverse(model, data)
        out[i] = data.qfrc_inverse
    return out


def _rms(x: np.ndarray) -> np.ndarray:
    return np.sqrt(np.mean(x**2, axis=0))


# --------------------------------------------------------------------------- arm


def test_urdf_loads_in_pinocchio_with_six_revolute_joints() -> None:
    model = pin.buildModelFromXML(urdf())
    assert (model.nq, model.nv, model.njoints) == (6, 6, 7)
    assert list(model.names)[1:] == ["a1", "a2", "a3", "a4", "a5", "a6"]
    assert [model.joints[i].shortname() for i in range(1, 7)] == [
        "JointModelRZ",
        "JointModelRY",
        "JointModelRY",
        "JointModelRX",
        "JointModelRY",
        "JointModelRX",
    ]
    np.testing.assert_allclose(model.lowerPositionLimit, ARM.lower)
    np.testing.assert_allclose(model.upperPositionLimit, ARM.upper)
    np.testing.assert_allclose(model.velocityLimit, ARM.velocity_limit)
    masses = [model.inertias[i].mass for i in range(1, 7)]
    np.testing.assert_allclose(masses, [j.body.mass for j in ARM.joints])
    assert all(15.0 <= m <= 150.0 for m in masses)
    with_payload = pin.buildModelFromXML(urdf(ARM, PAYLOAD))
    assert with_payload.inertias[6].mass == pytest.approx(ARM.joints[5].body.mass + 6.0)
    # wrist axes 4, 5, 6 meet in one point (spherical wrist); 2 and 3 parallel
    data = model.createData()
    pin.forwardKinematics(model, data, np.array([0.3, -0.4, 0.7, 0.2, -0.5, 0.9]))
    np.testing.assert_allclose(data.oMi[5].translation, data.oMi[6].translation, atol=1e-12)
    axis4 = data.oMi[4].rotation[:, 0]
    np.testing.assert_allclose(
        np.cross(data.oMi[5].translation - data.oMi[4].translation, axis4), 0.0, atol=1e-12
    )
    np.testing.assert_allclose(data.oMi[2].rotation[:, 1], data.oMi[3].rotation[:, 1], atol=1e-12)


def test_inertia_tensors_are_physically_consistent_and_parsed_exactly() -> None:
    model = pin.buildModelFromXML(urdf())
    for i, joint in enumerate(ARM.joints, start=1):
        inertia = joint.body.inertia
        np.testing.assert_allclose(inertia, inertia.T, atol=0)
        lam = np.sort(np.linalg.eigvalsh(inertia))
        assert lam[0] > 0.0
        assert lam[0] + lam[1] >= lam[2] * (1 + 1e-12)  # triangle inequality (strict box)
        off = np.abs(inertia[np.triu_indices(3, 1)])
        assert np.all(off > 1e-6 * lam[2]), f"{joint.name}: tensor not full"
        np.testing.assert_allclose(model.inertias[i].inertia, inertia, rtol=1e-12, atol=1e-15)
        np.testing.assert_allclose(model.inertias[i].lever, joint.body.com, atol=1e-15)


# --------------------------------------------------------------------------- torque


@pytest.mark.parametrize("case", ["null", "payload_both"])
def test_noise_free_torque_matches_mujoco_inverse_dynamics(case: str) -> None:
    """Rigid part of the generated torque (clean minus eq. 15 friction) against MuJoCo's
    mj_inverse on an MJCF built from the arm spec (not from the URDF)."""
    train, _, _ = g.make_case(case)
    idx = np.arange(0, train.t.size, 25)
    q, dq, ddq = train.q_true[idx], train.dq[idx], train.ddq[idx]
    rigid = train.tau_clean[idx] - g.friction_torque(g.nominal_friction(), q, dq)
    payload = PAYLOAD if case == "payload_both" else None
    expected = _mujoco_inverse(mjcf(ARM, payload), q, dq, ddq)
    np.testing.assert_allclose(rigid, expected, rtol=0, atol=1e-8 * np.max(np.abs(expected)))
    if payload is None:
        np.testing.assert_allclose(train.tau_rigid[idx], rigid, rtol=0, atol=1e-9)


def test_mujoco_check_is_sensitive_to_products_of_inertia() -> None:
    """Turning one link's box (same mass, COM and principal moments) changes the torque well
    beyond the tolerance above: the check would catch a mis-written inertia tensor."""
    train, _, _ = g.make_case("null")
    idx = np.arange(0, train.t.size, 250)
    j3 = ARM.joints[2]
    turned = dataclasses.replace(j3, body=dataclasses.replace(j3.body, box_rpy=(0.0, 0.0, 0.0)))
    arm2 = ArmSpec(
        ARM.name, ARM.base, (*ARM.joints[:2], turned, *ARM.joints[3:]), ARM.flange_offset
    )
    other = _mujoco_inverse(mjcf(arm2), train.q_true[idx], train.dq[idx], train.ddq[idx])
    assert np.max(np.abs(other - train.tau_rigid[idx])) > 1e-3


def test_friction_is_eq15_as_written_and_dissipative() -> None:
    fr = g.nominal_friction()
    q = np.array([[0.3, -0.7, 1.1, -2.0, 0.4, 5.0]])
    for v in (-1.3, -0.02, -1e-3, 0.0, 1e-3, 0.02, 0.9):
        dq = np.full((1, 6), v)
        got = g.friction_torque(fr, q, dq)[0]
        for j in range(6):
            tc, ts, tv, qe = fr.coulomb[j], fr.static[j], fr.viscous[j], fr.q_e[j]
            sgn = math.tanh(v / 1e-4)
            pos = sum(
                fr.a[j, k] * math.sin((k + 1) * q[0, j]) + fr.b[j, k] * math.cos((k + 1) * q[0, j])
                for k in range(3)
            )
            want = (tc + (ts - tc) * math.exp(-((v / qe) ** 2))) * sgn + tv * v + pos
            assert got[j] == pytest.approx(want, rel=1e-12, abs=1e-12)
            assert (want - pos) * v >= 0.0  # velocity part opposes motion
    peak = g.nominal_peak_torque()
    assert np.all(fr.static > fr.coulomb)
    assert np.all((fr.coulomb > 0.01 * peak) & (fr.coulomb < 0.1 * peak))
    assert np.all((fr.q_e >= 0.01) & (fr.q_e <= 0.05))


def test_measurement_noise_and_quantisation() -> None:
    train, test, _ = g.make_case("null")
    step = ARM.encoder_step
    for run in (train, test):
        counts = run.q / step
        np.testing.assert_allclose(counts, np.round(counts), atol=1e-6)
        assert np.all(np.abs(run.q - run.q_true) <= step / 2 * (1 + 1e-9))
        noise = run.tau - run.tau_clean
        np.testing.assert_allclose(_rms(noise), run.noise_std, rtol=0.05)
        assert np.all(np.abs(noise.mean(axis=0)) < 0.05 * run.noise_std)
    np.testing.assert_array_equal(
        train.noise_std, np.maximum(0.005 * g.nominal_peak_torque(), 0.05)
    )


# --------------------------------------------------------------------------- trajectories


def test_train_and_test_trajectories_differ_and_stay_within_80_percent() -> None:
    train, test, _ = g.make_case("null")
    assert train.t.size == 50 * 250 and test.t.size == 25 * 250
    np.testing.assert_allclose(np.diff(train.t), 1 / 250, rtol=1e-9)
    n = test.t.size
    assert np.min(_rms(train.q_true[:n] - test.q_true)) > 0.1
    for run in (train, test):
        bound = 0.8 * ARM.half_range + ARM.encoder_step
        assert np.all(np.abs(run.q - ARM.centre) <= bound)
        assert np.all(np.abs(run.q_true - ARM.centre) <= 0.8 * ARM.half_range * (1 + 1e-12))
        assert np.all(np.abs(run.dq) <= 0.6 * ARM.velocity_limit * (1 + 1e-12))
        assert np.all(np.ptp(run.q_true, axis=0) > 0.3 * ARM.half_range)  # really excited
        # analytic derivatives agree with central differences of the analytic q
        h = 1 / 250
        dq_fd = (run.q_true[2:] - run.q_true[:-2]) / (2 * h)
        ddq_fd = (run.q_true[2:] - 2 * run.q_true[1:-1] + run.q_true[:-2]) / h**2
        np.testing.assert_allclose(dq_fd, run.dq[1:-1], atol=1e-3 * np.max(np.abs(run.dq)))
        np.testing.assert_allclose(ddq_fd, run.ddq[1:-1], atol=1e-3 * np.max(np.abs(run.ddq)))
    assert not np.array_equal(g.make_case("null", seed=1)[0].tau, train.tau)
    np.testing.assert_array_equal(g.make_case("null")[0].tau, train.tau)  # deterministic


# --------------------------------------------------------------------------- cases


@pytest.mark.parametrize("case", list(g.CASES))
def test_effect_shows_only_on_the_joints_the_truth_names(case: str) -> None:
    train, test, truth = g.make_case(case)
    assert truth["case"] == case
    json.dumps(truth)  # JSON-able
    effects = truth["effects"]
    assert len(effects) == (0 if case == "null" else 1)
    joints = set(effects[0]["joints"]) if effects else set()
    in_train = bool(effects) and effects[0]["appeared"] == "all_along"
    for run, present in ((train, in_train), (test, bool(effects))):
        diff = run.tau_clean - run.tau_nominal
        for j in range(6):
            if present and j + 1 in joints:
                assert _rms(diff[:, j]) >= run.noise_std[j], f"{case} {run.role} joint {j + 1}"
            else:
                assert np.all(diff[:, j] == 0.0), f"{case} {run.role} joint {j + 1}"
        if effects:
            e = effects[0]
            assert e["main_parameter"] in e["parameters"]


def test_case_parameters_are_what_the_torque_contains() -> None:
    train, _, truth = g.make_case("hose_spring")
    p = truth["effects"][0]["parameters"]
    diff = train.tau_clean[:, 3] - train.tau_nominal[:, 3]
    np.testing.assert_allclose(diff, p["k_nm_per_rad"] * (train.q_true[:, 3] - p["q0_rad"]))
    train, _, truth = g.make_case("ripple")
    p = truth["effects"][0]["parameters"]
    diff = train.tau_clean[:, 2] - train.tau_nominal[:, 2]
    want = p["amplitude_nm"] * np.sin(p["cycles_per_rev"] * train.q_true[:, 2] + p["phase_rad"])
    np.testing.assert_allclose(diff, want)
    assert 20 <= p["cycles_per_rev"] <= 40
    train, _, truth = g.make_case("wrist_coupling")
    p = truth["effects"][0]["parameters"]
    diff = train.tau_clean[:, 5] - train.tau_nominal[:, 5]
    np.testing.assert_allclose(diff, p["coefficient"] * train.tau_nominal[:, 4])
    train, _, truth = g.make_case("delay")
    d = truth["effects"][0]["parameters"]["delay_s"]
    assert 0.008 <= d <= 0.012
    # the delayed torque at t is the undelayed torque at t - d (d = 2.5 samples: interpolate)
    k = 1000
    t_back = train.t[k] - d
    lo = int(np.floor(t_back * 250))
    frac = t_back * 250 - lo
    interp = (1 - frac) * train.tau_nominal[lo] + frac * train.tau_nominal[lo + 1]
    np.testing.assert_allclose(train.tau_clean[k], interp, atol=0.02 * np.max(np.abs(interp)))


# --------------------------------------------------------------------------- files


def test_write_case_files_round_trip(tmp_path) -> None:
    paths = g.write_case(tmp_path / "ripple", "ripple")
    train, test, truth = g.make_case("ripple")
    assert {p.name for p in (tmp_path / "ripple").iterdir()} == {
        "train.csv",
        "test.csv",
        "robot.urdf",
        "truth.json",
    }
    header = paths["train"].read_text().splitlines()[0].split(",")
    assert header == [
        "t",
        *(f"q{i}" for i in range(1, 7)),
        *(f"dq{i}" for i in range(1, 7)),
        *(f"tau{i}" for i in range(1, 7)),
    ]
    for key, run in (("train", train), ("test", test)):
        back = g.read_csv(paths[key])
        for name in ("t", "q", "dq", "tau"):
            np.testing.assert_allclose(back[name], getattr(run, name), rtol=1e-11, atol=1e-12)
    assert pin.buildModelFromXML(paths["urdf"].read_text()).nq == 6
    assert "payload" not in paths["urdf"].read_text()
    assert json.loads(paths["truth"].read_text()) == json.loads(json.dumps(truth))


# --------------------------------------------------------------------------- baseline


def test_plain_least_squares_recovers_the_null_case_to_noise() -> None:
    train, test, _ = g.make_case("null")
    result = plain_ls(urdf(), run_arrays(train), run_arrays(test))
    ratio = result.rms_test / test.noise_std
    assert np.all(ratio <= 1.5), ratio
    assert np.all(ratio >= 0.9), ratio  # judged against the noisy files, so not below noise
    np.testing.assert_allclose(result.coulomb, g.nominal_friction().coulomb, rtol=0.2)
    # a payload present in both runs is only a change of link 6's parameters: the same fit
    # absorbs it (the truth marks it not separable)
    train_p, test_p, truth = g.make_case("payload_both")
    assert truth["effects"][0]["separable_from_rigid_model"] is False
    with_payload = plain_ls(urdf(), run_arrays(train_p), run_arrays(test_p))
    np.testing.assert_allclose(with_payload.rms_test, result.rms_test, rtol=0.01)


def test_table_comparison_tolerates_unexpected_analyze_output() -> None:
    truth = [
        {
            "name": "wrist_coupling",
            "joints": [6],
            "appeared": "all_along",
            "main_parameter": "coefficient",
            "parameters": {"from_joint": 5, "coefficient": 0.1},
        }
    ]
    found = [
        "garbage",
        {"name": "wrist_coupling", "joints": [6], "parameters": {"from_joint": 4}},
        {
            "name": "wrist_coupling",
            "joints": [6],
            "parameters": {"from_joint": 5, "coefficient": 0.09},
        },
        {"name": "brand_new_effect", "joints": "all", "parameters": None},
        {"joints": [1]},
    ]
    result = compare(truth, found)
    assert result["truth"][0]["verdict"] == "found"
    assert result["truth"][0]["analyze_index"] == 2
    assert result["extra"] == [0, 1, 3, 4]
    for e in (*found, *truth):
        assert isinstance(describe_effect(e), str)
    assert compare(truth, [])["truth"][0]["verdict"] == "missed"
