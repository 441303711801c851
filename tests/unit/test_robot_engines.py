"""One description, two engines: pinocchio (URDF) and MuJoCo (MJCF) must describe the same arm."""

from __future__ import annotations

import math
from pathlib import Path

import mujoco
import numpy as np
import pinocchio as pin
import pytest

from control.model.dynamics import LINK_PARAMETER_NAMES, RigidBodyModel
from gateway.errors import ConfigError
from gateway.robot.description import (
    DEFAULT_DESCRIPTION_PATH,
    LinkInertial,
    RobotDescription,
    load_description,
)
from gateway.robot.kinematics import dh_frames, dh_world_T_tool
from gateway.robot.mjcf import TOOL_SITE, to_mjcf
from gateway.robot.urdf import to_urdf

N_CONFIGS = 200


@pytest.fixture(scope="module")
def desc() -> RobotDescription:
    return load_description()


@pytest.fixture(scope="module")
def rbm(desc: RobotDescription) -> RigidBodyModel:
    return RigidBodyModel.from_description(desc)


@pytest.fixture(scope="module")
def mj(desc: RobotDescription) -> tuple[mujoco.MjModel, mujoco.MjData]:
    model = mujoco.MjModel.from_xml_string(to_mjcf(desc))
    return model, mujoco.MjData(model)


@pytest.fixture(scope="module")
def configs(desc: RobotDescription) -> np.ndarray:
    rng = np.random.default_rng(20220630)
    return rng.uniform(desc.lower_rad, desc.upper_rad, size=(N_CONFIGS, desc.n_dof))


def _mj_forward(mj: tuple[mujoco.MjModel, mujoco.MjData], q: np.ndarray, dq: np.ndarray) -> None:
    model, data = mj
    data.qpos[:] = q
    data.qvel[:] = dq
    mujoco.mj_forward(model, data)


def _mj_mass_matrix(mj: tuple[mujoco.MjModel, mujoco.MjData]) -> np.ndarray:
    model, data = mj
    m = np.zeros((model.nv, model.nv))
    mujoco.mj_fullM(model, data, m)
    return m


# --- the description ------------------------------------------------------------------------


def test_default_description_reads_table_i_as_standard_dh_in_si_units(desc: RobotDescription):
    assert desc.joint_names == ("j1", "j2", "j3", "j4", "j5", "j6")
    assert [j.a_m for j in desc.joints] == pytest.approx([0.002402, 0.900073, 1.1008, 0, 0, 0])
    assert [j.d_m for j in desc.joints] == pytest.approx([0.769, 0.001177, 0, 0, 0.112981, 0.0768])
    assert np.degrees([j.alpha_rad for j in desc.joints]) == pytest.approx([90, 0, 0, 90, 90, 0])
    assert np.degrees([j.theta_offset_rad for j in desc.joints]) == pytest.approx(
        [0, 90.382, -88.093, 0.191, 89.084, 0]
    )
    assert np.degrees(desc.lower_rad) == pytest.approx([-120, -70, -45, -360, -360, -360])
    assert np.degrees(desc.upper_rad) == pytest.approx([120, 70, 60, 360, 360, 360])
    assert desc.drive_gains_nm_per_a == pytest.approx([46.21, 66.18, 39.0, 11.15, 11.15, 5.58])


def test_zero_pose_has_upper_arm_upright_and_forearm_forward(desc: RobotDescription):
    frames = dh_frames(desc, np.zeros(6))
    shoulder, elbow, wrist = (frames[k][:3, 3] for k in (1, 2, 3))
    upper_arm = (elbow - shoulder) / np.linalg.norm(elbow - shoulder)
    forearm = (wrist - elbow) / np.linalg.norm(wrist - elbow)
    assert upper_arm[2] > math.cos(math.radians(1.0))  # within 1° of vertical
    assert forearm[0] > math.cos(math.radians(3.0))  # within 3° of horizontal, forward (+x)


