"""A virtual robot drawn from a seed: ``leadthrough sim --plant-seed N``.

Seed 0 is the truth as written (``gr630st_truth.toml`` and the arm's MJCF, the documented
default plant). Any other seed draws, independently per value and uniformly within:

- inner-loop PI gains K_p, K_I: ±50 % (:data:`INNER_GAINS`);
- joint friction, every coefficient and the Stribeck velocity: ±40 % (:data:`FRICTION`);
- link masses ±15 % (the inertia about the COM scales with the mass) and each coordinate of a
  link's centre of mass by up to ±15 % of its distance from the joint frame (:data:`INERTIALS`);
- assist cylinders, bore, linkage lengths and pressure lag: ±10 % (:data:`CYLINDERS`), and
  each chamber's gas volume, likewise (its own stream);
- drive torque constants K: ±7 % (:data:`TORQUE_CONSTANTS`), a datasheet's tolerance: the
  product converts current to torque with the datasheet's value, so its every torque is off
  by the same factor per joint;
- current-sensor zero offsets: uniformly within ± ``[sensors] current_offset_fraction`` of
  each joint's current limit (a drive's tolerance is about 0.5 %; 0 by default), in every
  current it reports;
- the brakes' engagement time ±30 % (:data:`BRAKE_ENGAGE`) and each brake's torque ±20 %
  (:data:`BRAKE_TORQUE`).

Each group draws from its own stream (``numpy.random.default_rng([seed, group])``), so a
change to one group's draws leaves the others' as they were. Current limits, sensors,
kinematics and the command protocol are not drawn.
"""

from __future__ import annotations

import dataclasses

import mujoco
import numpy as np

from sim_bridge.config import SimConfig, arm_mjcf_path

INNER_GAINS = 0.50
FRICTION = 0.40
INERTIALS = 0.15
CYLINDERS = 0.10
TORQUE_CONSTANTS = 0.07
BRAKE_ENGAGE = 0.30
BRAKE_TORQUE = 0.20
_GAINS, _FRICTION, _INERTIALS, _CYLINDERS, _TORQUE_CONSTANTS, _GAS, _CURRENT_OFFSETS = range(1, 8)
_BRAKES = 8


def _factors(seed: int, group: int, shape: int | tuple[int, ...], spread: float) -> np.ndarray:
    rng = np.random.default_rng([seed, group])
    return rng.uniform(1.0 - spread, 1.0 + spread, shape)


def draw(cfg: SimConfig) -> SimConfig:
    """``cfg`` with its inner gains, friction, cylinders, torque constants and current-sensor
    offsets drawn for
    ``cfg.plant_seed`` (seed 0: ``cfg`` itself). The inertials are drawn by :func:`arm_spec`."""
    seed = cfg.plant_seed
    if seed == 0:
        return cfg
    n = len(cfg.inner_loop.kp_a_s_per_rad)
    g = _factors(seed, _GAINS, (2, n), INNER_GAINS)
    inner = dataclasses.replace(
        cfg.inner_loop,
        kp_a_s_per_rad=tuple(float(v) for v in np.multiply(cfg.inner_loop.kp_a_s_per_rad, g[0])),
        ki_a_per_rad=tuple(float(v) for v in np.multiply(cfg.inner_loop.ki_a_per_rad, g[1])),
    )
    f = _factors(seed, _FRICTION, (n, 11), FRICTION)
    friction = tuple(
        dataclasses.replace(
            ft,
            tau_s_nm=ft.tau_s_nm * f[j, 0],
            tau_c_nm=ft.tau_c_nm * f[j, 1],
            tau_v1_nm_s_per_rad=ft.tau_v1_nm_s_per_rad * f[j, 2],
            tau_v2_nm_s2_per_rad2=ft.tau_v2_nm_s2_per_rad2 * f[j, 3],
            q_e_rad_s=ft.q_e_rad_s * f[j, 4],
            fourier_nm=tuple(float(v) for v in np.multiply(ft.fourier_nm, f[j, 5:])),
        )
        for j, ft in enumerate(cfg.friction)
    )
    units = cfg.cylinders.units
    c = _factors(seed, _CYLINDERS, (len(units) + 1, 3), CYLINDERS)
    cylinders = dataclasses.replace(
        cfg.cylinders,
        time_constant_s=cfg.cylinders.time_constant_s * c[-1, 0],
        units=tuple(
            dataclasses.replace(
                u,
                piston_diameter_m=u.piston_diameter_m * c[k, 0],
                ab_m=u.ab_m * c[k, 1],
                ac_m=u.ac_m * c[k, 2],
            )
            for k, u in enumerate(units)
        ),
    )
    k = _factors(seed, _TORQUE_CONSTANTS, n, TORQUE_CONSTANTS)
    drives = dataclasses.replace(
        cfg.drives,
        gain_nm_per_a=tuple(float(v) for v in np.multiply(cfg.drives.gain_nm_per_a, k)),
    )
    gas = _factors(seed, _GAS, len(units), CYLINDERS)
    cylinders = dataclasses.replace(
        cylinders,
        units=tuple(
            dataclasses.replace(u, gas_length_m=u.gas_length_m * float(gas[k]))
            for k, u in enumerate(cylinders.units)
        ),
    )
    limit = np.asarray(cfg.drives.max_current_a, dtype=float)
    spread = cfg.sensors.current_offset_fraction
    o = np.random.default_rng([seed, _CURRENT_OFFSETS]).uniform(-spread, spread, n) * limit
    sensors = dataclasses.replace(cfg.sensors, current_offset_a=tuple(float(v) for v in o))
    b = np.random.default_rng([seed, _BRAKES])
    engage = cfg.brakes.engage_s * b.uniform(1.0 - BRAKE_ENGAGE, 1.0 + BRAKE_ENGAGE)
    torque = np.multiply(
        cfg.brakes.torque_nm,
        b.uniform(1.0 - BRAKE_TORQUE, 1.0 + BRAKE_TORQUE, len(cfg.brakes.torque_nm)),
    )
    brakes = dataclasses.replace(
        cfg.brakes, engage_s=float(engage), torque_nm=tuple(float(v) for v in torque)
    )
    return dataclasses.replace(
        cfg,
        inner_loop=inner,
        friction=friction,
        cylinders=cylinders,
        drives=drives,
        sensors=sensors,
        brakes=brakes,
    )


def arm_spec(cfg: SimConfig) -> mujoco.MjSpec:
    """The arm's MJCF as a spec with the timestep of ``cfg`` and, for a seed > 0, link masses,
    centres of mass and inertias drawn around the file's (module docstring)."""
    spec = mujoco.MjSpec.from_file(str(arm_mjcf_path(cfg)))
    spec.option.timestep = cfg.timestep_s
    if cfg.plant_seed == 0:
        return spec
    bodies = [b for b in spec.bodies if b.name != "world"]
    f = _factors(cfg.plant_seed, _INERTIALS, (len(bodies), 4), INERTIALS)
    for k, body in enumerate(bodies):
        scale = f[k, 0]
        com = np.array(body.ipos, dtype=float)
        shift = (f[k, 1:] - 1.0) * np.linalg.norm(com)
        body.mass = float(body.mass * scale)
        body.ipos = com + shift
        body.fullinertia = np.asarray(body.fullinertia, dtype=float) * scale
    return spec
