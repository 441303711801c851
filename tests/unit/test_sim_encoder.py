"""The virtual drives measure through encoders: positions in steps of 2π / (2^bits · R), the
velocity their difference over the last servo tick. (The PI loop of eq. (19) is MuJoCo's
actuator on the joint's state: a 20-bit encoder's step, ~4e-8 rad, is far below anything it
responds to.)"""

from __future__ import annotations

import dataclasses

import numpy as np

from sim_bridge.config import load_sim_config
from sim_bridge.plant import Plant


def test_positions_are_encoder_steps_and_velocity_their_difference_per_tick():
    cfg = load_sim_config()
    plant = Plant(cfg)
    step = 2.0 * np.pi / (2.0**cfg.sensors.encoder_bits * np.array(cfg.drives.gear_ratio))
    q0 = plant.q_rad
    dq_cmd = np.array([0.05, -0.03, 0.02, 0.1, -0.1, 0.2])
    for k in range(200):
        t = (k + 1) * cfg.timestep_s
        prev = plant.sample_q_rad.copy()
        plant.step(q0 + dq_cmd * t, dq_cmd)
        counts = plant.sample_q_rad / step
        np.testing.assert_allclose(counts, np.round(counts), atol=1e-6)
        np.testing.assert_allclose(
            plant.sample_dq_rad_s, (plant.sample_q_rad - prev) / cfg.timestep_s, rtol=1e-12
        )
    # the reported position stays within half a step of the true one
    assert np.all(np.abs(plant.sample_q_rad - plant.q_rad) <= 0.5 * step + 1e-15)
    # the drive follows the commanded velocity through its encoder
    assert np.all(np.abs(plant.dq_rad_s - dq_cmd) < 0.02)


def test_zero_bits_is_an_exact_measurement():
    cfg = load_sim_config()
    cfg = dataclasses.replace(cfg, sensors=dataclasses.replace(cfg.sensors, encoder_bits=0))
    plant = Plant(cfg)
    plant.step(plant.q_rad, np.full(6, 0.01))
    np.testing.assert_array_equal(plant.sample_q_rad, plant.q_rad)
    np.testing.assert_array_equal(plant.sample_dq_rad_s, plant.dq_rad_s)
