"""The virtual cell's cylinders compress their gas as the rod moves (isothermal, refilled by the
regulator with its lag) and its current sensors read a zero offset, servo on or off."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from sim_bridge.config import load_sim_config
from sim_bridge.physics import ATMOSPHERE_BAR, AssistCylinders
from sim_bridge.plant import Plant
from sim_bridge.truth import draw


def _move_j2(plant: Plant, dq: float, steps: int) -> None:
    q = plant.q_rad
    dt = plant.cfg.timestep_s
    for k in range(steps):
        target = q.copy()
        target[1] += dq * (k + 1) * dt
        cmd = np.zeros(plant.n)
        cmd[1] = dq
        plant.step(target, cmd)


def test_moving_the_crank_changes_its_pressure_and_the_regulator_restores_it():
    cfg = load_sim_config()
    unit = cfg.cylinders.units[0]
    slow = dataclasses.replace(cfg.cylinders, time_constant_s=1e6)  # no refill: pure gas
    plant = Plant(dataclasses.replace(cfg, cylinders=slow))
    q2_0 = plant.q_rad[1]
    p0 = plant.pressure_bar[0] + ATMOSPHERE_BAR
    _move_j2(plant, 0.4, 500)
    q2_1 = plant.q_rad[1]
    assert abs(q2_1 - q2_0) > 0.1
    v0, v1 = (unit.gas_length_m + AssistCylinders.extension_m(unit, q) for q in (q2_0, q2_1))
    # p V constant, to within the one timestep the pressure update trails the rod
    assert (plant.pressure_bar[0] + ATMOSPHERE_BAR) * v1 == pytest.approx(p0 * v0, rel=2e-4)
    assert (plant.pressure_bar[0] + ATMOSPHERE_BAR) != pytest.approx(p0, rel=1e-2)

    plant = Plant(cfg)  # the regulator's lag: a dip or rise while moving, back at rest
    _move_j2(plant, 0.4, 500)
    moved = plant.pressure_bar[0] - plant.pressure_set_bar[0]
    assert abs(moved) > 0.02
    for _ in range(3000):  # on the brakes: the rod at rest
        plant.step(None, None)
    assert abs(plant.pressure_bar[0] - plant.pressure_set_bar[0]) < 0.01 * abs(moved)


def test_extension_grows_by_the_moment_arm_per_radian():
    cfg = load_sim_config()
    for unit in cfg.cylinders.units:
        for q in (-0.8, 0.0, 0.5):
            h = 1e-6
            slope = (AssistCylinders.extension_m(unit, q + h)
                     - AssistCylinders.extension_m(unit, q - h)) / (2 * h)  # fmt: skip
            assert slope == pytest.approx(AssistCylinders.moment_arm_m(unit, q), rel=1e-5)


def test_the_per_cycle_pass_is_the_geometry_of_each_unit():
    """AssistCylinders.arms_and_gas (what the plant calls every cycle) against moment_arm_m
    and extension_m, one unit at a time, over the joints' range."""
    cfg = load_sim_config()
    cylinders = AssistCylinders(cfg.cylinders.units, 6)
    for q in np.random.default_rng(3).uniform(-2.5, 2.5, (200, 6)):
        arms, gas = cylinders.arms_and_gas(q.tolist())
        for unit, arm, column in zip(cylinders.units, arms, gas, strict=True):
            qj = q[unit.joint - 1]
            assert arm == pytest.approx(AssistCylinders.moment_arm_m(unit, qj), abs=1e-12)
            if unit.gas_length_m > 0:
                want = max(unit.gas_length_m + AssistCylinders.extension_m(unit, qj),
                           0.1 * unit.gas_length_m)  # fmt: skip
                assert column == pytest.approx(want, abs=1e-12)
            else:
                assert column == float("inf")


def test_currents_read_the_sensor_offset_with_the_brakes_on():
    cfg = load_sim_config()
    offsets = (0.07, -0.21, 0.15, 0.018, -0.008, 0.006)
    cfg = dataclasses.replace(
        cfg, sensors=dataclasses.replace(cfg.sensors, current_offset_a=offsets)
    )
    plant = Plant(cfg)
    mean = np.mean([(plant.step(None, None), plant.measured_current_a())[1]
                    for _ in range(2000)], axis=0)  # fmt: skip
    np.testing.assert_allclose(mean, cfg.sensors.current_offset_a, atol=3e-3)


def test_other_seeds_draw_offsets_and_gas_volumes_within_their_ranges():
    cfg = load_sim_config()
    cfg = dataclasses.replace(
        cfg, sensors=dataclasses.replace(cfg.sensors, current_offset_fraction=0.005)
    )
    limit = np.array(cfg.drives.max_current_a)
    seen = []
    for seed in (1, 2, 3):
        d = draw(dataclasses.replace(cfg, plant_seed=seed))
        off = np.array(d.sensors.current_offset_a)
        assert np.all(np.abs(off) <= cfg.sensors.current_offset_fraction * limit)
        seen.append(off)
        for u, u0 in zip(d.cylinders.units, cfg.cylinders.units, strict=True):
            assert u.gas_length_m == pytest.approx(u0.gas_length_m, rel=0.1)
            assert u.gas_length_m != u0.gas_length_m
    assert not np.allclose(seen[0], seen[1])