def test_joints_two_to_four_are_parallel_and_wrist_axes_distinct(desc: RobotDescription):
    q = np.array([0.3, -0.2, 0.4, 0.5, -0.7, 0.2])
    frames = dh_frames(desc, q)
    z = [f[:3, 2] for f in frames]  # joint i+1 turns about z_i
    assert abs(z[1] @ z[2]) == pytest.approx(1.0)
    assert abs(z[1] @ z[3]) == pytest.approx(1.0)
    assert abs(z[4] @ z[5]) < 0.99  # joints 5 and 6 do not share an axis (standard DH reading)


def test_every_link_inertia_is_physically_valid(desc: RobotDescription):
    for link in desc.links:
        moments = np.linalg.eigvalsh(link.inertia_kgm2)
        assert moments[0] > 0
        assert moments[2] <= moments[0] + moments[1]


def _write_modified(tmp_path: Path, old: str, new: str) -> Path:
    text = DEFAULT_DESCRIPTION_PATH.read_text()
    assert old in text, old
    path = tmp_path / "bad.toml"
    path.write_text(text.replace(old, new, 1))
    return path


@pytest.mark.parametrize(
    ("old", "new", "field"),
    [
        ("mass_kg = 60.0 ", "mass_kg = -60.0 ", "mass_kg"),
        ("lower_deg = -70.0 ", "lower_deg = 80.0 ", "lower_deg"),
        ("gear_ratio = 153.0 ", "gear_ratio = 0.0 ", "gear_ratio"),
        ("ixx_kgm2 = 13.1 ", "ixx_kgm2 = 100.0 ", "ixx_kgm2"),
        ('kind = "j3_lever"', 'kind = "j3_screw"', "kind"),
        ("d_mm = 769.0 ", "d_m = 0.769 ", "d_m"),
        ("drive_gain_nm_per_a = 5.58 ", 'drive_gain_nm_per_a = "5.58" ', "drive_gain_nm_per_a"),
        ("position_in_link6_m = [0.0, 0.0, 0.15]", "position_in_link6_m = [0.15]", "position"),
    ],
)
def test_bad_description_is_refused_naming_the_field(
    tmp_path: Path, old: str, new: str, field: str
):
    path = _write_modified(tmp_path, old, new)
    with pytest.raises(ConfigError, match=field) as info:
        load_description(path)
    assert str(path) in str(info.value)


def test_link_inertial_refuses_tensor_breaking_the_triangle_inequality():
    with pytest.raises(ConfigError, match="triangle"):
        LinkInertial(1.0, (0.0, 0.0, 0.0), 1.0, 0.0, 0.0, 1.0, 0.0, 3.0)


# --- the engines ----------------------------------------------------------------------------


def test_tool_pose_agrees_between_pinocchio_mujoco_and_plain_dh(desc, rbm, mj, configs):
    model, data = mj
    site = model.site(TOOL_SITE).id
    for q in configs:
        _mj_forward(mj, q, np.zeros(6))
        world_T_tool = rbm.world_T_tool(q)
        np.testing.assert_allclose(data.site_xpos[site], world_T_tool[:3, 3], rtol=0, atol=1e-9)
        np.testing.assert_allclose(
            data.site_xmat[site].reshape(3, 3), world_T_tool[:3, :3], rtol=0, atol=1e-9
        )
        np.testing.assert_allclose(dh_world_T_tool(desc, q), world_T_tool, rtol=0, atol=1e-9)


def test_gravity_torque_agrees_between_engines(rbm, mj, configs):
    data = mj[1]
    for q in configs:
        _mj_forward(mj, q, np.zeros(6))
        g = rbm.gravity_nm(q)
        np.testing.assert_allclose(data.qfrc_bias, g, rtol=0, atol=1e-6 * np.abs(g).max())


def test_bias_torque_with_velocity_agrees_between_engines(rbm, mj, configs):
    rng = np.random.default_rng(7)
    for q in configs[:50]:
        dq = rng.uniform(-1.0, 1.0, 6)
        _mj_forward(mj, q, dq)
        expected = rbm.rnea_nm(q, dq, np.zeros(6))  # C(q, dq) dq + g(q)
        np.testing.assert_allclose(mj[1].qfrc_bias, expected, rtol=0, atol=1e-9 * 1e3)


