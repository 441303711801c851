"""Brakes that can be released with the servo off (issue 22), and the paper's baseline: the
operator drags the released arm along the demo's path."""

from __future__ import annotations

import dataclasses

import numpy as np

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
