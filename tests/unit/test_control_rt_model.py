"""The compiled per-cycle model computes what the model file says.

The control cycle evaluates the model it compensates in Rust (control/rt/src/point_model.rs,
from the table control/rt_tables.py makes), a re-statement of :meth:`IdentifiedModel.torque_nm`
for one state. These tests pin the two together for every friction family, every effect of the
vocabulary, plain joints and the training envelope, on samples inside and well outside that
envelope and at exactly zero velocity; and the declared model's and the cylinders' per-cycle
torques to their vectorised forms.
"""

from __future__ import annotations

import numpy as np
import pytest
from example_cell import EXAMPLE_MODEL

from control import _rt
from control.declared_model import DeclaredModel, IdentifiedControlModel
from control.identification.envelope import Envelope
from control.identification.friction_law import FRICTION_MODELS, FRICTION_PARAM_NAMES
from control.identification.model import IdentifiedModel, PlainJoint
from control.identification.rigid import RobotRegressor
from control.identification.terms import (
    EFFECT_NAMES,
    EffectTerm,
    FrictionTerm,
)
from control.rt_tables import NOT_AT_RUN_TIME, point_model_table, to_json
from gateway.robot.description import load_description
from gateway.robot.urdf import to_urdf

RTOL, ATOL = 1e-12, 1e-9


@pytest.fixture(scope="module")
def regressor() -> RobotRegressor:
    desc = load_description()
    return RobotRegressor(to_urdf(desc), tuple(desc.gravity_m_s2))


def every_effect(rng: np.random.Generator) -> list[tuple[EffectTerm, np.ndarray, str]]:
    """One of each effect of the vocabulary, with random coefficients."""
    terms = [
        EffectTerm("position_ripple", (2,), {"cycles_per_rev": 27}),
        EffectTerm("payload", (0, 1, 2, 4, 5)),
        EffectTerm("spring", (1,)),
        EffectTerm("stribeck", (0,), {"velocity_rad_s": 0.03}),
        EffectTerm("load_dependent_friction", (1,)),
        EffectTerm("time_delay", (0, 1, 2, 3, 4, 5), {"delay_s": 0.004}),
        EffectTerm("thermal_drift", (3,)),
        EffectTerm("wrist_coupling", (4,), {"from_joint": 3, "source": "torque"}),
        EffectTerm("wrist_coupling", (5,), {"from_joint": 4, "source": "friction"}),
    ]
    assert {t.name for t in terms} == set(EFFECT_NAMES), "a new effect needs a case here"
    sizes = {"position_ripple": 2, "payload": 10, "spring": 2, "thermal_drift": 2}
    return [
        (t, rng.normal(0.0, 5.0, sizes.get(t.name, 1)), "between_train_and_test") for t in terms
    ]


def model_with(regressor, kinds, rng, *, envelope=True, plain=(), effects=True, options=False):
    """``options``: every other joint's friction with memory, every third with a Gaussian
    Stribeck rise (:class:`FrictionTerm`)."""
    n = regressor.n
    terms = [
        FrictionTerm(
            j,
            kinds[j],
            float(rng.uniform(0.005, 0.05)),
            float(rng.uniform(50, 150)),
            presliding_rad=3e-4 if options and j % 2 == 0 else None,
            stribeck_rad_s=0.02 if options and j % 3 == 0 else None,
        )
        for j in range(n)
    ]
    coefs = [rng.normal(0.0, 20.0, len(t.parameter_names)) for t in terms]
    assert all(
        len(t.parameter_names) == len(FRICTION_PARAM_NAMES[t.kind]) + (t.stribeck_rad_s is not None)
        for t in terms
    )
    nb = regressor.base.n_base
    beta = regressor.base.base_values(regressor.parameters()) + rng.normal(0.0, 0.5, nb)
    env = None
    if envelope:
        q = rng.uniform(-1.0, 1.0, (200, n))
        dq = rng.uniform(-0.5, 0.5, (200, n))
        env = Envelope.of(q, dq)
    plain_joints = {
        j: PlainJoint(j, beta + rng.normal(0.0, 1.0, nb), *rng.normal(0.0, 10.0, 2)) for j in plain
    }
    return IdentifiedModel(
        regressor,
        beta,
        "mixed",
        terms,
        coefs,
        effects=every_effect(rng) if effects else [],
        envelope=env,
        plain_joints=plain_joints,
    )


