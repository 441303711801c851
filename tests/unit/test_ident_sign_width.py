"""Eq. (15)'s smooth sign with a width of its own, and case (B)'s rule (v).

A drive's friction changes sign far more sharply than its Stribeck drop decays. With the
paper's single q_e both follow one width, and the identification then read the difference as
a spurious Stribeck effect; the fitted model now chooses the sign's width separately.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from control import _rt
from control.identification.effect_rules import forward_gain
from control.identification.fit import fit_rigid_friction
from control.identification.lsq import BlockLS, contiguous_folds
from control.identification.terms import Context, FrictionTerm
from control.model.friction import Eq15Friction, FrictionParams, eq15_basis
from control.rt_tables import MODEL_FORMAT, MODEL_VERSION, friction_table, to_json


def _compiled(term: FrictionTerm, coef: np.ndarray) -> _rt.PointModel:
    """The control cycle's compiled model (control/rt) of one massless joint with ``term``."""
    eye = np.eye(3).tolist()
    chain = {"format": "leadthrough-rigid-chain", "version": 1, "gravity_m_s2": [0, 0, -9.81],
             "joints": [{"parent": None, "kind": "revolute", "axis": [0, 0, 1], "armature": 0,
                         "placement": {"rotation": eye, "translation": [0, 0, 0]},
                         "inertia": [0.0] * 10}],
             "tool": {"joint": 0,
                      "placement": {"rotation": eye, "translation": [0, 0, 0]}}}  # fmt: skip
    table = {"format": MODEL_FORMAT, "version": MODEL_VERSION, "chain": chain, "coriolis": True,
             "w_rigid": [[0.0] * 10], "w_payload": None, "envelope": None, "effects": [],
             "cylinders": [], "friction": [friction_table(term, coef)]}  # fmt: skip
    return _rt.PointModel(to_json(table))


def _params(sign_width: float | None) -> FrictionParams:
    return FrictionParams(
        0.8, 2.0, 0.05, -0.1, 0.02, 0.03, 0.1, -0.2, 3.0, 0.5,
        q_e_rad_s=0.04, gear_ratio=2.0, sign_width_rad_s=sign_width,
    )  # fmt: skip


@pytest.mark.parametrize("width", [None, 0.001])
def test_model_basis_and_the_compiled_cycle_agree_with_a_sign_width(width):
    rng = np.random.default_rng(4)
    q = rng.uniform(-2, 2, 300)
    dq = rng.uniform(-0.2, 0.2, 300)
    p = _params(width)
    batched = Eq15Friction([p])(q[:, None], dq[:, None])[:, 0]
    basis = eq15_basis(q, dq, p.q_e_rad_s, p.gear_ratio, width)
    np.testing.assert_allclose(basis @ p.linear_parameters(), batched, atol=1e-12)
    term = FrictionTerm(0, "eq15", p.q_e_rad_s, p.gear_ratio, width)
    compiled = _compiled(term, p.linear_parameters())
    for k in range(0, 300, 37):
        got = compiled.torque_nm([q[k]], [dq[k]])[0]
        assert got == pytest.approx(batched[k], abs=1e-12)
    assert FrictionParams.from_linear(p.linear_parameters(), 0.04, 2.0, width) == p


def test_without_a_width_the_sign_follows_q_e_as_the_paper_writes():
    tied, separate = _params(None), _params(0.04)
    dq = np.linspace(-0.3, 0.3, 61)[:, None]
    q = np.zeros_like(dq)
    np.testing.assert_allclose(Eq15Friction([tied])(q, dq), Eq15Friction([separate])(q, dq))
    assert tied.sign_rad_s == 0.04
    with pytest.raises(ValueError, match="sign_width_rad_s"):
        _params(0.0)


def _one_joint_run(seed: int) -> tuple[Context, np.ndarray]:
    """A joint with Coulomb 2 N·m, a Stribeck drop of 1 N·m decaying over 0.03 rad/s and a sign
    30 times sharper (width 1e-3 rad/s, as a sharp step looks through 1e-3 rad/s of velocity
    noise), on a slow multi-sine with many reversals, torque noise 0.01 N·m. One constant
    "rigid" column stands in for the rigid body."""
    rng = np.random.default_rng(seed)
    t = np.arange(40_000) / 500.0
    amplitudes, phases = rng.uniform(0.05, 0.2, 4), rng.uniform(0, 6, 4)
    freqs = (0.05, 0.11, 0.23, 0.41)
    dq = sum(
        a * np.sin(2 * np.pi * f * t + ph)
        for a, f, ph in zip(amplitudes, freqs, phases, strict=True)
    )
    q = np.cumsum(dq) / 500.0
    tau = (2.0 + 1.0 * np.exp(-np.abs(dq) / 0.03)) * np.tanh(dq / 2e-3) + 1.5 * dq
    tau = tau + 0.3 + rng.normal(0, 0.01, t.size)
    ctx = Context(
        q=q[:, None], dq=dq[:, None], ddq=np.gradient(dq, t)[:, None], t=t,
        y_base=np.ones((1, t.size, 1)),
    )  # fmt: skip
    return ctx, tau[:, None]


def test_the_fit_chooses_a_sharp_sign_and_reaches_the_noise():
    ctx, tau = _one_joint_run(7)
    folds = contiguous_folds(tau.shape[0], 5)
    tied = fit_rigid_friction(BlockLS(tau, folds), ctx, "eq15", np.ones(1), sign_grid=())
    free = fit_rigid_friction(BlockLS(tau, folds), ctx, "eq15", np.ones(1))
    (term,) = free.terms
    assert term.sign_width_rad_s is not None and term.sign_width_rad_s <= 0.002
    assert 0.015 <= term.q_e_rad_s <= 0.06
    assert free.evaluation.cv_rms[0] < 0.012  # the noise is 0.01
    assert tied.evaluation.cv_rms[0] > 1.5 * free.evaluation.cv_rms[0]


def test_rule_v_scores_a_case_b_candidate_only_where_the_training_run_went():
    """A mismatch that lives only outside the envelope (the model's extrapolation) is learnt by
    a candidate fitted on the test run, and shows as a gain forward in time; scored on the rows
    inside the envelope it brings nothing. An effect present everywhere gains on both."""
    rng = np.random.default_rng(2)
    n = 4000
    outside = (np.arange(n) // 200) % 3 == 0  # a third of the run, in bursts
    x = rng.normal(size=n)
    noise = rng.normal(0, 0.1, n)
    folds = contiguous_folds(n, 5)
    cols = {0: x[:, None]}
    extrapolation = BlockLS((np.where(outside, 1.0, 0.0) * x + noise)[:, None], folds)
    everywhere = BlockLS((0.5 * x + noise)[:, None], folds)
    w = np.ones(1)
    assert forward_gain(extrapolation, [], w, "c", cols)[0] > 0.1
    assert forward_gain(extrapolation, [], w, "c", cols, scored=~outside)[0] < 0.0
    assert forward_gain(everywhere, [], w, "c", cols, scored=~outside)[0] > 0.5
    # Scoring every row gives what the rule (iv) figure always was.
    np.testing.assert_allclose(
        forward_gain(everywhere, [], w, "c", cols),
        forward_gain(everywhere, [], w, "c", cols, scored=np.ones(n, bool)),
    )
    assert math.isfinite(float(forward_gain(everywhere, [], w, "c", cols)[0]))
