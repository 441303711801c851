"""control/identification/assembly.py: every whole model of an analysis carries the same
effects, whatever predicts a joint's own torque."""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest

from control.identification.assembly import Assembly
from control.identification.effects import Accepted
from control.identification.fit import FrictionFit
from control.identification.guard import CHOSEN
from control.identification.lsq import Evaluation, Solution
from control.identification.model import PLAIN_LS, ZERO, plain_key
from control.identification.rigid import RobotRegressor
from control.identification.terms import EffectTerm, FrictionTerm
from gateway.robot.description import load_description
from gateway.robot.urdf import to_urdf

#: A tool mounted between the runs: 8 kg, its centre 0.1 m out along the flange's z, the
#: inertia about the flange of a 0.1 m cube there [kg, kg·m, kg·m²] (pinocchio's order).
TOOL_MASS_KG, TOOL_COM_M = 8.0, np.array([0.0, 0.0, 0.1])
#: Two springs found on the training files, on joints 2 and 3 (0-based 1, 2) [N·m/rad, N·m]
SPRINGS = {1: (150.0, 20.0), 2: (-80.0, 5.0)}
#: Each joint's plain least squares: the URDF's β scaled, Coulomb, viscous, offset
PLAIN_SCALE, PLAIN_FRICTION = 1.1, (5.0, 10.0, 2.0)
VISCOUS_NM_S_PER_RAD = 40.0


def _tool_inertia() -> pin.Inertia:
    m, c = TOOL_MASS_KG, TOOL_COM_M
    cube = pin.Inertia.FromBox(m, 0.1, 0.1, 0.1)
    return pin.Inertia(m, c, cube.inertia)


def _accepted(term: EffectTerm, coef: np.ndarray, appeared: str) -> Accepted:
    n = np.zeros(1)
    return Accepted(term, np.asarray(coef, dtype=float), appeared, term.joints, n, n)


@pytest.fixture(scope="module")
def parts() -> Assembly:
    desc = load_description()
    xml = to_urdf(desc)
    reg = RobotRegressor(xml, tuple(desc.gravity_m_s2))
    n, nb = reg.n, reg.base.n_base
    beta = reg.base.base_values(reg.parameters())
    terms = [FrictionTerm(j, "simple", 0.01, 1.0) for j in range(n)]
    coef = {"rigid": beta, **{t.key: np.array([0.0, VISCOUS_NM_S_PER_RAD, 0.0]) for t in terms}}
    solution = Solution(coef, nb)
    zeros = np.zeros(n)
    fit = FrictionFit("simple", terms, np.ones(n), Evaluation(zeros, zeros, nb, zeros, solution))
    plain = {plain_key(j): np.r_[PLAIN_SCALE * beta, PLAIN_FRICTION] for j in range(n)}
    springs = [
        _accepted(EffectTerm("spring", (j,), {}), np.array(kb), "train")
        for j, kb in SPRINGS.items()
    ]
    tool = _tool_inertia().toDynamicParameters()
    payload = _accepted(EffectTerm("payload", tuple(range(n)), {}), tool, "between")
    meta = {"urdf_xml": xml, "position_cutoff_hz": 20.0, "torque_cutoff_hz": 40.0}
    return Assembly(reg, fit, solution, "robot.urdf", meta, None, None, plain, springs, [payload])


