"""Brakes that can be released with the servo off (issue 22), and the paper's baseline: the
operator drags the released arm along the demo's path."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from sim_bridge.baseline import run_baseline
from sim_bridge.config import load_sim_config
from sim_bridge.demo import BASELINE_STIFF_HAND, DEMO_PATH, HAND
from sim_bridge.plant import Plant


def _run(plant: Plant, seconds: float, released: bool) -> None:
    for _ in range(round(seconds / plant.cfg.timestep_s)):
        plant.step(None, None, brakes_released=released)


def test_held_brakes_lock_the_arm_and_released_ones_let_it_fall():
    plant = Plant(load_sim_config())
    q0 = plant.q_rad
    _run(plant, 0.3, released=False)
    np.testing.assert_array_equal(plant.q_rad, q0)
    assert plant.brakes
    _run(plant, 0.3, released=True)
    assert not plant.brakes
    assert np.abs(plant.q_rad - q0)[1:3].max() > 0.01, "gravity moves the released arm"
    assert np.all(plant.current_a == 0.0) and np.all(plant.tau_motor_nm == 0.0)


def test_baseline_needs_far_more_force_than_a_hand_gives():
    cfg = load_sim_config()
    path = [w for w in DEMO_PATH if w[0] <= 7.0]  # the first stroke, 0.3 m along x
    human = run_baseline(cfg, path, HAND, 7.0)
    stiff = run_baseline(cfg, path, BASELINE_STIFF_HAND, 7.0)
    assert human["force_saturated_share"] > 0.5
    assert human["max_tool_off_path_m"] > 0.2  # the hand cannot hold the falling arm
    # a hand that can keeps the tool on the path, and it takes hundreds of newtons
    assert stiff["max_tool_off_path_m"] < 0.05
    assert 200.0 < stiff["mean_force_n"] <= stiff["peak_force_n"]


def test_the_baseline_of_another_plant_differs():
    cfg = load_sim_config()
    path = [w for w in DEMO_PATH if w[0] <= 2.0]
    a = run_baseline(cfg, path, BASELINE_STIFF_HAND, 2.0)
    b = run_baseline(dataclasses.replace(cfg, plant_seed=5), path, BASELINE_STIFF_HAND, 2.0)
    assert b["plant_seed"] == 5
    assert abs(a["mean_force_n"] - b["mean_force_n"]) > 1.0


def _moving(plant: Plant, dq: np.ndarray, seconds: float) -> None:
    """Servo the arm along ``dq`` from where it is for ``seconds``."""
    q0, t0 = plant.q_rad.copy(), plant.t_s
    for _ in range(round(seconds / plant.cfg.timestep_s)):
        plant.step(q0 + dq * (plant.t_s - t0), dq)


def _cut(plant: Plant, seconds: float, power_cut: bool) -> np.ndarray:
    """Servo off for ``seconds``; the positions of every tick, (ticks, n)."""
    qs = []
    for _ in range(round(seconds / plant.cfg.timestep_s)):
        plant.step(None, None, power_cut=power_cut)
        qs.append(plant.q_rad.copy())
    return np.array(qs)


DQ = np.array([0.3, 0.15, -0.15, 0.5, 0.5, 0.5])


def test_a_power_cut_lets_the_arm_move_until_the_brakes_bite_then_they_stop_it():
    """Stop category 0 on the virtual plant ([brakes], issue 10): the joints coast on for
    the engagement time (0.1 s, seed 0), then each brake's torque stops its joint, which it
    then holds."""
    plant = Plant(load_sim_config())
    _moving(plant, DQ, 0.3)
    engage = plant.cfg.brakes.engage_s
    q_cut = plant.q_rad.copy()
    qs = _cut(plant, 0.6, power_cut=True)
    dt = plant.cfg.timestep_s
    bite = round(engage / dt) - 1
    during = qs[bite] - q_cut
    # J1 (heavy, little gravity on it) carries on at nearly its speed until the brakes bite
    assert during[0] == pytest.approx(DQ[0] * engage, rel=0.3)
    assert plant.brakes, "every joint stands on its brake"
    np.testing.assert_array_equal(qs[-1], qs[-200])
    # after the bite J1 stops within a braking distance: 0.25 rad/s on its brake's 900 N·m
    braked = abs(qs[-1, 0] - qs[bite, 0])
    assert 0.0 < braked < 0.02, braked
    stopped = np.flatnonzero(np.any(np.diff(qs, axis=0) != 0.0, axis=1))[-1] * dt
    assert engage < stopped < engage + 0.2, stopped


def test_a_servo_off_the_host_asks_for_closes_the_brakes_first():
    plant = Plant(load_sim_config())
    _moving(plant, np.zeros(6), 0.2)  # holding still
    q = plant.q_rad.copy()
    qs = _cut(plant, 0.3, power_cut=False)
    np.testing.assert_allclose(qs[-1], q, atol=1e-4)  # the hold's dither, braked
    # a power cut at rest: gravity moves J2/J3 until the brakes bite
    plant = Plant(load_sim_config())
    _moving(plant, np.zeros(6), 0.2)
    q = plant.q_rad.copy()
    qs = _cut(plant, 0.3, power_cut=True)
    assert np.abs(qs[-1] - q)[1:3].max() > 1e-4, "the arm sags until the brakes bite"


def test_ideal_brakes_lock_at_once_and_other_seeds_draw_their_brakes():
    cfg = load_sim_config()
    plant = Plant(dataclasses.replace(cfg, brakes=dataclasses.replace(cfg.brakes, torque_nm=())))
    _moving(plant, DQ, 0.2)
    q = plant.q_rad.copy()
    np.testing.assert_array_equal(_cut(plant, 0.1, power_cut=True)[-1], q)
    drawn = Plant(dataclasses.replace(cfg, plant_seed=3)).cfg.brakes
    assert drawn.engage_s != cfg.brakes.engage_s and 0.07 <= drawn.engage_s <= 0.13
    ratio = np.divide(drawn.torque_nm, cfg.brakes.torque_nm)
    assert np.all((ratio >= 0.8) & (ratio <= 1.2)) and len(set(ratio.round(6))) == 6
