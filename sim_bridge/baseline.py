"""The paper's baseline on the virtual robot: servo off, brakes released, the operator drags.

With the servo off and the brake-release switch held, nothing but the assist cylinders (at
their pressures) offsets gravity; the operator's hand (the demo's, :data:`.demo.HAND`) guides
the tool along the demo's path (:data:`.demo.DEMO_PATH`) against the unbalanced weight, the
friction and the inertia. The plant runs in this process, faster than real time, without the
controller or the product: a released brake needs neither. ``leadthrough demo --baseline``
prints the operator force this takes, to set against the lead-through demo's.
"""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np

from sim_bridge.config import SimConfig
from sim_bridge.operator import Operator
from sim_bridge.plant import Plant

#: record every this many physics steps (the figures' sample period)
RECORD_EVERY_S = 0.004
#: the ideal orientation lock of an inertia floor (:func:`orientation_lock`): stiff enough that
#: the hand's 80 N at the tool turns the gun a few hundredths of a degree, damped near
#: critically for the lightest wrist (0.25 kg·m²); explicit at the plant's 0.5 ms step,
#: sqrt(K / I) × dt = 0.14
LOCK_NM_PER_RAD, LOCK_NM_S_PER_RAD = 20000.0, 100.0


def orientation_lock(plant: Plant) -> Any:
    """Joint torques that hold the last link's orientation where it is now, as a stiff
    spring-damper on its rotation (MuJoCo's own kinematics, the scorer's): an arm guided with
    its gun's orientation locked by an ideal fixture, for the inertia floor of an
    orientation-locked guide. Set it as ``plant.external_torque``."""
    import mujoco
    from scipy.spatial.transform import Rotation

    model, data, body, n = plant.model, plant.data, plant.last_body, plant.n
    r0 = data.xmat[body].reshape(3, 3).copy()
    jac = np.zeros((3, model.nv))

    def torque(p: Plant) -> np.ndarray:
        r = data.xmat[body].reshape(3, 3)
        e = Rotation.from_matrix(r @ r0.T).as_rotvec()
        mujoco.mj_jacBody(model, data, None, jac, body)
        jw = jac[:, :n]
        return jw.T @ (-LOCK_NM_PER_RAD * e - LOCK_NM_S_PER_RAD * (jw @ data.qvel[:n]))

    return torque


def drag_released(
    cfg: SimConfig,
    path: list[list[float]],
    hand: dict[str, float],
    duration_s: float,
    gravity: bool = True,
    lock_orientation: bool = False,
) -> dict[str, Any]:
    """Drag the released arm along ``path`` for ``duration_s`` with a hand of settings
    ``hand`` (:class:`.config.OperatorScript` fields); every :data:`RECORD_EVERY_S`: time ``t_s``
    (T,) and (T, 3) ``tool``, ``force`` (the hand's, world), ``target`` (where the hand wants
    the tool) and ``flange`` (the last link's origin) [m, N], (T, n) ``q`` the joints [rad];
    ``origin`` the tool at onset,
    ``script`` the operator's settings. ``lock_orientation``: the gun's orientation held by
    an ideal fixture (:func:`orientation_lock`)."""
    script = dataclasses.replace(
        cfg.operator,
        mode="path",
        path=tuple(tuple(float(v) for v in w) for w in path),
        enabling_after_s=0.0,
        release_after_s=None,
        brake_release_after_s=0.0,
        **hand,
    )
    plant = Plant(dataclasses.replace(cfg, operator=script))
    if not gravity:  # a weightless arm: only its inertia (and what cfg leaves) resists the hand
        plant.model.opt.gravity[:] = 0.0
    op = Operator(script)
    plant.hand = op.hand
    op.mark_onset(plant.t_s, plant.tool_position_m())
    if lock_orientation:
        plant.external_torque = orientation_lock(plant)
    every = max(1, round(RECORD_EVERY_S / plant.cfg.timestep_s))
    rows = []
    for k in range(round(duration_s / plant.cfg.timestep_s)):
        plant.step(None, None, brakes_released=op.brakes_released(plant.t_s))
        if k % every == 0:
            rows.append(
                np.r_[
                    plant.t_s,
                    plant.tool_position_m(),
                    plant.hand_force_n,
                    op.target_m(plant.t_s),
                    plant.data.xpos[plant.last_body],
                    plant.data.qpos[: plant.n],
                ]
            )
    a = np.array(rows)
    return {
        "t_s": a[:, 0],
        "tool": a[:, 1:4],
        "force": a[:, 4:7],
        "target": a[:, 7:10],
        "flange": a[:, 10:13],
        "q": a[:, 13:],
        "origin": op.origin_m,
        "script": script,
    }


def run_baseline(
    cfg: SimConfig, path: list[list[float]], hand: dict[str, float], duration_s: float
) -> dict[str, Any]:
    """Drag the released arm along ``path`` for ``duration_s``; the operator force figures."""
    trace = drag_released(cfg, path, hand, duration_s)
    f = np.linalg.norm(trace["force"], axis=1)
    miss = np.linalg.norm(trace["tool"] - trace["target"], axis=1)
    return {
        "plant_seed": cfg.plant_seed,
        "duration_s": duration_s,
        "mean_force_n": float(f.mean()),
        "peak_force_n": float(f.max()),
        "force_saturated_share": float(np.mean(f >= 0.999 * trace["script"].max_force_n)),
        "max_tool_off_path_m": float(miss.max()),
        "mean_tool_off_path_m": float(miss.mean()),
        "pressures_bar": list(cfg.cylinders.initial_bar),
    }
