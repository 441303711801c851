"""The teach benchmark's path and figures (sim_bridge/teach_bench.py,
sim_bridge/teach_bench_metrics.py), on synthetic traces."""

from __future__ import annotations

import argparse
import dataclasses

import numpy as np
import pytest

from sim_bridge import teach_bench
from sim_bridge.config import load_sim_config
from sim_bridge.harness import REPO, SIM_CELL
from sim_bridge.plant import Plant
from sim_bridge.teach_bench import (
    configure_parser,
    inertia_config,
    run_inertia,
    run_offservo,
)
from sim_bridge.teach_bench_metrics import (
    _distance_to_polyline,
    _target,
    adaptation_report,
    commands_missed,
    metrics,
    settling_time_s,
)
from sim_bridge.teach_raster import DWELL_S, SPEED_M_S, raster_facing, raster_path


def test_the_raster_zig_zags_on_the_vertical_plane_at_the_painters_speed():
    path = np.array(raster_path(width_m=1.0, height_m=0.6, passes=4))
    assert np.all(np.diff(path[:, 0]) >= 0) and np.all(path[:, 1] == 0.0)  # y-z plane
    corners = path[2::2, 2:]  # each corner once (the dwell repeats it)
    np.testing.assert_allclose(corners[:2], [[-0.5, 0.3], [0.5, 0.3]])
    np.testing.assert_allclose(corners[-1], [-0.5, -0.3])
    assert {round(z, 9) for z in corners[:, 1]} == {0.3, 0.1, -0.1, -0.3}
    legs = np.linalg.norm(np.diff(path[:, 2:], axis=0), axis=1)
    length = legs.sum()
    assert length == pytest.approx(np.hypot(0.5, 0.3) + 4 * 1.0 + 3 * 0.2)
    moving_s = np.diff(path[:, 0])[legs > 0].sum()
    assert moving_s == pytest.approx(length / SPEED_M_S)
    assert path[-1][0] == pytest.approx(1.0 + moving_s + 8 * DWELL_S)
    with pytest.raises(ValueError):
        raster_path(passes=1)


def test_distance_to_a_polyline():
    v = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [1.0, 1.0, 0.0]])
    p = np.array([[0.5, 0.2, 0.0], [1.3, 0.5, 0.0], [-1.0, 0.0, 0.0], [1.0, 1.0, 0.4]])
    np.testing.assert_allclose(_distance_to_polyline(p, v), [0.2, 0.3, 1.0, 0.4])


def _trace(path, follow_until_s=None, lag_m=0.0):
    tau = np.arange(0.0, path[-1][0] + 2.0, 0.004)
    origin = np.array([1.0, 0.1, 2.0])
    shown = tau if follow_until_s is None else np.minimum(tau, follow_until_s)
    tool = origin + _target(path, shown) + np.array([lag_m, 0.0, 0.0])
    force = np.zeros((tau.size, 3))
    moving = np.linalg.norm(np.gradient(_target(path, tau), tau, axis=0), axis=1) > 1e-3
    force[moving, 1] = 4.0  # pushes while the target moves
    force[~moving, 1] = 1.0
    flange = tool + np.array([0.0, 0.0, 0.25])
    return tau, tool, origin, force, flange


def test_a_painter_who_follows_the_path_completes_it():
    path = raster_path()
    m = metrics(path, *_trace(path, lag_m=0.002))
    assert m["completed"]
    assert m["path_error_mm"] == pytest.approx(2.0, abs=0.01)
    assert m["mean_force_n"] == pytest.approx(4.0) and m["peak_force_n"] == pytest.approx(4.0)
    assert m["dwell_mean_force_n"] == pytest.approx(1.0, abs=0.05)
    assert m["mean_moment_nm"] == pytest.approx(4.0 * 0.25)  # |r x F|, r 0.25 m along z
    assert m["moving_s"] == pytest.approx(path[-1][0] - 1.0 - 8 * DWELL_S, abs=0.1)


def test_a_painter_who_stops_halfway_has_not_completed():
    path = raster_path()
    m = metrics(path, *_trace(path, follow_until_s=path[-1][0] / 2))
    assert not m["completed"]
    assert m["path_error_mm"] < 1e-6  # it stayed on the path: it just did not get to the end