def _states(n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    rng = np.random.default_rng(5)
    q = rng.uniform(-1.0, 1.0, (40, n))
    # well away from zero: every Coulomb sign is the velocity's
    dq = rng.choice([-1.0, 1.0], (40, n)) * rng.uniform(0.2, 1.0, (40, n))
    return q, dq, rng.uniform(-2.0, 2.0, (40, n))


def _tool_torque(reg: RobotRegressor, q, dq, ddq) -> np.ndarray:
    """The tool's joint torque from pinocchio alone: the arm with the tool on its last link
    less the arm without it."""
    with_tool = reg.model.copy()
    last = with_tool.njoints - 1
    with_tool.inertias[last] = with_tool.inertias[last] + _tool_inertia()
    a, b = with_tool.createData(), reg.model.createData()
    return np.array(
        [
            pin.rnea(with_tool, a, *s) - pin.rnea(reg.model, b, *s)
            for s in zip(q, dq, ddq, strict=True)
        ]
    )


def _plain_torque(parts: Assembly, q, dq, ddq) -> np.ndarray:
    """Each joint's plain least squares, from its own row of the base regressor."""
    y = parts.reg.base_regressor(q, dq, ddq)
    coulomb, viscous, offset = PLAIN_FRICTION
    beta = parts.plain_coef[plain_key(0)][:-3]
    return np.einsum("jtb,b->tj", y, beta) + coulomb * np.sign(dq) + viscous * dq + offset


def test_every_model_of_the_second_look_carries_the_load_that_appeared_between_the_runs(parts):
    """Zero carries the tool alone, plain least squares its own fit plus the tool, on every
    joint; judged without the tool a fallback would lose on a joint the tool loads."""
    reg = parts.reg
    q, dq, ddq = _states(reg.n)
    tool = _tool_torque(reg, q, dq, ddq)
    assert np.all(np.sqrt(np.mean(tool[:, 1:3] ** 2, axis=0)) > 5.0)  # it loads J2, J3
    models = parts.second_look({1: parts.fallback(1, PLAIN_LS)})
    assert set(models) == {CHOSEN, PLAIN_LS, ZERO}
    np.testing.assert_allclose(models[ZERO].torque_nm(q, dq, ddq), tool, atol=1e-6)
    np.testing.assert_allclose(
        models[PLAIN_LS].torque_nm(q, dq, ddq), _plain_torque(parts, q, dq, ddq) + tool, atol=1e-6
    )


def test_a_training_effect_leaves_a_joint_on_a_fallback_and_stays_on_the_others(parts):
    """The training guard's choice with joint 2 on plain least squares: joint 2 has its plain
    fit and the tool, not its spring; joint 3 keeps the model, its spring and the tool."""
    reg = parts.reg
    q, dq, ddq = _states(reg.n)
    tool = _tool_torque(reg, q, dq, ddq)
    bare = parts.model({}, between=False).torque_nm(q, dq, ddq)
    spring = {j: k * q[:, j] + b for j, (k, b) in SPRINGS.items()}
    bare_arm = bare.copy()
    for j, s in spring.items():
        bare_arm[:, j] -= s  # the model with neither spring nor tool
    chosen = parts.second_look({1: parts.fallback(1, PLAIN_LS)})[CHOSEN].torque_nm(q, dq, ddq)
    np.testing.assert_allclose(
        chosen[:, 1], _plain_torque(parts, q, dq, ddq)[:, 1] + tool[:, 1], atol=1e-6
    )
    np.testing.assert_allclose(chosen[:, 2], bare_arm[:, 2] + spring[2] + tool[:, 2], atol=1e-6)
    np.testing.assert_allclose(chosen[:, 0], bare_arm[:, 0] + tool[:, 0], atol=1e-6)
    # before case (B) searched the test run: no tool yet, joint 2 still without its spring
    before = parts.model({1: parts.fallback(1, PLAIN_LS)}, between=False).torque_nm(q, dq, ddq)
    np.testing.assert_allclose(before[:, 1], _plain_torque(parts, q, dq, ddq)[:, 1], atol=1e-6)
    np.testing.assert_allclose(before[:, 2], bare_arm[:, 2] + spring[2], atol=1e-6)


def test_a_fallback_is_plain_least_squares_or_zero(parts):
    assert parts.fallback(0, ZERO).coef == pytest.approx(0.0 * parts.plain_coef[plain_key(0)])
    with pytest.raises(ValueError, match="nominal"):
        parts.fallback(0, "nominal")
