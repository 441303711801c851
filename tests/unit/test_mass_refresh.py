"""M̂ of the identified model for the admittance's compiled cycle, handed in off the cycle
(control/mass_refresh.py): the cycle renders the nominal rigid body's M̂ until it is given the
identified one, keeps the newest it was given, wants another once its reference has moved the
inertia step, and the control process's thread hands it over where the arm is and stops."""

from __future__ import annotations

import time

import numpy as np
import pytest
from example_cell import ADMITTANCE_ALONE, example_control

from control.admittance_law import AdmittanceController
from control.declared_model import DeclaredModel, IdentifiedControlModel
from control.identification.model import IdentifiedModel
from control.identification.rigid import RobotRegressor
from control.identification.terms import FrictionTerm
from control.mass_refresh import MassRefresh
from control.zero_moment_law import INERTIA_STEP_RAD
from gateway.robot.description import load_description
from gateway.robot.urdf import to_urdf

Q = np.array([0.1, 0.3, 0.4, 0.2, -0.5, 0.1])
#: the identified links are this much heavier than the datasheet's: an M̂ the cycle renders
#: from the identified model is told from the nominal one by it
HEAVIER = 1.5


@pytest.fixture(scope="module")
def ctl(tmp_path_factory) -> AdmittanceController:
    desc = load_description()
    reg = RobotRegressor(to_urdf(desc), tuple(desc.gravity_m_s2))
    beta = reg.base.base_values(HEAVIER * reg.parameters())
    terms = [FrictionTerm(j, "simple", 0.01, 100.0) for j in range(reg.n)]
    coefs = [np.zeros(3) for _ in terms]
    model = IdentifiedControlModel(IdentifiedModel(reg, beta, "simple", terms, coefs))
    cfg = example_control(tmp_path_factory.mktemp("mass"), **ADMITTANCE_ALONE)
    return AdmittanceController(cfg, model)


def in_use(ctl: AdmittanceController, q: np.ndarray) -> np.ndarray:
    return np.array(ctl.compiled.mass_in_use(q.tolist()))


def test_the_cycle_renders_the_nominal_mass_until_it_is_handed_the_identified_one(ctl):
    nominal = np.array(ctl._inertia.mass_matrix(Q.tolist(), armature=True))
    identified = ctl.mass(Q)
    # the identified model's M̂ is its own: heavier links, the datasheet's rotors
    assert np.abs(identified - nominal).max() > 0.1 * np.abs(nominal).max()
    np.testing.assert_allclose(in_use(ctl, Q), nominal, rtol=1e-12)
    assert ctl.refresh_mass(Q)
    np.testing.assert_allclose(in_use(ctl, Q), identified, rtol=1e-12)
    # within the inertia step the one handed in stands; past it, another is wanted
    near = Q + 0.5 * INERTIA_STEP_RAD
    assert not ctl.refresh_mass(near)
    far = Q.copy()
    far[1] += 1.5 * INERTIA_STEP_RAD
    assert ctl.refresh_mass(far)
    np.testing.assert_allclose(in_use(ctl, Q), ctl.mass(far), rtol=1e-12)


def test_the_thread_hands_it_over_where_the_arm_is_and_stops(ctl):
    pose = Q.copy()
    pose[0] += 0.3  # far from any M̂ handed in before
    refresh = MassRefresh(ctl, lambda: pose)
    refresh.start()
    try:
        deadline = time.monotonic() + 5.0
        while refresh.refreshed == 0 and time.monotonic() < deadline:
            time.sleep(0.01)
    finally:
        refresh.stop()
    assert refresh.refreshed >= 1 and refresh.errors == 0
    assert not refresh._thread.is_alive()
    np.testing.assert_allclose(in_use(ctl, pose), ctl.mass(pose), rtol=1e-12)


def test_a_model_without_an_identified_mass_never_wants_one(tmp_path):
    cfg = example_control(tmp_path, **ADMITTANCE_ALONE)
    plain = AdmittanceController(cfg, DeclaredModel.load(cfg.model))
    assert not plain.refresh_mass(Q)
    nominal = np.array(plain._inertia.mass_matrix(Q.tolist(), armature=True))
    np.testing.assert_allclose(in_use(plain, Q), nominal, rtol=1e-12)
