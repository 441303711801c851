"""Constrained guiding (control/rt/src/law/guide.rs) in the zero-moment law's cycle: the
fixture's torque is the task-space spring's on the tool, as pinocchio's Jacobian of the same
nominal rigid body gives it; it takes its reference where the arm is when the mode applies; a
free guide adds nothing; a name that is not a guide is refused."""

from __future__ import annotations

import dataclasses

import numpy as np
import pinocchio as pin
import pytest
from example_cell import example_cell

from control.cell_config import load_control_config
from control.declared_model import DeclaredModel
from control.model.dynamics import RigidBodyModel
from control.zero_moment_law import ZeroMomentController
from gateway.message_factories import make_joint_state
from gateway.messages import ControllerState

Q0 = np.array([0.2, -0.3, 0.4, 0.1, -0.5, 0.3])
P_BAR = (6.0, 4.0)


@pytest.fixture(scope="module")
def cfg(tmp_path_factory):
    cfg = load_control_config(example_cell(tmp_path_factory.mktemp("cell")))[0]
    # the law alone, engaging on the first state: no speed limit, adaptation, inertia share
    return dataclasses.replace(
        cfg, engage_rest_states=0, max_tool_speed_m_s=0.0, omega_adaptation_per_s=0.0,
        inertia_compensation=0.0, stiction_dither=0.0, command_delay_cycles=0,
    )  # fmt: skip


@pytest.fixture(scope="module")
def model(cfg) -> DeclaredModel:
    return DeclaredModel.load(cfg.model)


def _state(cycle, q):
    zero = np.zeros(len(q))
    return make_joint_state(cycle, 1.0, ControllerState.EXTERNAL, 2, q, zero, zero, q, zero,
                            0.004)  # fmt: skip


def _fixture_by_pinocchio(model, cfg, guide, q0, q):
    """J_vᵀ F + J_ωᵀ M of the module docstring of law/guide.rs at rest, on pinocchio's
    kinematics of the datasheet's rigid body (the tool frame, world-aligned)."""
    rigid = RigidBodyModel.from_description(model.desc)
    m, d, frame = rigid.model, rigid.model.createData(), rigid.tool_frame_id

    def pose(qq):
        pin.framesForwardKinematics(m, d, qq)
        placement = d.oMf[frame]
        return placement.translation.copy(), placement.rotation.copy()

    p0, r0 = pose(q0)
    p, r = pose(q)
    jac = pin.computeFrameJacobian(m, d, q, frame, pin.LOCAL_WORLD_ALIGNED)
    moment = -cfg.guide_rot_stiffness_nm_per_rad * pin.log3(r @ r0.T)
    if guide == "plane":
        n = r0[:, 2]
        proj = np.outer(n, n)
    elif guide == "axis":
        a = r0[:, "xyz".index(cfg.guide_axis)]
        proj = np.eye(3) - np.outer(a, a)
    else:
        proj = np.zeros((3, 3))
    force = -cfg.guide_stiffness_n_per_m * proj @ (p - p0)
    return jac[:3].T @ force + jac[3:].T @ moment


@pytest.mark.parametrize("guide", ["orientation-locked", "plane", "axis"])
def test_the_fixture_is_the_task_space_spring_on_the_tool(cfg, model, guide):
    locked = ZeroMomentController(dataclasses.replace(cfg, guide=guide), model)
    free = ZeroMomentController(cfg, model)
    assert locked.guide == guide and free.guide == "free"
    for c in (locked, free):
        c.answer(_state(1, Q0), P_BAR)
    # at its reference the fixture adds nothing
    np.testing.assert_allclose(locked.tau_d_nm, free.tau_d_nm, rtol=1e-12, atol=1e-9)
    rng = np.random.default_rng(11)
    for cycle in range(2, 12):
        q = Q0 + rng.normal(0.0, 0.03, 6)
        for c in (locked, free):
            c.answer(_state(cycle, q), P_BAR)
        added = locked.tau_d_nm - free.tau_d_nm
        want = _fixture_by_pinocchio(model, locked.cfg, guide, Q0, q)
        np.testing.assert_allclose(added, want, rtol=1e-9, atol=1e-6)
        off_m, turned_rad = locked.guide_deviation()
        assert turned_rad > 0.0 and (off_m > 0.0) == (guide != "orientation-locked")
    assert np.abs(free._cycle.guide_torque_nm).max() == 0.0


