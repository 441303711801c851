"""Base parameters and regressor of any URDF (GR630ST from its description, Panda from DH)."""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest

from control.identification.dh_urdf import PANDA_DH_ROWS, DHRow, urdf_from_dh
from control.identification.lsq import BlockLS, contiguous_folds
from control.identification.rigid import RobotRegressor
from control.identification.synthetic import GR630ST_MAX_SPEED_RAD_S, MultiSine
from gateway.errors import ConfigError
from gateway.robot.description import load_description
from gateway.robot.kinematics import dh_frames
from gateway.robot.urdf import to_urdf

# Link base parameters (36 GR630ST, 43 Panda as in Gaz et al.) plus the separable armatures
# (joint 1's merges with link 1's Izz; the QR finds which).
EXPECTED_BASE = {"gr630st": 40, "panda": 48}


@pytest.fixture(scope="module")
def gr630st() -> RobotRegressor:
    return RobotRegressor(to_urdf(load_description()))


@pytest.fixture(scope="module")
def panda() -> RobotRegressor:
    return RobotRegressor(urdf_from_dh(PANDA_DH_ROWS, "modified", "panda"))


@pytest.fixture(params=["gr630st", "panda"])
def robot(request, gr630st, panda) -> tuple[str, RobotRegressor]:
    return request.param, {"gr630st": gr630st, "panda": panda}[request.param]


def _stacked(reg: RobotRegressor, n_samples: int, seed: int) -> np.ndarray:
    q, dq, ddq = reg.random_samples(n_samples, np.random.default_rng(seed))
    return np.vstack([reg.regressor(a, b, c) for a, b, c in zip(q, dq, ddq, strict=True)])


def test_base_parameter_count_matches_known_and_svd_rank(robot):
    name, reg = robot
    assert reg.base.n_base == EXPECTED_BASE[name]
    assert np.linalg.matrix_rank(_stacked(reg, 300, seed=7)) == reg.base.n_base


def test_regressor_times_full_parameters_is_rnea(robot):
    _, reg = robot
    rng = np.random.default_rng(11)
    q, dq, ddq = reg.random_samples(20, rng)
    theta = reg.parameters()
    y = reg.regressor_columns(q, dq, ddq, np.arange(11 * reg.n))  # (n, T, 11 n)
    np.testing.assert_allclose(np.einsum("jtk,k->tj", y, theta), reg.rnea(q, dq, ddq), atol=1e-9)


def test_base_regressor_times_base_parameters_is_rnea(robot):
    _, reg = robot
    rng = np.random.default_rng(12)
    q, dq, ddq = reg.random_samples(30, rng)
    beta = reg.base.base_values(reg.parameters())
    tau = np.einsum("jtb,b->tj", reg.base_regressor(q, dq, ddq), beta)
    np.testing.assert_allclose(tau, reg.rnea(q, dq, ddq), atol=1e-8)


def test_base_parameters_are_documented_combinations(gr630st):
    definitions = gr630st.base.definitions()
    assert len(definitions) == gr630st.base.n_base
    assert all(
        d.startswith(gr630st.base.names[i])
        for d, i in zip(definitions, gr630st.base.independent, strict=True)
    )


def test_base_model_reproduces_rnea_exactly_on_noiseless_trajectory(gr630st):
    """Fit β by least squares on a noiseless multi-sine: the base model reproduces the URDF's
    inverse dynamics, on the fitted samples and on another trajectory."""
    desc = load_description()
    reg = gr630st

    def samples(seed: int, base_hz: float) -> tuple[np.ndarray, ...]:
        traj = MultiSine.random(
            desc.lower_rad,
            desc.upper_rad,
            np.random.default_rng(seed),
            GR630ST_MAX_SPEED_RAD_S,
            base_hz=base_hz,
        )
        return traj(np.linspace(0.0, 40.0, 1500))

    q, dq, ddq = samples(1, 0.05)
    tau = reg.rnea(q, dq, ddq)
    y = reg.base_regressor(q, dq, ddq)
    ls = BlockLS(tau, contiguous_folds(tau.shape[0], 1))
    ls.add("rigid", {j: y[j] for j in range(reg.n)})
    beta = ls.solve(["rigid"], np.ones(reg.n), rcond=1e-9).coef["rigid"]
    scale = np.abs(tau).max(axis=0)
    np.testing.assert_allclose(np.einsum("jtb,b->tj", y, beta), tau, atol=1e-7 * scale.max())
    q2, dq2, ddq2 = samples(2, 0.07)
    tau2 = reg.rnea(q2, dq2, ddq2)
    pred2 = np.einsum("jtb,b->tj", reg.base_regressor(q2, dq2, ddq2), beta)
    np.testing.assert_allclose(pred2, tau2, atol=1e-6 * scale.max())
    np.testing.assert_allclose(beta, reg.base.base_values(reg.parameters()), rtol=1e-5, atol=1e-6)


