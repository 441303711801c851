"""Constrained guiding in the sensorless admittance (control/rt/src/law/guide.rs
``Guide::constraint``, control/rt/src/law/admittance/constraint.rs): a hand that pushes the
tool and twists it moves the reference's tool point as the guide allows and does not turn
it; free, the same hand turns it by degrees. The kinematics that judge are pinocchio's of the
datasheet's rigid body, not the law's compiled chain."""

from __future__ import annotations

import dataclasses

import numpy as np
import pinocchio as pin
import pytest
from example_cell import ADMITTANCE_ALONE, example_control

from control.admittance_law import AdmittanceController
from control.declared_model import DeclaredModel
from control.model.dynamics import RigidBodyModel
from gateway.message_factories import make_joint_state
from gateway.messages import ControllerState

N = 6
Q0 = np.array([0.0, 0.15, 0.25, 0.0, -0.4, 0.0])
P_BAR = (6.0, 4.0)
#: the hand at the tool point: 40 N along no axis of the tool or the world, and a 6 N·m
#: twist about another direction (a painter's wrist), on world axes
FORCE_N = 40.0 * np.array([0.6, 0.48, -0.64])
MOMENT_NM = 6.0 * np.array([0.0, 0.6, 0.8])
#: what the fixture lets the reference drift off it, the tool point from its plane or line [m]
#: and the tool's turn [rad]: the trapezoid step's second-order error along the arm's arcs,
#: about ½ κ v² dt per second (κ ≈ 2 1/m for a 1 m arm, v the 0.22 m/s limit, dt 4 ms: 2e-4
#: m/s), held by the drift correction's 5 1/s at 4e-5 m (measured: 37 and 46 µm); bound 5×
#: that, 0.2 mm, far under the arm's own tracking error. The turn likewise (the tool's angular
#: speed here about 0.1 rad/s: 2e-5 rad), bound 1e-4 rad; issue 47 asks 1° (17 mrad) of the
#: real gun
LOCK_M = 2e-4
LOCK_RAD = 1e-4


@pytest.fixture(scope="module")
def cfg(tmp_path_factory):
    # the law alone: the fake drives carry the model's torque only (test_admittance.py)
    return example_control(tmp_path_factory.mktemp("cell"), **ADMITTANCE_ALONE)


def state(k: int, q, dq, current):
    zero = np.zeros(N)
    return make_joint_state(k, 0.004 * k, ControllerState.EXTERNAL, 0, np.asarray(q),
                            np.asarray(dq), np.asarray(current), np.asarray(q), zero,
                            0.004)  # fmt: skip


def guided(cfg, guide: str) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The reference's tool pose at rest, then after 1.2 s of the hand (the arm following the
    reference, its drives carrying the model's load and the torque that accelerates it, less
    the hand's ``Jᵀ (F, M)``): (p₀, R₀, p, R), world axes."""
    model = DeclaredModel.load(cfg.model)
    ctl = AdmittanceController(dataclasses.replace(cfg, guide=guide), model)
    kin = RigidBodyModel.from_description(model.desc)
    k_nm_per_a = np.array([j.drive_gain_nm_per_a for j in model.desc.joints])
    adm = ctl.admittance

    def load(q):
        return model.gravity_nm(q) - model.cylinder_nm(q, np.array(P_BAR))

    for k in range(1, 50):
        ctl.answer(state(k, Q0, np.zeros(N), load(Q0) / k_nm_per_a), P_BAR)
    start = kin.world_T_tool(np.array(adm.q_r))
    hand = np.concatenate([FORCE_N, MOMENT_NM])
    for k in range(50, 350):
        q, dq = np.array(adm.q_r), np.array(adm.dq_r)
        tau = load(q) + ctl.mass(q) @ np.array(adm.ddq_r) - kin.tool_jacobian_world(q).T @ hand
        ctl.answer(state(k, q, dq, tau / k_nm_per_a), P_BAR)
    end = kin.world_T_tool(np.array(adm.q_r))
    return start[:3, 3], start[:3, :3], end[:3, 3], end[:3, :3]


def turned_rad(r0, r) -> float:
    return float(np.linalg.norm(pin.log3(r @ r0.T)))


def test_free_the_hand_turns_the_tool_by_degrees(cfg):
    p0, r0, p, r = guided(cfg, "free")
    assert turned_rad(r0, r) > np.radians(2.0)
    assert (p - p0) @ FORCE_N > 0.0


def test_orientation_locked_the_tool_follows_the_push_and_does_not_turn(cfg):
    p0, r0, p, r = guided(cfg, "orientation-locked")
    assert turned_rad(r0, r) < LOCK_RAD
    moved = p - p0
    assert moved @ FORCE_N / np.linalg.norm(FORCE_N) > 0.01, moved


def test_a_plane_keeps_the_tool_in_it_and_lets_it_slide(cfg):
    p0, r0, p, r = guided(cfg, "plane")
    normal = r0[:, 2]
    moved = p - p0
    assert turned_rad(r0, r) < LOCK_RAD
    assert abs(moved @ normal) < LOCK_M
    along = FORCE_N - (FORCE_N @ normal) * normal  # the push's share in the plane
    assert moved @ along / np.linalg.norm(along) > 0.01, moved


def test_an_axis_keeps_the_tool_on_its_line_and_lets_it_slide_along(cfg):
    p0, r0, p, r = guided(cfg, "axis")
    axis = r0[:, "xyz".index(cfg.guide_axis)]
    moved = p - p0
    assert turned_rad(r0, r) < LOCK_RAD
    assert np.linalg.norm(moved - (moved @ axis) * axis) < LOCK_M
    assert (moved @ axis) * (FORCE_N @ axis) > 0.0 and abs(moved @ axis) > 0.005, moved
