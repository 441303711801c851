"""The plant with the truth's ``stiction`` (issue 22): a joint at rest holds against any torque
below its static level and breaks away above it; sliding, it meets the Coulomb level of the
Stribeck curve. The default plant's smooth law creeps instead (the last test)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from sim_bridge.config import load_sim_config
from sim_bridge.plant import Plant


def _released_without_gravity(seed: int = 0) -> Plant:

    plant = Plant(dataclasses.replace(load_sim_config(), plant_seed=seed, stiction=True))
    plant.model.opt.gravity[:] = 0.0
    return plant


def _push(plant: Plant, torque_nm: np.ndarray, seconds: float) -> None:
    """Servo off, brakes released, cylinders out of the way: only ``torque_nm`` and friction
    act on the joints (and inertia)."""
    # the cylinders' torque, which the plant holds over a cycle, replaced by ``torque_nm``
    plant.cylinders.torque_from_arms = lambda arms, p: torque_nm.copy()  # type: ignore[method-assign]
    for _ in range(round(seconds / (4 * plant.cfg.timestep_s))):
        plant.run(4, None, brakes_released=True)


@pytest.mark.parametrize("seed", [0, 7])
def test_a_joint_at_rest_holds_below_its_static_level_and_breaks_away_above(seed):
    plant = _released_without_gravity(seed)
    q0 = plant.q_rad
    static = plant.friction.dry_level_nm(q0, np.zeros(plant.n))
    assert np.all(static > 0.0)
    _push(plant, 0.5 * static, 1.0)
    # a smoothed sign (tanh(dq / 2 q_e)) would let it creep ~10 mrad/s here
    assert np.abs(plant.dq_rad_s).max() < 2e-4
    assert np.abs(plant.q_rad - q0).max() < 2e-4
    for j in range(plant.n):  # one at a time: the others' reactions would add to it
        plant = _released_without_gravity(seed)
        torque = np.zeros(plant.n)
        torque[j] = 1.3 * static[j]
        _push(plant, torque, 0.3)
        assert plant.dq_rad_s[j] > 0.01, f"J{j + 1} slides above its static level"


def test_sliding_meets_the_coulomb_level_and_the_stribeck_drop():
    plant = _released_without_gravity()
    static = plant.friction.dry_level_nm(plant.q_rad, np.zeros(plant.n))
    fast = plant.friction.dry_level_nm(plant.q_rad, np.full(plant.n, 1.0))
    coulomb = plant.friction.coulomb_level(plant.q_rad)
    np.testing.assert_allclose(fast, coulomb, rtol=1e-6)
    assert np.all(static > coulomb)
    # between the Coulomb and the static level a resting joint stays, a sliding one goes on
    plant = _released_without_gravity()
    between = 0.5 * (static + coulomb)
    _push(plant, between, 0.5)
    assert np.abs(plant.dq_rad_s).max() < 2e-4
    plant.data.qvel[: plant.n] = 0.2
    _push(plant, between, 0.2)
    assert np.all(plant.dq_rad_s > 0.1)


def test_the_viscous_friction_is_joint_damping_at_the_cycle_velocity():
    plant = _released_without_gravity()
    v = np.array([0.0, 0.1, -0.2, 0.5, -1.0, 2.0])
    expected = plant.friction.v1 + plant.friction.v2 * np.abs(v)
    np.testing.assert_allclose(plant.friction.damping_nm_s_per_rad(v), expected)


def test_the_smooth_law_creeps_where_stiction_holds_and_stiction_is_the_default():
    assert Plant(dataclasses.replace(load_sim_config(), plant_seed=0)).stiction
    plant = Plant(dataclasses.replace(load_sim_config(), plant_seed=0, stiction=False))
    plant.model.opt.gravity[:] = 0.0
    static = plant.friction.dry_level_nm(plant.q_rad, np.zeros(plant.n))
    _push(plant, 0.5 * static, 1.0)
    assert np.abs(plant.dq_rad_s).min() > 2e-3