def _modified_dh(a: float, alpha: float, d: float, theta: float) -> np.ndarray:
    ca, sa, ct, st = np.cos(alpha), np.sin(alpha), np.cos(theta), np.sin(theta)
    return np.array(
        [
            [ct, -st, 0, a],
            [st * ca, ct * ca, -sa, -sa * d],
            [st * sa, ct * sa, ca, ca * d],
            [0, 0, 0, 1],
        ]
    )


def test_modified_dh_urdf_matches_craig_forward_kinematics(panda):
    q = np.random.default_rng(2).uniform(-1, 1, panda.n)
    world_T_flange = np.eye(4)
    for row, qi in zip(PANDA_DH_ROWS[:7], q, strict=True):
        world_T_flange = world_T_flange @ _modified_dh(row.a_m, row.alpha_rad, row.d_m, qi)
    world_T_flange = world_T_flange @ _modified_dh(0.0, 0.0, 0.107, 0.0)
    pin.framesForwardKinematics(panda.model, panda.data, q)
    got = panda.data.oMf[panda.model.getFrameId("frame1")].homogeneous
    np.testing.assert_allclose(got, world_T_flange, atol=1e-12)


def test_standard_dh_urdf_matches_the_description_chain():
    desc = load_description()
    rows = [
        DHRow(j.a_m, j.alpha_rad, j.d_m, j.theta_offset_rad, j.lower_rad, j.upper_rad)
        for j in desc.joints
    ]
    reg = RobotRegressor(urdf_from_dh(rows, "standard", "gr"))
    assert reg.base.n_base == EXPECTED_BASE["gr630st"]
    q = np.random.default_rng(3).uniform(-1, 1, reg.n)
    pin.framesForwardKinematics(reg.model, reg.data, q)
    got = reg.data.oMf[reg.model.getFrameId("gr_dh_end")].homogeneous
    np.testing.assert_allclose(got, dh_frames(desc, q)[-1], atol=1e-12)


def test_continuous_joints_are_refused():
    urdf = urdf_from_dh(PANDA_DH_ROWS[:2], "modified", "two").replace(
        'type="revolute"', 'type="continuous"', 1
    )
    with pytest.raises(ConfigError, match="1-DOF"):
        RobotRegressor(urdf)


def test_unknown_dh_convention_is_a_config_error():
    with pytest.raises(ConfigError, match="convention"):
        urdf_from_dh(PANDA_DH_ROWS, "craig")


def test_regressor_columns_match_per_sample_regressor_and_run_in_threads(robot):
    """Chunked columns equal the per-sample regressor, across chunk edges, and two threads
    computing them at once (the cutoff search does) do not share pinocchio's Data."""
    from concurrent.futures import ThreadPoolExecutor

    from control.identification import rigid

    _, reg = robot
    rng = np.random.default_rng(5)
    t = rigid.REGRESSOR_CHUNK + 37
    q, dq, ddq = (rng.uniform(-1.0, 1.0, (t, reg.n)) for _ in range(3))
    cols = np.concatenate([reg.base.independent, reg.payload_indices]).astype(int)
    ref = np.stack([reg.regressor(q[k], dq[k], ddq[k])[:, cols] for k in range(t)], axis=1)
    with ThreadPoolExecutor(max_workers=2) as pool:
        runs = list(pool.map(lambda _: reg.regressor_columns(q, dq, ddq, cols), range(4)))
    for out in runs:
        assert np.array_equal(out, ref)
