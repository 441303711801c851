"""The control process reads a drive's torque through the channel the identification measured.

An identified model carries the torque channel's gain k and offset b per joint
(control/identification/chain.py): a drive whose datasheet torque constant is a few % off reads
``K i = k τ + b`` for a physical joint torque τ. The model predicts τ, so every reading the
control process compares with it (the law's hand torque, the engagement probe, the adaptation's
residual, the static-load check) must be ``(K i - b) / k`` first, or a 7 % gain error on a
shoulder carrying 500 N·m reads as a 35 N·m hand that is not there.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from example_cell import example_cell

from control.cell_config import load_control_config
from control.declared_model import DeclaredModel
from control.identification.model import IdentifiedModel
from control.identification.rigid import RobotRegressor
from control.identification.terms import FrictionTerm
from control.load_check import static_load_check
from control.zero_moment_law import ZeroMomentController
from gateway.message_factories import make_joint_state
from gateway.messages import ControllerState
from gateway.robot.description import load_description
from gateway.robot.urdf import to_urdf

N = 6
GAIN = np.array([1.0, 0.93, 1.04, 1.0, 0.95, 1.0])
OFFSET_NM = np.array([0.0, -12.0, 3.0, 0.5, 0.0, -0.2])
Q0 = np.array([0.0, 0.15, 0.25, 0.0, -0.4, 0.0])
P_BAR = np.array([6.0, 4.0])


def identified(path, gain=None, offset=None) -> DeclaredModel:
    """An identified model (eq. 15 friction, the datasheet's rigid body) with this chain."""
    desc = load_description()
    xml = to_urdf(desc)
    reg = RobotRegressor(xml, tuple(desc.gravity_m_s2))
    terms = [FrictionTerm(j, "eq15", 0.01, desc.gear_ratios[j]) for j in range(N)]
    coefs = [np.array([20.0, 30.0, 1.0, 0.5, 0.2, 0.1, 1.0, 0.5, 60.0, 2.0])] * N
    meta = {"urdf_xml": xml, "cylinders_removed": True}
    base = reg.base.base_values(reg.parameters())
    chain = {"torque_gain": gain, "torque_offset_nm": offset}
    IdentifiedModel(reg, base, "eq15", terms, coefs, metadata=meta, **chain).save(path)
    return DeclaredModel.load(path)


@pytest.fixture(scope="module")
def cfg(tmp_path_factory):
    base = load_control_config(example_cell(tmp_path_factory.mktemp("cell")))[0]
    return dataclasses.replace(base, engage_rest_states=0)


def test_the_model_turns_a_reading_into_physical_torque_through_its_chain(tmp_path):
    model = identified(tmp_path / "model.json", GAIN, OFFSET_NM)
    k_datasheet = model.desc.drive_gains_nm_per_a
    tau = np.array([10.0, -480.0, 150.0, 20.0, -8.0, 1.5])
    current = (GAIN * tau + OFFSET_NM) / k_datasheet  # what the drives report
    np.testing.assert_allclose(model.motor_torque_nm(current), tau, rtol=1e-12, atol=1e-9)
    plain = identified(tmp_path / "plain.json")  # no chain measured: the datasheet's K
    np.testing.assert_array_equal(plain.motor_torque_nm(current), k_datasheet * current)


def test_the_compiled_cycle_reads_the_currents_as_the_model_does(tmp_path, cfg):
    model = identified(tmp_path / "model.json", GAIN, OFFSET_NM)
    ctl = ZeroMomentController(cfg, model)
    current = np.array([3.0, -40.0, 12.0, 1.0, -0.5, 0.1])
    st = make_joint_state(1, 0.004, ControllerState.EXTERNAL, 0, Q0, np.zeros(N), current,
                          Q0, np.zeros(N), 0.004)  # fmt: skip
    np.testing.assert_allclose(
        ctl.motor_torque_nm(st), model.motor_torque_nm(current), rtol=1e-12, atol=1e-9
    )


def test_the_static_load_check_compares_the_physical_torque_with_the_model(tmp_path):
    """An arm holding exactly the model's static load through a channel with a gain and an
    offset passes; read with the datasheet's K alone, the same currents are 36 N·m off on J2
    and fail."""
    model = identified(tmp_path / "model.json", GAIN, OFFSET_NM)
    static = model.gravity_nm(Q0) - model.cylinder_nm(Q0, P_BAR)
    current = (GAIN * static + OFFSET_NM) / model.desc.drive_gains_nm_per_a
    margin = [2.0] * N
    assert static_load_check(model, Q0, current, P_BAR, margin).ok
    plain = identified(tmp_path / "plain.json")
    assert abs(GAIN[1] * static[1] + OFFSET_NM[1] - static[1]) > 30.0  # the premise
    assert not static_load_check(plain, Q0, current, P_BAR, margin).ok