def test_the_adaptation_report_scores_estimates_against_the_hidden_gains():
    seed = 3
    plant = Plant(dataclasses.replace(load_sim_config(), plant_seed=seed))
    k = np.array(load_sim_config().drives.gain_nm_per_a)
    omega, ups = 1.0 / (k * plant.kp), plant.ki / plant.kp
    inner_loop = {"omega_rad_s_per_nm": (1.1 * omega).tolist(), "upsilon_i_per_s": ups.tolist()}
    online = {
        "omega_rad_s_per_nm": [None, *(0.9 * omega[1:]).tolist()],
        "upsilon_i_per_s": (1.05 * ups).tolist(),
        "seconds": 12.5,
    }
    telemetry = {"omega_rad_s_per_nm": omega.tolist(), "inner_loop_estimate": online}
    out = adaptation_report(telemetry, seed, inner_loop)
    assert out["omega_source"] == "control telemetry"
    assert out["omega_ratio"] == pytest.approx([1.0] * 6)
    assert out["omega_i_ratio"] == pytest.approx([1.0] * 6)
    assert out["online_estimate"]["omega_ratio"][0] is None
    assert out["online_estimate"]["omega_ratio"][1:] == pytest.approx([0.9] * 5)
    assert out["online_estimate"]["omega_i_ratio"] == pytest.approx([1.05] * 6)
    # without telemetry the commissioned omega is what the law used
    out = adaptation_report(None, seed, inner_loop)
    assert out["omega_source"] == "commissioned"
    assert out["omega_ratio"] == pytest.approx([1.1] * 6)
    assert "online_estimate" not in out
    # another seed's gains are not this one's: the report must notice
    assert adaptation_report(telemetry, 4, inner_loop)["omega_ratio"] != pytest.approx([1.0] * 6)


def test_the_settling_time_is_when_every_estimate_entered_the_band_for_good():
    t = np.array([10.0, 11.0, 12.0, 13.0, 14.0])
    r = np.ones((5, 4))
    assert settling_time_s(t, r) == 0.0
    r[1, 2] = 1.2  # out at 11 s, in from 12 s
    assert settling_time_s(t, r) == 2.0
    r[3, 0] = 0.949  # out again at 13 s
    assert settling_time_s(t, r) == 4.0
    r[4, 3] = 1.051  # out at the end: never settled
    assert settling_time_s(t, r) is None


def test_the_adaptation_report_times_the_estimates_from_the_start_of_teaching():
    seed = 3
    plant = Plant(dataclasses.replace(load_sim_config(), plant_seed=seed))
    k = np.array(load_sim_config().drives.gain_nm_per_a)
    omega, ups = 1.0 / (k * plant.kp), plant.ki / plant.kp
    inner_loop = {"omega_rad_s_per_nm": omega.tolist(), "upsilon_i_per_s": ups.tolist()}
    history = [(t, (omega * (1.0 + 0.24 / (1.0 + t - 100.0))).tolist(), ups.tolist())
               for t in np.arange(99.5, 120.0, 0.5)]  # fmt: skip
    telemetry = {"omega_rad_s_per_nm": history[-1][1], "upsilon_i_per_s": history[-1][2]}
    out = adaptation_report(telemetry, seed, inner_loop, history, teaching_from_s=100.0)
    # 0.24 / (1 + t) <= 0.05 from t = 3.8 s of teaching on: the sample at 4 s
    assert out["within_5pct_after_s"] == 4.0 and out["teaching_s"] == 19.5


@pytest.mark.parametrize("seed", [0, 3])
def test_the_inertia_floor_leaves_the_plant_nothing_but_its_inertia(seed):
    """The floor's plant: whatever the stroke, the cylinders hold no pressure and give no
    torque; no friction; its masses are the seed's own."""
    plant = Plant(inertia_config(seed))
    plant.model.opt.gravity[:] = 0.0
    plant.data.qvel[:6] = [0.0, 0.3, -0.3, 0.0, 0.0, 0.0]
    for _ in range(400):
        plant.step(None, None, brakes_released=True)
    assert np.all(plant.pressure_bar == 0.0)
    assert not plant.cylinders.torque_nm(plant.q_rad, plant.pressure_bar).any()
    np.testing.assert_allclose(plant.friction.dry_level_nm(plant.q_rad, np.zeros(6)), 0.0)
    np.testing.assert_allclose(plant.friction.damping_nm_s_per_rad(np.full(6, 0.2)), 0.0)
    full = Plant(dataclasses.replace(load_sim_config(), plant_seed=seed))
    np.testing.assert_array_equal(plant.model.body_mass, full.model.body_mass)


def test_the_inertia_floor_is_below_the_cylinders_baseline_on_a_short_raster():
    path = raster_path(width_m=0.3, height_m=0.1, passes=2, start_s=0.5)
    floor = run_inertia(0, path, tail_s=0.5)
    baseline = run_offservo(0, path, tail_s=0.5)
    assert floor["completed"] and 0.1 < floor["mean_force_n"] < baseline["mean_force_n"]