def test_a_wrist_turned_by_the_hand_is_turned_back(cfg, model):
    ctl = ZeroMomentController(dataclasses.replace(cfg, guide="orientation-locked"), model)
    ctl.answer(_state(1, Q0), P_BAR)
    for j in (3, 4, 5):
        for turn in (0.01, -0.01):
            q = Q0.copy()
            q[j] += turn
            ctl.answer(_state(2, q), P_BAR)
            fixture = np.array(ctl._cycle.guide_torque_nm)
            assert fixture[j] * turn < 0.0, (j, turn, fixture)
            assert ctl.guide_deviation()[1] == pytest.approx(abs(turn), rel=1e-9)


def test_a_new_guide_takes_its_reference_where_the_arm_is_then(cfg, model):
    ctl = ZeroMomentController(cfg, model)
    ctl.answer(_state(1, Q0), P_BAR)
    q = Q0 + 0.05
    ctl.guide = "orientation-locked"
    ctl.answer(_state(2, q), P_BAR)
    np.testing.assert_allclose(ctl._cycle.guide_torque_nm, 0.0, atol=1e-9)
    ctl.answer(_state(3, Q0), P_BAR)  # back where teaching engaged: now off the reference
    assert np.abs(ctl._cycle.guide_torque_nm).max() > 1.0
    ctl.disengage()  # a new engagement takes it again
    ctl.answer(_state(10, Q0), P_BAR)
    np.testing.assert_allclose(ctl._cycle.guide_torque_nm, 0.0, atol=1e-9)


def test_a_name_that_is_no_guide_is_refused_and_the_guide_stays(cfg, model):
    ctl = ZeroMomentController(dataclasses.replace(cfg, guide="plane"), model)
    with pytest.raises(ValueError, match="orientation-locked"):
        ctl.guide = "sideways"
    assert ctl.guide == "plane"


def test_the_admittances_reference_holds_a_locked_orientation_against_a_wrist_push(cfg, model):
    """The admittance (its probe and stick zone off: the law alone) holds the guide on its
    reference (law/guide.rs Guide::constraint, law/admittance/constraint.rs). An arm that
    follows its reference exactly, its current carrying the model's torque less a steady
    10 N·m hand on J5: free, the tool turns on and on; locked, it does not turn (what the
    reference's drift correction leaves, 1e-4 rad at most: test_admittance_guide.py), where
    the spring this law used before gave way by up to 10 / K_r rad (4 mrad); pinocchio's
    kinematics judge the turn."""
    from control.admittance_law import AdmittanceController

    # no start-up dither: the fake drives carry the model's torque only (test_admittance.py)
    base = dataclasses.replace(cfg, strategy="admittance", admittance_probe_speed_rad_s=0.0,
                               admittance_stick_zone=0.0, admittance_dither=0.0)  # fmt: skip
    k_nm_per_a = np.array([j.drive_gain_nm_per_a for j in model.desc.joints])
    push = np.array([0.0, 0.0, 0.0, 0.0, 10.0, 0.0])
    rigid = RigidBodyModel.from_description(model.desc)
    m, d, frame = rigid.model, rigid.model.createData(), rigid.tool_frame_id

    def rotation(q):
        pin.framesForwardKinematics(m, d, q)
        return d.oMf[frame].rotation.copy()

    r0 = rotation(Q0)
    turned = {}
    for guide in ("free", "orientation-locked"):
        ctl = AdmittanceController(dataclasses.replace(base, guide=guide), model)
        q, dq, ddq = Q0.copy(), np.zeros(6), np.zeros(6)
        angles = []
        for k in range(1, 800):  # 3.2 s, the hand from 0.2 s on
            hand = push if k >= 50 else 0.0
            current = (ctl.model_torque(q, dq, ddq, P_BAR) - hand) / k_nm_per_a
            ctl.answer(_current_state(k, q, dq, current), P_BAR)
            adm = ctl.admittance
            q, dq, ddq = np.array(adm.q_r), np.array(adm.dq_r), np.array(adm.ddq_r)
            angles.append(np.linalg.norm(pin.log3(rotation(q) @ r0.T)))
        turned[guide] = np.array(angles)
    spring = 10.0 / cfg.guide_rot_stiffness_nm_per_rad
    assert turned["free"][-1] > 50 * spring  # on and on
    assert turned["orientation-locked"].max() < 1e-4


def _current_state(cycle, q, dq, current):
    return make_joint_state(cycle, 0.004 * cycle, ControllerState.EXTERNAL, 0, q, dq, current,
                            q, np.zeros(len(q)), 0.004)  # fmt: skip
