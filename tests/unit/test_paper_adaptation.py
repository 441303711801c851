"""The paper's eqs. (28) and (30) together (control/rt/src/law/outer_loop.rs, PaperAdaptation).

The drive is eq. (19) averaged over a cycle: ``τ_m = K* (u₁ + Υ_I u₂)`` with u₁, u₂ the
cycle means of the velocity and position errors. These tests feed the law those means and
the torque a drive of known gains reports, and check what the module docstring claims: the
static gain K K_I converges whatever the excitation, ω̂ and Υ̂_I separately only where the
velocity error is a fair share of the command, the dead zone, the projection, and the
controller starting from the paper's Υ̂_I(0) with the commissioned static gain.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from example_cell import example_cell

from control._rt import OmegaAdaptation, OuterLoop, PaperAdaptation
from control.cell_config import load_control_config
from control.declared_model import DeclaredModel
from control.zero_moment_law import ZeroMomentController
from gateway.config import ConfigError

K = np.array([46.21, 66.18, 39.0])
KP = np.array([224.4, 375.3, 226.0])
KI = np.array([7479.0, 12510.0, 7532.0])
OMEGA, UPS = 1.0 / (K * KP), KI / KP
T = 0.004


def paper_loop(omega_scale, ups_scale, rate=1.0, dead_zone=(), floor=(1.0, 1.0, 1.0)):
    return OuterLoop(
        OMEGA * np.asarray(omega_scale), UPS * np.asarray(ups_scale), np.full(3, 0.05),
        np.full(3, 2.0), PaperAdaptation(rate, floor, dead_zone_nm=dead_zone),
    )  # fmt: skip


def drive(u1, u2, noise_nm=0.0, rng=None):
    """The motor torque the drive of (K, K_P, K_I) reports over a cycle of means u1, u2."""
    tau = K * KP * (u1 + UPS * u2)
    if noise_nm:
        tau = tau + rng.normal(0.0, noise_nm, tau.shape)
    return tau


def excite(loop, seconds, velocity_share, rng, noise_nm=0.0):
    """Cycles whose position error u₂ swings through the load (a few mrad) and whose velocity
    error u₁ is ``velocity_share`` of Υ_I u₂ in size, with its own phase."""
    for c in range(round(seconds / T)):
        t = c * T
        u2 = 0.004 * np.sin(2 * np.pi * 0.5 * t + np.arange(3)) + 0.002
        u1 = velocity_share * UPS * 0.004 * np.sin(2 * np.pi * 3.1 * t + 1.0 + np.arange(3))
        loop.adapt(u1.tolist(), u2.tolist(), drive(u1, u2, noise_nm, rng).tolist(), T)


def static_gain(loop):
    """K K_I ω̂ / Υ̂_I: 1 when the loop delivers the desired torque while holding a load."""
    return loop.omega * K * KI / loop.upsilon_i


@pytest.mark.parametrize(("omega_scale", "ups_scale"), [(1.2, 0.85), (0.8, 1.15), (1.0, 0.5)])
def test_a_velocity_error_of_a_fair_share_separates_omega_and_upsilon(omega_scale, ups_scale):
    """With u₁ as large as Υ_I u₂, ω̂ and Υ̂_I both converge to the drive's within 1 % in
    30 s, from either side, through the current's noise."""
    loop = paper_loop(omega_scale, ups_scale, rate=2.0, dead_zone=(0.0,) * 3)
    excite(loop, 30.0, 1.0, np.random.default_rng(0), noise_nm=0.5)
    np.testing.assert_allclose(loop.omega / OMEGA, 1.0, atol=0.01)
    np.testing.assert_allclose(loop.upsilon_i / UPS, 1.0, atol=0.01)


def test_teaching_excitation_converges_the_static_gain_but_not_the_two_apart():
    """In teaching u₁ is a few per cent of Υ_I u₂ (module docstring, "What the gradient cannot
    do quickly"): ω̂ 20 % high and Υ̂_I 4 % low, the static gain is within 1 % in 10 s, but
    after 20 s at u₁ = 3 % of Υ_I u₂ ω̂ and Υ̂_I are both still 5-10 % high (the static gain's
    correction shared between them in the ratio Λ : Λ_I, then a 70 s time constant)."""
    loop = paper_loop(1.2, 1.2 * 0.8)
    rng = np.random.default_rng(1)
    excite(loop, 10.0, 0.03, rng)
    np.testing.assert_allclose(static_gain(loop), 1.0, atol=0.01)
    excite(loop, 10.0, 0.03, rng)
    assert np.all((loop.omega / OMEGA > 1.05) & (loop.omega / OMEGA < 1.1))
    assert np.all((loop.upsilon_i / UPS > 1.05) & (loop.upsilon_i / UPS < 1.1))


