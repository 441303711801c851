"""How a teach-bench run is scored: the figures of one strategy's drag along the path (the hand's
force and its moment about the flange, per phase and over the moving part, the tool's distance
from the path, whether the operator got to the end), and the adaptation report: the loop's
estimates ω̂ and Υ̂_I = ω̂_I against the plant's hidden inner gains ω = 1/(K·K_p) and K_I/K_p
(K the datasheet torque constant), read for scoring only; the flange's pose and the tool's
turn from the plant's own kinematics."""

from __future__ import annotations

import dataclasses
import itertools
import math
from typing import Any

import mujoco
import numpy as np

from sim_bridge.config import load_sim_config
from sim_bridge.plant import Plant
from sim_bridge.teach_phases import PHASES, classify, phase_forces

#: the operator got to the end when the tool ends this close to the path's last point [m]
COMPLETED_WITHIN_M = 0.05


def flange_poses(plant_seed: int, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The flange (the last link's origin, (T, 3)) and the last link's orientation ((T, 3,
    3), the tool's: it is fixed to it) at the logged joint positions ``q`` (T, n), from the
    plant's own kinematics: the scorer's, never the product's."""
    cfg = dataclasses.replace(load_sim_config(), plant_seed=plant_seed)
    plant = Plant(cfg)
    model, data = plant.model, plant.data
    out = np.empty((q.shape[0], 3))
    rot = np.empty((q.shape[0], 3, 3))
    for k, row in enumerate(q):
        data.qpos[: plant.n] = row
        mujoco.mj_kinematics(model, data)
        out[k] = data.xpos[plant.last_body]
        rot[k] = data.xmat[plant.last_body].reshape(3, 3)
    return out, rot


def orientation_drift_deg(rot: np.ndarray) -> np.ndarray:
    """The angle of each orientation of ``rot`` (T, 3, 3) from the first [°]."""
    relative = np.einsum("tij,kj->tik", rot, rot[0])
    cos = (np.trace(relative, axis1=1, axis2=2) - 1.0) / 2.0
    return np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))


def _target(path: list[list[float]], tau: np.ndarray) -> np.ndarray:
    wp = np.asarray(path, dtype=float)
    return np.stack([np.interp(tau, wp[:, 0], wp[:, k]) for k in (1, 2, 3)], axis=1)


def _distance_to_polyline(points: np.ndarray, vertices: np.ndarray) -> np.ndarray:
    """Distance of each point (T, 3) to the polyline through ``vertices`` (V, 3) [m]."""
    best = np.full(points.shape[0], np.inf)
    for a, b in itertools.pairwise(vertices):
        ab = b - a
        length2 = float(ab @ ab)
        u = (
            np.zeros(points.shape[0])
            if length2 == 0
            else np.clip((points - a) @ ab / length2, 0, 1)
        )
        best = np.minimum(best, np.linalg.norm(points - (a + u[:, None] * ab), axis=1))
    return best


def metrics(
    path: list[list[float]],
    tau: np.ndarray,
    tool: np.ndarray,
    origin: np.ndarray,
    force: np.ndarray,
    flange: np.ndarray,
    q: np.ndarray | None = None,
) -> dict[str, Any]:
    """Figures of one strategy's run: ``tau`` (T,) time since the hand took the tool [s],
    ``tool``, ``force`` (the hand's, world) and ``flange`` positions (T, 3), ``origin`` the
    tool at onset, ``q`` (T, n) the arm's joints [rad] (None: no reversal phase), module
    docstring; ``phases`` the force per phase of :mod:`.teach_phases`."""
    target = _target(path, tau)
    speed = np.linalg.norm(np.gradient(target, tau, axis=0), axis=1) if tau.size > 1 else tau
    during = tau <= path[-1][0]
    phase = classify(tau, speed, path[-1][0], q)
    dwell = phase == PHASES.index("dwell")
    moving = (phase >= 0) & ~dwell
    f = np.linalg.norm(force, axis=1)
    moment = np.linalg.norm(np.cross(tool - flange, force), axis=1)
    vertices = origin + np.array([w[1:] for w in path])
    error = _distance_to_polyline(tool[during], vertices)
    end = origin + np.array(path[-1][1:])

    def stats(x: np.ndarray) -> tuple[float, float, float]:
        if not x.size:
            return math.nan, math.nan, math.nan
        return float(x.mean()), float(np.percentile(x, 95)), float(x.max())

    mean_f, p95_f, peak_f = stats(f[moving])
    progress = np.interp(
        tau,
        [w[0] for w in path],
        np.r_[
            0.0, np.cumsum(np.linalg.norm(np.diff(np.array([w[1:] for w in path]), axis=0), axis=1))
        ],
    )
    return {
        "_series": {"progress_m": progress[during], "force_n": f[during], "phase": phase[during]},
        "phases": phase_forces(tau, f, phase),
        "mean_force_n": mean_f,
        "p95_force_n": p95_f,
        "peak_force_n": peak_f,
        "mean_moment_nm": stats(moment[moving])[0],
        "dwell_mean_force_n": stats(f[dwell])[0],
        "path_error_mm": float(np.percentile(error, 95)) * 1e3 if error.size else math.nan,
        "completed": bool(
            tau.size
            and tau[-1] >= path[-1][0]
            and np.linalg.norm(tool[-1] - end) <= COMPLETED_WITHIN_M
        ),
        "moving_s": float(np.sum(np.diff(tau)[moving[1:]])) if tau.size > 1 else 0.0,
    }


def commands_missed(cycle: np.ndarray, latency_s: np.ndarray) -> int:
    """Command cycles of a truth log's rows that got no command in time: a cycle is the run of
    consecutive rows with the same ``cycle`` value (one row on the LTC cell; one per servo
    cycle of the CiA 402 drives, several to a SYNC, the SYNC's answer latency in one of them),
    missed when none of its rows has a latency. Counting rows instead read 22,119 missed
    commands in 59 s of CiA 402 teaching whose drives counted 3 missed cycles (2026-12-07)."""
    if cycle.size == 0:
        return 0
    starts = np.flatnonzero(np.r_[True, cycle[1:] != cycle[:-1]])
    answered = np.add.reduceat(~np.isnan(latency_s), starts) > 0
    return int(np.sum(~answered))


def settling_time_s(t_s: np.ndarray, ratios: np.ndarray, band: float = 0.05) -> float | None:
    """From ``t_s[0]``, the time after which every ratio (columns) stays within ``band`` of 1
    to the last sample; None if the last sample is outside it."""
    inside = np.all(np.abs(ratios - 1.0) <= band, axis=1)
    if not inside.size or not inside[-1]:
        return None
    outside = np.flatnonzero(~inside)
    first = 0 if not outside.size else int(outside[-1]) + 1
    return round(float(t_s[first] - t_s[0]), 2)


def adaptation_report(
    telemetry: dict[str, Any] | None,
    plant_seed: int,
    inner_loop: dict[str, Any],
    history: list[tuple[float, list[float], list[float]]] | None = None,
    teaching_from_s: float | None = None,
) -> dict[str, Any]:
    """The loop's estimates against the plant's hidden inner gains (module docstring):
    ``telemetry`` the control process's last message, ``inner_loop`` the commissioned
    ``inner_loop.json``. Ratios estimate / truth per joint. With the estimates' ``history``
    and the time teaching began (both on the machine's monotonic clock), also the time of
    guided motion after which every joint's ω̂ and ω̂_I stayed within 5 % of the truth."""
    nominal = load_sim_config()
    plant = Plant(dataclasses.replace(nominal, plant_seed=plant_seed))
    k = np.array(nominal.drives.gain_nm_per_a)  # the datasheet's: the product's torque unit
    omega_true = 1.0 / (k * plant.kp)
    omega_i_true = plant.ki / plant.kp
    adapted_ups = (telemetry or {}).get("upsilon_i_per_s")
    omega_i_hat = np.array(
        adapted_ups if adapted_ups is not None else inner_loop["upsilon_i_per_s"], dtype=float
    )
    omega_hat = (
        np.array(telemetry["omega_rad_s_per_nm"], dtype=float)
        if telemetry is not None
        else np.array(inner_loop["omega_rad_s_per_nm"], dtype=float)
    )
    out: dict[str, Any] = {
        "omega_hat": omega_hat.tolist(),
        "omega_true": omega_true.tolist(),
        "omega_i_hat": omega_i_hat.tolist(),
        "omega_i_true": omega_i_true.tolist(),
        "omega_ratio": (omega_hat / omega_true).round(4).tolist(),
        "omega_i_ratio": (omega_i_hat / omega_i_true).round(4).tolist(),
        "omega_source": "control telemetry" if telemetry is not None else "commissioned",
        "omega_i_source": "control telemetry" if adapted_ups is not None else "commissioned",
    }
    if history and teaching_from_s is not None:
        rows = [h for h in history if h[0] >= teaching_from_s]
        if rows:
            t = np.array([teaching_from_s] + [h[0] for h in rows])
            r = np.array(
                [np.concatenate([np.array(w) / omega_true, np.array(u) / omega_i_true])
                 for _, w, u in rows]
            )  # fmt: skip
            r = np.vstack([r[:1], r])  # at the start of teaching: the first estimate
            out["within_5pct_after_s"] = settling_time_s(t, r)
            out["teaching_s"] = round(float(t[-1] - t[0]), 2)
    online = (telemetry or {}).get("inner_loop_estimate")
    if online:
        est_omega = np.array([math.nan if v is None else v for v in online["omega_rad_s_per_nm"]])
        est_ups = np.array([math.nan if v is None else v for v in online["upsilon_i_per_s"]])
        out["online_estimate"] = {
            "omega_ratio": [None if math.isnan(v) else round(v, 4) for v in est_omega / omega_true],
            "omega_i_ratio": [
                None if math.isnan(v) else round(v, 4) for v in est_ups / omega_i_true
            ],
            "seconds": online.get("seconds"),
        }
    return out