def test_an_orientation_locked_floor_holds_the_gun_and_costs_the_hand_more():
    """The floor of an orientation-locked guide (sim_bridge/baseline.py orientation_lock):
    the gun's orientation stays within a tenth of a degree on a short raster, where the free
    floor's wrist turns out of the hand's way by degrees, and the hand moves more of the arm."""
    path = raster_path(width_m=0.3, height_m=0.1, passes=2, start_s=0.5)
    free = run_inertia(0, path, tail_s=0.5)
    locked = run_inertia(0, path, tail_s=0.5, guide="orientation-locked")
    assert locked["guide"] == "orientation-locked" and free["guide"] == "free"
    assert locked["orientation_drift_deg"]["max"] < 0.1
    assert free["orientation_drift_deg"]["max"] > 1.0
    assert locked["completed"] and locked["mean_force_n"] > free["mean_force_n"]


def test_a_raster_facing_the_gun_lies_in_its_plane_with_level_passes():
    """``--guide plane`` lays the raster in the plane the gun faces: the same times and
    lengths, every point in the plane, the passes level, the steps downwards; a gun facing
    along x gives the world's y-z raster back."""
    path = raster_path()
    n = np.array([0.826, 0.404, 0.392])  # the GR630ST's gun at its start pose
    facing = raster_facing(path, n)
    a, b = np.array(path), np.array(facing)
    np.testing.assert_array_equal(a[:, 0], b[:, 0])
    lengths = [np.linalg.norm(np.diff(x[:, 1:], axis=0), axis=1) for x in (a, b)]
    np.testing.assert_allclose(lengths[1], lengths[0], atol=1e-12)
    np.testing.assert_allclose(b[:, 1:] @ n / np.linalg.norm(n), 0.0, atol=1e-12)
    level = np.isclose(np.diff(a[:, 3]), 0.0)  # the passes of the y-z raster
    np.testing.assert_allclose(np.diff(b[:, 3])[level], 0.0, atol=1e-12)
    assert b[-1, 3] < 0.0  # it ends at the bottom, as the y-z raster
    np.testing.assert_allclose(raster_facing(path, [1.0, 0.0, 0.0]), path, atol=1e-12)


class _Bar:
    """What a progress bar gives run_seed: nothing shown."""

    def write(self, text: str) -> None: ...

    def set_label(self, text: str) -> None: ...

    def advance(self, label: str = "") -> None: ...


class _Reached(Exception):
    pass


@pytest.mark.parametrize("cell", [None, REPO / "deploy" / "config" / "sim_cell_cia402.toml"])
def test_the_products_strategies_run_through_the_cell_config_asked_for(cell, tmp_path, monkeypatch):
    """`teach-bench --cell`: the product's strategies run (and the robot is commissioned)
    through the cell config given, the default virtual cell's without it."""
    p = argparse.ArgumentParser()
    configure_parser(p)
    argv = ["--strategies", "admittance", "--out", str(tmp_path)]
    args = p.parse_args(argv + ([] if cell is None else ["--cell", str(cell)]))
    seen: dict = {}

    def run_best(plant_seed, path, work, **kwargs):
        seen.update(kwargs, plant_seed=plant_seed)
        raise _Reached

    monkeypatch.setattr(teach_bench, "run_best", run_best)
    with pytest.raises(_Reached):
        teach_bench.run_seed(3, ["admittance"], tmp_path, args, _Bar())
    assert seen["plant_seed"] == 3
    assert seen["cell_file"] == (SIM_CELL if cell is None else cell)


def test_commands_missed_are_counted_per_command_cycle_not_per_truth_row():
    nan = np.nan
    # the LTC cell: a row per cycle; two of five without an answer
    assert commands_missed(np.arange(5), np.array([1e-3, nan, 1e-3, nan, 1e-3])) == 2
    # CiA 402 drives: four servo rows to a SYNC, the answer's latency in one of them; the
    # third SYNC got none
    cycle = np.repeat([7, 8, 9, 10], 4)
    latency = np.full(16, nan)
    latency[[3, 5, 15]] = 1e-3
    assert commands_missed(cycle, latency) == 1
    # the counter wraps (the CiA 402 cell logs its SYNC count modulo 2**16): runs, not values
    assert commands_missed(np.array([65535, 65535, 0, 0]), np.array([nan, 1e-3, nan, nan])) == 1
    assert commands_missed(np.array([], dtype=int), np.array([])) == 0