def test_mass_matrix_agrees_once_mujoco_armature_is_removed(desc, rbm, mj, configs):
    armature = np.diag(desc.armature_kgm2)
    for q in configs:
        _mj_forward(mj, q, np.zeros(6))
        m_mj = _mj_mass_matrix(mj)
        np.testing.assert_allclose(m_mj - armature, rbm.mass_matrix(q), rtol=0, atol=1e-9)
        np.testing.assert_allclose(m_mj, rbm.mass_matrix(q, include_armature=True), atol=1e-9)


def test_tool_jacobian_agrees_with_mujoco_site_jacobian(rbm, mj, configs):
    model, data = mj
    site = model.site(TOOL_SITE).id
    for q in configs[:50]:
        _mj_forward(mj, q, np.zeros(6))
        jacp, jacr = np.zeros((3, 6)), np.zeros((3, 6))
        mujoco.mj_jacSite(model, data, jacp, jacr, site)
        np.testing.assert_allclose(rbm.tool_jacobian_world(q), np.vstack([jacp, jacr]), atol=1e-9)


def test_tool_jacobian_has_full_rank_at_a_generic_configuration(rbm):
    q = np.radians([20.0, -15.0, 30.0, 40.0, -60.0, 10.0])
    singular_values = np.linalg.svd(rbm.tool_jacobian_world(q), compute_uv=False)
    assert np.linalg.matrix_rank(rbm.tool_jacobian_world(q)) == 6
    assert singular_values[-1] > 1e-2


def test_regressor_times_model_parameters_is_inverse_dynamics(rbm):
    rng = np.random.default_rng(3)
    params = rbm.parameters()
    assert params.shape == (10 * 6,)
    assert len(LINK_PARAMETER_NAMES) == 10
    for _ in range(20):
        q, dq, ddq = rng.normal(size=(3, 6))
        y = rbm.regressor(q, dq, ddq)
        assert y.shape == (6, 60)
        np.testing.assert_allclose(y @ params, rbm.rnea_nm(q, dq, ddq), atol=1e-9)


def test_link_masses_reach_both_engines_unchanged(desc, rbm, mj):
    masses = [link.mass_kg for link in desc.links]
    assert rbm.parameters()[0::10] == pytest.approx(masses)
    model = mj[0]
    assert [model.body(f"link{i + 1}").mass[0] for i in range(6)] == pytest.approx(masses)


def test_mujoco_joints_are_limited_undamped_with_armature(desc, mj):
    model = mj[0]
    assert model.opt.integrator == mujoco.mjtIntegrator.mjINT_IMPLICITFAST
    assert model.opt.timestep == pytest.approx(0.0005)
    assert model.opt.gravity == pytest.approx(desc.gravity_m_s2)
    assert [model.joint(i).name for i in range(model.njnt)] == list(desc.joint_names)
    assert np.all(model.jnt_limited == 1)
    np.testing.assert_allclose(model.jnt_range[:, 0], desc.lower_rad)
    np.testing.assert_allclose(model.jnt_range[:, 1], desc.upper_rad)
    np.testing.assert_allclose(model.dof_armature, desc.armature_kgm2)
    assert np.all(model.dof_damping == 0.0)
    assert np.all(model.dof_frictionloss == 0.0)
    assert np.all(model.geom_contype == 0)
    assert np.all(model.geom_conaffinity == 0)


def test_pinocchio_joint_limits_and_order_follow_the_description(desc):
    model = pin.buildModelFromXML(to_urdf(desc))
    assert tuple(model.names[1:]) == desc.joint_names
    np.testing.assert_allclose(model.lowerPositionLimit, desc.lower_rad)
    np.testing.assert_allclose(model.upperPositionLimit, desc.upper_rad)
    assert model.existFrame("tool")