def test_the_paper_start_with_the_commissioned_static_gain_converges_on_a_held_load():
    """The arm pinned against a stop (u₁ = 0, the operator's hand pushing: it does not enter
    the motor torque the law compares) with a static gain off by 25 %: the gain comes to 1
    and stays, ω̂ and Υ̂_I do not wander off together."""
    loop = paper_loop(1.25, 1.0)
    u1, u2 = np.zeros(3), np.array([0.003, -0.004, 0.001])
    for _ in range(round(10.0 / T)):
        loop.adapt(u1.tolist(), u2.tolist(), drive(u1, u2).tolist(), T)
    np.testing.assert_allclose(static_gain(loop), 1.0, atol=0.005)
    omega, ups = loop.omega, loop.upsilon_i
    for _ in range(round(10.0 / T)):
        loop.adapt(u1.tolist(), u2.tolist(), drive(u1, u2).tolist(), T)
    np.testing.assert_allclose(loop.omega, omega, rtol=2e-3)
    np.testing.assert_allclose(loop.upsilon_i, ups, rtol=2e-3)


def test_the_dead_zone_and_the_torque_floor_stop_the_adaptation():
    u1, u2 = np.zeros(3), np.array([0.003, -0.004, 1e-6])
    tau = drive(u1, u2)
    loop = paper_loop(1.02, 1.0, dead_zone=(1e4, 0.0, 0.0), floor=(1.0, 1.0, 100.0))
    for _ in range(200):
        loop.adapt(u1.tolist(), u2.tolist(), tau.tolist(), T)
    assert loop.omega[0] == OMEGA[0] * 1.02  # the error is inside its dead zone
    assert loop.omega[1] != OMEGA[1] * 1.02  # adapted
    assert loop.omega[2] == OMEGA[2] * 1.02  # |φ| under the joint's torque floor
    loop.set_dead_zone([1.0, 2.0, 3.0])  # 3 σ of the hold's torque noise, at least the floor
    assert loop.dead_zone_nm == [1e4, 6.0, 9.0]


def test_a_non_finite_cycle_is_no_step_and_the_estimates_stay_within_their_bounds():
    loop = paper_loop(1.0, 1.0, rate=20.0)
    nan = float("nan")
    loop.adapt([nan] * 3, [0.001] * 3, [10.0] * 3, T)
    loop.adapt([0.0] * 3, [0.001] * 3, [nan] * 3, T)
    np.testing.assert_array_equal(loop.omega, OMEGA)
    # a drive that reports far too much torque, for a long time: ω̂ and Υ̂_I stay in bounds
    for _ in range(round(60.0 / T)):
        loop.adapt([0.001] * 3, [0.001] * 3, [1e6] * 3, T)
    assert np.all(loop.omega >= OMEGA / 50 * (1 - 1e-12))
    ups = np.array(loop.upsilon_i)
    assert np.all((ups <= UPS * 50 * (1 + 1e-12)) & (ups > 0))


def test_eq28_alone_moves_only_omega_on_the_same_call():
    """OmegaAdaptation takes the cycle means the paper's laws take, and adapts ω̂ alone: fed a
    drive whose gain K* is 10 % above the commissioned one (Υ_I exact), ω̂ converges to 1/K*
    and Υ̂_I stays where it was."""
    eq28 = OuterLoop(OMEGA, UPS, np.full(3, 0.05), np.full(3, 2.0),
                     OmegaAdaptation(1.0, (1.0,) * 3))  # fmt: skip
    rng = np.random.default_rng(3)
    for c in range(round(10.0 / T)):
        u2 = 0.004 * np.sin(2 * np.pi * 0.5 * c * T + np.arange(3)) + 0.002
        u1 = 0.05 * UPS * 0.004 * np.sin(2 * np.pi * 3.1 * c * T + np.arange(3))
        eq28.adapt(u1.tolist(), u2.tolist(), (1.1 * drive(u1, u2, 0.5, rng)).tolist(), T)
    np.testing.assert_allclose(eq28.omega, OMEGA / 1.1, rtol=0.01)
    np.testing.assert_array_equal(eq28.upsilon_i, UPS)


@pytest.fixture(scope="module")
def cfg(tmp_path_factory):
    return load_control_config(example_cell(tmp_path_factory.mktemp("cell")))[0]


def test_the_paper_strategy_starts_from_its_upsilon_with_the_commissioned_static_gain(cfg):
    model = DeclaredModel.load(cfg.model)
    paper = dataclasses.replace(cfg, strategy="paper", paper_upsilon_i0_per_s=1.2)
    ctl = ZeroMomentController(paper, model)
    assert isinstance(ctl.loop.adaptation, PaperAdaptation)
    np.testing.assert_allclose(ctl.loop.upsilon_i, 1.2)
    commissioned = np.array(cfg.upsilon_i_per_s) / np.array(cfg.omega_rad_s_per_nm)
    np.testing.assert_allclose(
        np.array(ctl.loop.upsilon_i) / ctl.loop.omega, commissioned, rtol=1e-12
    )
    kept = ZeroMomentController(dataclasses.replace(cfg, strategy="paper"), model)
    np.testing.assert_allclose(kept.loop.upsilon_i, cfg.upsilon_i_per_s)


@pytest.mark.parametrize(
    ("key", "value"),
    [("paper_dead_zone_nm", (1.0, 2.0)), ("paper_upsilon_i0_per_s", -1.0),
     ("paper_adaptation_per_s", float("nan")), ("strategy", "papr")],
)  # fmt: skip
def test_a_bad_paper_setting_is_refused_naming_it(cfg, key, value):
    with pytest.raises(ConfigError, match=key if key != "strategy" else "strategy"):
        dataclasses.replace(cfg, **{key: value})
