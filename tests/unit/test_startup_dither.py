"""The admittance's start-up dither (control/rt/src/law/admittance/startup_dither.rs): its
sine on each resting joint, and the admittance that adds back what the drive gave of it, so a
stuck arm stays where it is."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from example_cell import ADMITTANCE_ALONE, example_control

from control._rt import STARTUP_DITHER_FADE_S as FADE_S
from control._rt import StartupDither
from control.admittance_law import AdmittanceController
from control.declared_model import DeclaredModel
from gateway.errors import ConfigError
from gateway.message_factories import make_joint_state
from gateway.messages import ControllerState

N = 6
DT = 0.004
REST = 2e-3
LEVEL = np.array([40.0, 60.0, 30.0, 8.0, 5.0, 0.0])


def run(d: StartupDither, seconds: float, dq_r=None) -> np.ndarray:
    dq_r = np.zeros(N) if dq_r is None else np.asarray(dq_r, dtype=float)
    return np.array([d.step(dq_r, DT) for _ in range(round(seconds / DT))])


def test_off_it_gives_nothing():
    d = StartupDither(0.0, 4.0, REST, 0)
    d.reset(LEVEL)
    assert not run(d, 1.0).any()
    assert not np.any(d.drove())


def test_it_fades_in_then_swings_each_joint_by_its_share_of_the_friction_level():
    d = StartupDither(0.5, 4.0, REST, 0)
    d.reset(LEVEL)
    first = np.array(d.step(np.zeros(N), DT))
    assert np.all(np.abs(first) <= 0.5 * LEVEL * DT / FADE_S + 1e-12)
    run(d, FADE_S)
    swing = run(d, 1.0)  # four periods at full gain
    # the largest sample of a 4 Hz sine sampled every 4 ms is within cos(pi 4 0.004) of its peak
    peak = np.abs(swing).max(axis=0)
    np.testing.assert_allclose(peak, 0.5 * LEVEL, rtol=1 - math.cos(math.pi * 4 * DT))
    assert np.all(peak <= 0.5 * LEVEL + 1e-12)
    # the joints' phases are spread: they do not all push at once
    assert np.argmax(swing[:, 0]) != np.argmax(swing[:, 1])


def test_a_joint_whose_reference_moves_gets_none_and_one_at_the_rest_speed_half():
    d = StartupDither(0.5, 4.0, REST, 0)
    d.reset(LEVEL)
    run(d, FADE_S)
    speeds = np.array([0.0, REST, 1.5 * REST, 2.0 * REST, -0.1, 1.0])
    peak = np.abs(run(d, 1.0, speeds)).max(axis=0)
    tol = 1 - math.cos(math.pi * 4 * DT)
    np.testing.assert_allclose(peak[:3], [20.0, 30.0, 7.5], rtol=tol)
    assert not peak[3:].any()


def test_what_drove_a_state_is_the_dither_sent_delay_plus_one_cycles_before():
    d = StartupDither(0.5, 4.0, REST, 2)
    d.reset(LEVEL)
    sent = []
    for k in range(10):
        drove = np.array(d.drove())
        if k < 3:
            assert not drove.any()
        else:
            np.testing.assert_array_equal(drove, sent[k - 3])
        sent.append(d.step(np.zeros(N), DT))
    d.reset(LEVEL)
    assert not np.any(d.drove())


@pytest.mark.parametrize(("share", "hz", "match"), [(1.0, 4.0, "share"),
                                                     (float("nan"), 4.0, "share"),
                                                     (0.5, 0.0, "Hz")])  # fmt: skip
def test_bad_settings_are_refused(share, hz, match):
    with pytest.raises(ValueError, match=match):
        StartupDither(share, hz, REST, 0)


@pytest.fixture(scope="module")
def cfg(tmp_path_factory):
    # the law alone with the dither: no stick zone, which would hide a swing of the estimate
    # within the friction level (the estimate itself is judged), against a dead zone of 1 N·m
    # (a model's held-out error; the example model declares none)
    return example_control(tmp_path_factory.mktemp("cell"),
                           **ADMITTANCE_ALONE | {"rest_hold_nm": (1.0,) * N,
                                                 "admittance_dither": 0.5,
                                                 "admittance_dither_hz": 4.0})  # fmt: skip


@pytest.mark.parametrize(("key", "value"), [("admittance_dither", 1.0),
                                            ("admittance_dither", -0.1),
                                            ("admittance_dither_hz", 0.0),
                                            ("admittance_dither_hz", float("nan"))])  # fmt: skip
def test_a_bad_dither_is_refused_by_name(cfg, key, value):
    with pytest.raises(ConfigError, match=key):
        dataclasses.replace(cfg, **{key: value})


def test_a_stuck_arm_whose_drives_give_the_dither_stays_where_it_is(cfg):
    """Every joint stuck at Q0: each state's current is what the vendor loop gives on the
    offset of the command before it (the example cell's delay is 0), Υ̂_I / ω̂ of it, as at
    rest a drive does. The command swings each joint by ω̂ × half its friction level / Υ̂_I,
    and the law reads no hand from the swing: the reference never moves (without the
    dither added back to the estimate it does: the swing reads as a push)."""
    model = DeclaredModel.load(cfg.model)
    ctl = AdmittanceController(cfg, model)
    assert cfg.command_delay_cycles == 0
    k_nm_per_a = np.array([j.drive_gain_nm_per_a for j in model.desc.joints])
    q0 = np.linspace(-0.2, 0.3, N)
    p = [5.0, 5.0]
    static = model.gravity_nm(q0) - model.cylinder_nm(q0, np.array(p))
    level = ctl.friction_level_nm(q0)
    assert np.count_nonzero(level) >= 3, "the example model needs friction for this test"
    omega, upsilon = np.asarray(ctl.loop.omega), np.asarray(ctl.loop.upsilon_i)
    tau = static.copy()
    swing = []
    for k in range(1, round(3.0 / DT)):
        st = make_joint_state(k, DT * k, ControllerState.EXTERNAL, 0, q0, np.zeros(N),
                              tau / k_nm_per_a, q0, np.zeros(N), DT)  # fmt: skip
        q_cmd, dq_cmd = ctl.answer(st, p)
        assert not np.any(dq_cmd), k
        np.testing.assert_array_equal(ctl.admittance.q_r, q0)
        assert np.all(np.abs(ctl.admittance.tau_h) < 1e-6), (k, ctl.admittance.tau_h)
        tau = (np.array(q_cmd) - q0) * upsilon / omega
        swing.append(np.array(q_cmd) - q0 - omega * static / upsilon)
    peak = np.abs(np.array(swing[round(1.0 / DT) :])).max(axis=0)
    want = omega * 0.5 * level / upsilon
    np.testing.assert_allclose(peak, want, rtol=0.01, atol=1e-12)
