"""Friction with memory (issue 46): the Dahl state over the joint's travel stands for the sign of
the velocity, the joint holds its last friction at rest, and the fit takes memory only where the
data show it."""

from __future__ import annotations

import numpy as np
import pytest

from control.identification.fit import fit_rigid_friction, rechoose_options
from control.identification.friction_law import friction_memory, linear_recurrence
from control.identification.lsq import BlockLS, contiguous_folds
from control.identification.terms import (
    Context,
    FrictionTerm,
)

RATE_HZ = 500.0


def test_the_scan_is_the_loop():
    rng = np.random.default_rng(0)
    a, b = rng.uniform(0.0, 1.0, 3001), rng.normal(size=3001)
    z, loop = 0.0, []
    for ak, bk in zip(a, b, strict=True):
        z = ak * z + bk
        loop.append(z)
    np.testing.assert_allclose(linear_recurrence(a, b), loop, atol=1e-12)


def test_direction_turns_round_over_the_presliding_travel_and_holds_at_rest():
    x_c = 1e-3
    # out 0.05 rad, rest, back 0.05 rad: positions on a fine grid
    out = np.linspace(0.0, 0.05, 501)
    q = np.r_[out, np.full(200, 0.05), out[::-1]]
    dq = np.r_[np.full(501, 0.1), np.zeros(200), np.full(501, -0.1)]
    z = friction_memory(q, dq, 0.0, x_c)[0]
    assert z[500] == pytest.approx(1.0, abs=1e-9)  # sliding: the velocity's sign
    np.testing.assert_allclose(z[501:701], z[500])  # held at rest
    back = 701 + np.searchsorted(-q[701:] + 0.05, [x_c, 3 * x_c])
    # Dahl: after a travel x back, z = -1 + 2 exp(-x / x_c)
    assert z[back[0]] == pytest.approx(-1.0 + 2.0 * np.exp(-1.0), abs=0.02)
    assert z[back[1]] == pytest.approx(-1.0 + 2.0 * np.exp(-3.0), abs=0.02)
    assert z[-1] == pytest.approx(-1.0, abs=1e-9)


def test_position_noise_at_rest_does_not_wear_the_held_direction_away():
    """A resting joint's positions wander by their noise (a low-passed encoder: about a
    micro-radian); weighted by the probability that the joint moves, that wander does not drive
    the state (unweighted, it decays towards 0: a step against the direction moves it twice as
    far as one with it)."""
    rng = np.random.default_rng(3)
    sigma_dq = 2e-3
    move = np.linspace(0.0, 0.02, 201)
    q = np.r_[move, 0.02 + 1e-6 * rng.standard_normal(2000)]
    dq = np.r_[np.full(201, 0.1), sigma_dq * rng.standard_normal(2000)]
    weighted = friction_memory(q, dq, sigma_dq, 3e-5)[0]
    unweighted = friction_memory(q, dq, 0.0, 3e-5)[0]
    # the probability of motion is not zero at rest: the smallest presliding travel loses a few
    # per cent over 4 s of rest, against most of it unweighted
    assert weighted[-1] > 0.9
    assert unweighted[-1] < 0.5


def test_memory_stands_for_the_sign_in_every_column_that_carries_it():
    q = np.linspace(0.0, 0.1, 50)[:, None]
    dq = np.full((50, 1), 0.2)
    seq = Context(q, dq, np.zeros_like(dq))
    point = Context(q, dq, np.zeros_like(dq), sequence=False)
    for kind in ("eq15", "eq14", "simple"):
        memory = FrictionTerm(0, kind, 0.01, 100.0, presliding_rad=1e-3)
        plain = FrictionTerm(0, kind, 0.01, 100.0)
        # after 50 x_c of sliding the state is the sign: the memoryless columns
        np.testing.assert_allclose(
            memory.columns(seq)[0][-1], plain.columns(seq)[0][-1], rtol=1e-6, atol=1e-9
        )
        # unrelated rows (a single state at run time) slide: the family's own sign
        np.testing.assert_allclose(memory.columns(point)[0], plain.columns(point)[0])
        assert memory.parameters(np.zeros(len(plain.columns(seq)[0][0])))["presliding_rad"] == 1e-3


def _teaching_motion(seconds: float = 120.0) -> tuple[np.ndarray, np.ndarray]:
    """A multisine interrupted by rests, at RATE_HZ: positions and velocities (T,)."""
    t = np.arange(round(seconds * RATE_HZ)) / RATE_HZ
    clock = np.cumsum(np.where((t % 10.0) < 7.0, 1.0, 0.0)) / RATE_HZ  # stops 3 s in 10
    q = 0.4 * np.sin(2 * np.pi * 0.21 * clock) + 0.15 * np.sin(2 * np.pi * 0.53 * clock + 1.0)
    return q, np.gradient(q, t)


