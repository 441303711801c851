"""The static-load check that gates teaching (control/load_check.py)."""

import numpy as np
from example_cell import EXAMPLE_MODEL

from control.declared_model import DeclaredModel
from control.load_check import breakaway_nm, static_load_check
from control.model.dynamics import RigidBodyModel

Q = np.array([0.0, 0.15, 0.25, 0.0, -0.4, 0.0])
P = np.array([6.0, 4.0])
MARGIN = [20.0, 20.0, 20.0, 2.0, 2.0, 1.0]


def held_current(model: DeclaredModel, extra_nm: np.ndarray) -> np.ndarray:
    """Motor current of the held arm when it carries ``extra_nm`` more than the model says."""
    gains = np.array([j.drive_gain_nm_per_a for j in model.desc.joints])
    return (model.gravity_nm(Q) - model.cylinder_nm(Q, P) + extra_nm) / gains


def test_matching_load_passes_within_friction_and_margin():
    model = DeclaredModel.load(EXAMPLE_MODEL)
    friction = breakaway_nm(model, Q)
    assert np.all(friction > 0)
    check = static_load_check(model, Q, held_current(model, 0.9 * friction), P, MARGIN)
    assert check.ok, check.message


def test_an_undeclared_tool_fails_naming_the_joint():
    model = DeclaredModel.load(EXAMPLE_MODEL)
    # An 8 kg gun 0.05 m beyond the flange, as the virtual cell's test mounts it.
    rb = RigidBodyModel.from_description(model.desc)
    jac = rb.tool_jacobian_world(Q)[:3]
    gun_nm = jac.T @ np.array([0.0, 0.0, 8.0 * 9.81])
    check = static_load_check(model, Q, held_current(model, gun_nm), P, MARGIN)
    assert not check.ok
    assert check.joint == 3 and "joint 3" in check.message and "identify" in check.message
    assert check.to_json()["ok"] is False


def test_a_nan_current_fails():
    model = DeclaredModel.load(EXAMPLE_MODEL)
    current = held_current(model, np.zeros(6))
    current[4] = np.nan
    check = static_load_check(model, Q, current, P, [])
    assert not check.ok and "joint 5" in check.message
