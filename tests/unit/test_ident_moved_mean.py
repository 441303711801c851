"""A candidate fitted where the model is fixed (case B) must be more than a moved mean torque
(:func:`control.identification.effects._judge_all` with ``moved_mean``), and a spring pulls
towards its rest angle (:func:`control.identification.effect_rules.implausible`).

The residual of one joint is built by hand on a slow sine of q (1 rad amplitude) with white
noise σ: what the case-B search sees after the fixed model is taken out.
"""

from __future__ import annotations

import numpy as np
import pytest

from control.identification.effect_rules import NoiseFloor, Options
from control.identification.effects import _judge_all
from control.identification.lsq import BlockLS, contiguous_folds
from control.identification.terms import EffectTerm

SIGMA_NM = 0.02
ROWS = 6000


def _motion() -> np.ndarray:
    t = np.arange(ROWS) / 250.0
    return np.sin(2 * np.pi * 0.05 * t) + 0.3 * np.sin(2 * np.pi * 0.13 * t)


def _verdict(residual_of_q, moved_mean: bool, term=None, columns=None, seed: int = 0):
    """The verdict on ``term`` (a spring on the joint unless given) with ``columns`` (of q;
    the spring's ``q``, ``1`` unless given)."""
    rng = np.random.default_rng(seed)
    q = _motion()
    y = (residual_of_q(q) + SIGMA_NM * rng.standard_normal(ROWS))[:, None]
    options = Options()
    ls = BlockLS(y, contiguous_folds(ROWS, options.folds))
    term = term or EffectTerm("spring", (0,))
    cols = {0: columns(q) if columns else np.column_stack([q, np.ones_like(q)])}
    noise = NoiseFloor(np.array([SIGMA_NM]), np.array([SIGMA_NM**2]))
    current = ls.evaluate([], np.ones(1))
    (verdict,) = _judge_all(
        ls, [term], lambda _: cols, [], np.ones(1), current, noise, 10, options, None,
        moved_mean=moved_mean,
    )  # fmt: skip
    return verdict


def test_a_mean_torque_that_moved_with_a_slope_below_the_noise_is_not_a_spring():
    # 4 σ of offset, 0.2 σ per radian: the slope holds 2 % of what the term takes
    def moved(q):
        return 4 * SIGMA_NM + 0.2 * SIGMA_NM * q

    assert _verdict(moved, moved_mean=False).accepted  # the whole term passes (i)-(iii)
    verdict = _verdict(moved, moved_mean=True)
    assert not verdict.accepted
    assert "not told from a moved mean torque" in verdict.implausible


# a coupling copies a neighbour's torque: here a gravity-like 1.0 + 0.05 sin q [N·m]
COUPLING = EffectTerm("wrist_coupling", (0,), {"from_joint": 1, "source": "torque"})


def _neighbour(q):
    return (1.0 + 0.05 * np.sin(3 * q))[:, None]


def test_a_mean_torque_that_moved_is_not_a_coupling_to_a_torque_with_a_mean():
    # 3 σ of offset: 6 % of the neighbour's torque, whose varying part is then 0.15 σ
    verdict = _verdict(lambda q: 0.06 * _neighbour(q)[:, 0] * (3 * SIGMA_NM / 0.06), True,
                       COUPLING, _neighbour)  # fmt: skip
    assert not verdict.accepted
    assert "not told from a moved mean torque" in verdict.implausible


def test_a_coupling_to_a_varying_torque_is_kept():
    def neighbour(q):
        return (0.3 + 2.0 * np.sin(3 * q))[:, None]

    verdict = _verdict(lambda q: 0.1 * neighbour(q)[:, 0], True, COUPLING, neighbour)
    assert verdict.accepted, verdict.implausible
    assert verdict.evaluation.solution.coef[COUPLING.key][0] == pytest.approx(0.1, rel=0.05)


@pytest.mark.parametrize("q0", [-0.5, 0.4, 1.5])
def test_a_spring_of_a_few_noise_levels_per_radian_is_kept(q0):
    # 3 σ per radian, the least the hard world draws over a training range of about a radian
    verdict = _verdict(lambda q: 3 * SIGMA_NM * (q - q0), moved_mean=True)
    assert verdict.accepted, verdict.implausible
    k = verdict.evaluation.solution.coef[verdict.term.key][0]
    assert k == pytest.approx(3 * SIGMA_NM, rel=0.1)


def test_a_spring_pushing_away_from_its_rest_angle_is_refused():
    verdict = _verdict(lambda q: -3 * SIGMA_NM * (q - 0.2), moved_mean=True)
    assert not verdict.accepted
    assert "pushing away from its rest angle" in verdict.implausible
