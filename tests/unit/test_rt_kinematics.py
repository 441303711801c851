"""The speed monitor's kinematic chain for the compiled CAN cycle (drivers/can/rt_kinematics.py):
plain JSON, and evaluated as speed_monitor.rs evaluates it, the tool point and flange that
pinocchio computes (RigidBodyModel.world_T_tool and the description's tool offset)."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from control.model.dynamics import RigidBodyModel
from drivers.can.rt_kinematics import CHAIN_FORMAT, CHAIN_VERSION, chain_table
from gateway.robot.description import load_description


def _rotation(axis: np.ndarray, angle_rad: float) -> np.ndarray:
    """Rodrigues: the turn by ``angle_rad`` about the unit ``axis``."""
    x, y, z = axis
    k = np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])
    return np.eye(3) + math.sin(angle_rad) * k + (1.0 - math.cos(angle_rad)) * (k @ k)


def evaluate(table: dict, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(tool, flange) in the world [m] of the table at ``q`` [rad], as KinematicChain::points."""
    pose = np.eye(4)
    for joint, angle in zip(table["joints"], q, strict=True):
        turn = np.eye(4)
        turn[:3, :3] = _rotation(np.array(joint["axis"]), float(angle))
        pose = pose @ np.array(joint["parent_T_joint"]) @ turn
    tool = pose[:3, :3] @ np.array(table["tool_m"]) + pose[:3, 3]
    flange = pose[:3, :3] @ np.array(table["flange_m"]) + pose[:3, 3]
    return tool, flange


def test_the_table_is_plain_json():
    table = chain_table(load_description())
    text = json.dumps(table, allow_nan=False)
    assert json.loads(text) == table
    assert table["format"] == CHAIN_FORMAT and table["version"] == CHAIN_VERSION
    assert [j["name"] for j in table["joints"]] == list(load_description().joint_names)
    for joint in table["joints"]:
        matrix = np.array(joint["parent_T_joint"])
        assert matrix.shape == (4, 4) and matrix[3].tolist() == [0.0, 0.0, 0.0, 1.0]
        np.testing.assert_allclose(matrix[:3, :3] @ matrix[:3, :3].T, np.eye(3), atol=1e-12)
        assert joint["axis"] == [0.0, 0.0, 1.0]
    assert len(table["tool_m"]) == 3 and len(table["flange_m"]) == 3


def pinocchio_points(
    model: RigidBodyModel, tool_in_6: np.ndarray, q: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """(tool, flange) in the world [m] at ``q`` [rad] from pinocchio's pose of the tool: the
    tool point its origin, the flange behind it by the tool's offset in link 6 [m]."""
    pose = model.world_T_tool(q)
    tool = pose[:3, 3]
    return tool, tool - pose[:3, :3] @ tool_in_6


def test_the_table_evaluated_is_pinocchios_tool_and_flange_for_random_joint_positions():
    desc = load_description()
    table = json.loads(json.dumps(chain_table(desc)))  # what the compiled side receives
    model = RigidBodyModel.from_description(desc)
    tool_in_6 = np.array(desc.tool.position_in_link6_m, dtype=float)
    rng = np.random.default_rng(48)
    lower, upper = np.array(desc.lower_rad), np.array(desc.upper_rad)
    for _ in range(20):
        q = rng.uniform(lower, upper)
        tool, flange = evaluate(table, q)
        want_tool, want_flange = pinocchio_points(model, tool_in_6, q)
        np.testing.assert_allclose(tool, want_tool, rtol=0.0, atol=1e-9)
        np.testing.assert_allclose(flange, want_flange, rtol=0.0, atol=1e-9)


def test_the_default_is_the_datasheets_description():
    assert chain_table() == chain_table(load_description())


@pytest.mark.parametrize("q", [np.zeros(6), np.full(6, 0.5)])
def test_the_flange_is_behind_the_tool_by_the_tools_offset(q):
    desc = load_description()
    tool, flange = evaluate(chain_table(desc), q)
    offset = np.linalg.norm(desc.tool.position_in_link6_m)
    assert np.linalg.norm(tool - flange) == pytest.approx(offset, abs=1e-12)
