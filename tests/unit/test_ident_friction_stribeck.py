"""A Stribeck curve of another shape than the family's is the friction's own (issue 46): the fit
gives the joint a Gaussian Stribeck rise where the data show one, and the effect search no
longer names a ``stribeck`` effect."""

from __future__ import annotations

import numpy as np

from control.identification.effect_candidates import candidates
from control.identification.effect_rules import Options
from control.identification.fit import fit_rigid_friction
from control.identification.lsq import BlockLS, contiguous_folds
from control.identification.terms import Context, FrictionTerm

RATE_HZ = 500.0


def _motion(seconds: float = 120.0) -> tuple[np.ndarray, np.ndarray]:
    """A slow two-tone motion, positions and velocities (T,): most of its rows below 0.1 rad/s
    pass through the Stribeck range."""
    t = np.arange(round(seconds * RATE_HZ)) / RATE_HZ
    q = 0.3 * np.sin(2 * np.pi * 0.05 * t) + 0.05 * np.sin(2 * np.pi * 0.31 * t + 1.0)
    return q, np.gradient(q, t)


def _fit(tau: np.ndarray, q: np.ndarray, dq: np.ndarray) -> FrictionTerm:
    y_base = np.sin(q)[None, :, None]  # one joint, one gravity-like column
    ctx = Context(q[:, None], dq[:, None], np.zeros((q.size, 1)), y_base=y_base)
    ls = BlockLS(tau[:, None], contiguous_folds(q.size, 5))
    return fit_rigid_friction(ls, ctx, "simple", np.ones(1), presliding_grid=()).terms[0]


def test_the_fit_takes_a_gaussian_rise_where_the_curve_has_one_and_not_where_it_has_none():
    rng = np.random.default_rng(5)
    q, dq = _motion()
    noise = 0.05 * rng.standard_normal(q.size)
    gravity = 12.0 * np.sin(q)
    coulomb, static, v_s = 2.0, 3.5, 0.02
    curve = coulomb + (static - coulomb) * np.exp(-((dq / v_s) ** 2))
    with_rise = _fit(gravity + curve * np.sign(dq) + noise, q, dq)
    assert with_rise.stribeck_rad_s is not None
    assert v_s / 2.2 <= with_rise.stribeck_rad_s <= v_s * 2.2  # the grid's neighbours of v_s
    # a Coulomb friction of the family's own shape (its smooth sign at a q_e of its grid)
    without = _fit(gravity + coulomb * np.tanh(dq / (2 * 0.02)) + noise, q, dq)
    assert without.stribeck_rad_s is None


def test_the_effect_search_offers_no_stribeck_effect():
    q, dq = _motion(10.0)
    ctx = Context(q[:, None], dq[:, None], np.zeros((q.size, 1)))
    residual = np.exp(-((dq / 0.02) ** 2))[:, None] * np.sign(dq)[:, None]
    names = {t.name for t in candidates(ctx, residual, [], Options())}
    assert "stribeck" not in names and "spring" in names