def test_friction_options_evaluate_per_cycle_as_the_sliding_law(regressor):
    """Memory and a Gaussian Stribeck rise (:class:`FrictionTerm`): one state slides, so the
    cycle's table (the family's coefficients, the rise as a stribeck column) gives what
    torque_nm gives for one sample, in every family and with plain joints."""
    rng = np.random.default_rng(11)
    for kinds, plain in ((["eq15"] * 6, ()), (["eq15", "eq14", "simple"] * 2, (1,))):
        model = model_with(regressor, kinds, rng, plain=plain, effects=False, options=True)
        point = PointModel(model)
        zeros = np.zeros(regressor.n)
        for q, dq in samples(regressor.n, rng, 60):
            want = model.torque_nm(q, dq, zeros)
            np.testing.assert_allclose(
                point.torque_nm(q.tolist(), dq.tolist()), want, rtol=RTOL, atol=ATOL
            )


def PointModel(model: IdentifiedModel) -> _rt.PointModel:
    """The compiled model of an identified one, as the control process builds it."""
    control = IdentifiedControlModel(model)
    return _rt.PointModel(to_json(point_model_table(control.desc, control.identified)))


def samples(n: int, rng: np.random.Generator, count: int):
    """q and dq inside and far outside the envelope above; every fifth sample at rest, and one
    joint at exactly zero velocity in each other sample."""
    for i in range(count):
        q = rng.uniform(-2.5, 2.5, n)
        dq = np.zeros(n) if i % 5 == 0 else rng.uniform(-2.0, 2.0, n)
        dq[i % n] = 0.0
        yield q, dq


CASES = {
    "eq15 with every effect": (["eq15"] * 6, (), True),
    "eq14 with every effect": (["eq14"] * 6, (), True),
    "simple with every effect": (["simple"] * 6, (), True),
    "families mixed, plain joints 2 and 6": (["eq15", "eq14", "simple"] * 2, (1, 5), True),
    "no envelope": (["eq15"] * 6, (3,), False),
}


@pytest.mark.parametrize("case", CASES)
def test_point_model_equals_torque_nm(regressor, case):
    kinds, plain, envelope = CASES[case]
    assert set(kinds) <= set(FRICTION_MODELS)
    rng = np.random.default_rng(abs(hash(case)) % 2**32)
    model = model_with(regressor, kinds, rng, envelope=envelope, plain=plain)
    point = PointModel(model)
    zeros = np.zeros(regressor.n)
    for q, dq in samples(regressor.n, rng, 100):
        want = model.torque_nm(q, dq, zeros)
        got = point.torque_nm(q.tolist(), dq.tolist())
        np.testing.assert_allclose(got, want, rtol=RTOL, atol=ATOL)
        at_rest = model.torque_nm(q, zeros, zeros)
        np.testing.assert_allclose(point.torque_nm(q.tolist()), at_rest, rtol=RTOL, atol=ATOL)


def test_every_friction_family_is_covered():
    kinds = {k for spec in CASES.values() for k in spec[0]}
    assert kinds == set(FRICTION_MODELS)


def test_effects_without_a_run_time_torque_are_the_ones_torque_nm_skips(regressor):
    """time_delay and thermal_drift change nothing per cycle, exactly as torque_nm without a
    time; every other effect does change the torque."""
    rng = np.random.default_rng(3)
    bare = model_with(regressor, ["eq15"] * 6, rng, effects=False)
    q, dq = np.full(6, 0.3), np.full(6, 0.02)  # within the Stribeck velocity
    base = np.asarray(PointModel(bare).torque_nm(q.tolist(), dq.tolist()))
    for term, coef, appeared in every_effect(rng):
        bare.effects = [(term, coef, appeared)]
        delta = np.asarray(PointModel(bare).torque_nm(q.tolist(), dq.tolist())) - base
        if term.name in NOT_AT_RUN_TIME:
            assert not np.any(delta), term.name
        else:
            assert np.any(np.abs(delta) > 1e-6), term.name


def test_an_effect_it_cannot_evaluate_is_refused_at_load(regressor):
    rng = np.random.default_rng(4)
    model = model_with(regressor, ["eq15"] * 6, rng, effects=False)
    model.effects = [(EffectTerm("gear_backlash", (1,)), np.ones(1), "training")]
    with pytest.raises(ValueError, match="gear_backlash"):
        PointModel(model)


def test_a_torque_that_is_not_finite_is_refused_naming_the_joint():
    model = DeclaredModel.load(EXAMPLE_MODEL)
    q = np.zeros(model.n)
    with pytest.raises(ArithmeticError, match="joint 2"):
        model.cycle_torques_nm(q, [0.0] * model.n, [float("inf"), 1.0])
    with pytest.raises(ValueError, match="p_bar needs 2 values"):
        model.cycle_torques_nm(q, [0.0] * model.n, [1.0])