def _dahl_loop(q: np.ndarray, f_c: float, x_c: float) -> np.ndarray:
    """Dahl's friction along positions q, explicit steps on a 20x finer travel (the test's own
    integration, not the product's)."""
    z, out = 0.0, np.empty(q.size)
    out[0] = 0.0
    for k in range(1, q.size):
        for dx in np.full(20, (q[k] - q[k - 1]) / 20.0):
            z += dx / x_c * (1.0 - z * np.sign(dx))
        out[k] = f_c * z
    return out


def _fit(tau: np.ndarray, q: np.ndarray, dq: np.ndarray) -> FrictionTerm:
    y_base = np.sin(q)[None, :, None]  # one joint, one gravity-like column
    ctx = Context(q[:, None], dq[:, None], np.zeros((q.size, 1)), y_base=y_base)
    ls = BlockLS(tau[:, None], contiguous_folds(q.size, 5))
    fit = fit_rigid_friction(ls, ctx, "simple", np.ones(1))
    return fit.terms[0]


def test_the_fit_takes_memory_where_the_friction_has_it_and_not_where_it_has_none():
    rng = np.random.default_rng(7)
    q, dq = _teaching_motion()
    noise = 0.05 * rng.standard_normal(q.size)
    gravity = 12.0 * np.sin(q)
    with_memory = _fit(gravity + _dahl_loop(q, 3.0, 5e-4) + noise, q, dq)
    assert with_memory.presliding_rad is not None
    assert 1.5e-4 <= with_memory.presliding_rad <= 1.5e-3  # the grid's points about 5e-4
    without = _fit(gravity + 3.0 * np.sign(dq) + noise, q, dq)
    assert without.presliding_rad is None


def test_a_motion_cut_in_pieces_carries_its_direction_across_the_cut():
    """``leadthrough predict`` evaluates a file stretch by stretch and chunk by chunk; each
    piece starting from the last one's end gives the whole motion's direction."""
    t = np.linspace(0.0, 6.0, 3001)
    q, dq = 0.01 * np.sin(2.0 * t), 0.02 * np.cos(2.0 * t)
    whole = friction_memory(q, dq, 1e-3, 2e-4)[0]
    first = friction_memory(q[:1200], dq[:1200], 1e-3, 2e-4)[0]
    # the second piece starts from the first one's last state and position
    second = friction_memory(q[1200:], dq[1200:], 1e-3, 2e-4, first[-1], q[1199])[0]
    np.testing.assert_allclose(np.r_[first, second], whole, atol=1e-12)
    assert not np.allclose(friction_memory(q[1200:], dq[1200:], 1e-3, 2e-4)[0], whole[1200:])


def _with_ripple(tau: np.ndarray, q: np.ndarray, dq: np.ndarray) -> tuple:
    """The fit of ``tau`` (a gear ripple in it the fit does not know), then the ripple's columns
    added to its least squares and the options chosen again: (first term, term after)."""
    y_base = np.sin(q)[None, :, None]
    ctx = Context(q[:, None], dq[:, None], np.zeros((q.size, 1)), y_base=y_base)
    ls = BlockLS(tau[:, None], contiguous_folds(q.size, 5))
    fit = fit_rigid_friction(ls, ctx, "simple", np.ones(1))
    ls.add("ripple", {0: np.column_stack([np.sin(51 * q), np.cos(51 * q)])})
    names = [*fit.names, "ripple"]
    again = rechoose_options(ls, ctx, names, fit.weights, fit.terms[0])
    # the least squares holds the chosen term's columns
    np.testing.assert_array_equal(ls.cols[again.key][0], again.columns(ctx)[0])
    return fit.terms[0], again


def test_options_are_chosen_again_once_an_effect_takes_its_share_of_the_residual():
    rng = np.random.default_rng(11)
    q, dq = _teaching_motion()
    noise = 0.05 * rng.standard_normal(q.size)
    ripple = 6.0 * np.sin(51 * q + 0.7)
    base = 12.0 * np.sin(q) + ripple + noise
    _, again = _with_ripple(base + _dahl_loop(q, 3.0, 5e-4), q, dq)
    assert again.presliding_rad is not None
    assert 1.5e-4 <= again.presliding_rad <= 1.5e-3
    _, again = _with_ripple(base + 3.0 * np.sign(dq), q, dq)
    assert again.presliding_rad is None
