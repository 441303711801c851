"""The compiled rigid-body chain (control/rt/src/chain.rs) gives pinocchio's numbers.

The control cycle's inverse dynamics, regressor, mass matrix and tool Jacobian come from the
compiled chain, built from a table of the pinocchio model (control/rt_tables.py). These tests
hold the two together on random states: on the robot's own description (revolute joints about
z) and on a branched-free chain of random revolute joints about x, y, z and unaligned axes with
random bodies, so a convention that only the datasheet's chain happens to satisfy is caught.
"""

from __future__ import annotations

import json

import numpy as np
import pinocchio as pin
import pytest

from control import _rt
from control.model.dynamics import RigidBodyModel
from control.rt_tables import chain_table, to_json
from gateway.robot.description import load_description
from gateway.robot.urdf import TOOL_LINK

ATOL = 1e-9


def random_model(rng: np.random.Generator) -> tuple[pin.Model, np.ndarray]:
    """Eight joints (revolute about x, y, z and unaligned axes, prismatic along z and an
    unaligned axis: a linear track) with random placements and bodies, gravity off the axes, a
    tool frame on the last joint; and armatures."""
    model = pin.Model()
    model.gravity = pin.Motion(np.array([0.3, -0.5, -9.7]), np.zeros(3))
    parent = 0
    for k in range(8):
        axis = rng.normal(size=3)
        axis /= np.linalg.norm(axis)
        joint = (pin.JointModelPZ(), pin.JointModelRX(), pin.JointModelRY(), pin.JointModelRZ(),
                 pin.JointModelRevoluteUnaligned(axis), pin.JointModelPrismaticUnaligned(axis),
                 pin.JointModelRZ(), pin.JointModelRevoluteUnaligned(axis))[k]  # fmt: skip
        placement = pin.SE3(pin.rpy.rpyToMatrix(*rng.uniform(-np.pi, np.pi, 3)),
                            rng.uniform(-0.5, 0.5, 3))  # fmt: skip
        parent = model.addJoint(parent, joint, placement, f"j{k}")
        a = rng.normal(size=(3, 3))
        inertia = pin.Inertia(float(rng.uniform(0.5, 20.0)), rng.uniform(-0.2, 0.2, 3),
                              a @ a.T + 0.1 * np.eye(3))  # fmt: skip
        model.appendBodyToJoint(parent, inertia, pin.SE3.Identity())
    tool = pin.SE3(pin.rpy.rpyToMatrix(0.1, -0.4, 0.8), np.array([0.05, 0.02, 0.3]))
    model.addFrame(pin.Frame("tool", parent, 0, tool, pin.FrameType.OP_FRAME))
    return model, rng.uniform(0.0, 2.0, 8)


def robot_model() -> tuple[pin.Model, np.ndarray]:
    rigid = RigidBodyModel.from_description(load_description())
    return rigid.model, rigid.armature_kgm2


MODELS = {
    "the robot's description": robot_model,
    "random revolute and prismatic joints": lambda: random_model(np.random.default_rng(7)),
}


@pytest.mark.parametrize("which", MODELS)
def test_the_compiled_chain_gives_pinocchios_dynamics_and_kinematics(which):
    model, armature = MODELS[which]()
    data = model.createData()
    tool = TOOL_LINK if which == "the robot's description" else "tool"
    chain = _rt.Chain(to_json(chain_table(model, armature, tool)))
    n = model.nv
    assert chain.n == n
    tool_id = model.getFrameId(tool)
    rng = np.random.default_rng(11)
    for _ in range(50):
        q, dq, ddq = rng.uniform(-3, 3, n), rng.uniform(-2, 2, n), rng.uniform(-5, 5, n)
        args = (q.tolist(), dq.tolist(), ddq.tolist())
        want = pin.rnea(model, data, q, dq, ddq)
        np.testing.assert_allclose(chain.rnea(*args), want, atol=ATOL)
        np.testing.assert_allclose(chain.rnea(*args, armature=True), want + armature * ddq,
                                   atol=ATOL)  # fmt: skip
        no_g = pin.rnea(model, data, q, dq, ddq) - pin.computeGeneralizedGravity(model, data, q)
        np.testing.assert_allclose(chain.rnea(*args, gravity=False), no_g, atol=ATOL)
        y = pin.computeJointTorqueRegressor(model, data, q, dq, ddq)
        np.testing.assert_allclose(chain.regressor(*args), y, atol=ATOL)
        m = pin.crba(model, data, q)
        m = np.triu(m) + np.triu(m, 1).T
        np.testing.assert_allclose(chain.mass_matrix(q.tolist()), m, atol=ATOL)
        np.testing.assert_allclose(chain.mass_matrix(q.tolist(), armature=True),
                                   m + np.diag(armature), atol=ATOL)  # fmt: skip
        pin.framesForwardKinematics(model, data, q)
        rot, origin = chain.tool_pose(q.tolist())
        np.testing.assert_allclose(rot, data.oMf[tool_id].rotation, atol=ATOL)
        np.testing.assert_allclose(origin, data.oMf[tool_id].translation, atol=ATOL)
        jac = pin.computeFrameJacobian(model, data, q, tool_id, pin.LOCAL_WORLD_ALIGNED)
        np.testing.assert_allclose(chain.tool_jacobian(q.tolist()), jac, atol=ATOL)


def test_a_joint_the_compiled_chain_cannot_take_is_refused_by_name():
    model = pin.Model()
    model.addJoint(0, pin.JointModelRUBZ(), pin.SE3.Identity(), "endless")
    with pytest.raises(ValueError, match="'endless' is a JointModelRUBZ"):
        chain_table(model)


BAD_TABLES = {
    "a rotation that is not one": (("joints", 0, "placement", "rotation", 0, 0), 2.0,
                                   "joints[0].placement.rotation is not a rotation"),
    "an axis that is not a unit vector": (("joints", 1, "axis"), [0.0, 0.0, 2.0],
                                          "joints[1].axis is not a unit vector"),
    "a parent after its child": (("joints", 1, "parent"), 3, "joints[1].parent"),
    "a parameter that is not finite": (("joints", 2, "inertia", 0), "nan",
                                       "joints[2].inertia must be 10 finite numbers"),
    "a tool on no joint": (("tool", "joint"), 99, "tool.joint"),
    "another format": (("format",), "leadthrough-kinematic-chain",
                       "not a leadthrough-rigid-chain v1 table"),
}  # fmt: skip


@pytest.mark.parametrize("case", BAD_TABLES)
def test_a_bad_table_is_refused_naming_what_is_wrong(case):
    path, value, message = BAD_TABLES[case]
    table = chain_table(*robot_model(), TOOL_LINK)
    node = table
    for key in path[:-1]:
        node = node[key]
    node[path[-1]] = value
    with pytest.raises(ValueError, match=message.replace("[", r"\[").replace("]", r"\]")):
        _rt.Chain(json.dumps(table))


def test_wrong_lengths_are_refused_naming_the_argument():
    chain = _rt.Chain(to_json(chain_table(*robot_model(), TOOL_LINK)))
    with pytest.raises(ValueError, match="dq needs 6 values, got 5"):
        chain.rnea([0.0] * 6, [0.0] * 5, [0.0] * 6)
    with pytest.raises(ValueError, match="not JSON"):
        _rt.Chain("{")
