"""Identification through the product on the virtual cell (issue 3).

`leadthrough identify` runs as a user would: the gateway enters IDENTIFYING, the control
process plays the excitation plan, the CAN driver forwards it, the bus is recorded to MCAP,
cut into segments and fitted. The simulator may inject effects the declared model lacks
(private to the simulator); the analysis must name them and remove their error.
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest

from control.experiments import build_plan
from gateway.robot.description import load_description
from sim_bridge.commission import COMMISSION_LIMIT_S, commission, commissioned
from sim_bridge.config import load_sim_config
from sim_bridge.effects import MOTION_RAD_S
from sim_bridge.harness import Stack
from sim_bridge.truth import draw

pytestmark = pytest.mark.stack

#: The virtual controller's cycle in these tests (its default), run lock-step: the driver's
#: answer deadline (half a cycle of wall time) then leaves room for this 2-core machine's
#: scheduling hiccups; at 4 ms about 1 % of cycles were answered by a coast or hold.
CYCLE_S = 0.008

PLAN = {
    "friction": {"joints": [1, 2, 3, 4, 5, 6], "amplitude_rad": 0.1, "speeds_deg_s": [6.0]},
    "inner_loop": {"joints": [1, 2, 3, 4, 5, 6], "speed_rad_s": 0.05, "step_s": 0.3},
    "multisine": [
        {"seed": 1, "duration_s": 15, "amplitude_rad": [0.3, 0.25, 0.25, 0.5, 0.5, 0.5],
         "base_hz": 0.15, "harmonics": 5, "role": "train"},
        {"seed": 2, "duration_s": 15, "amplitude_rad": [0.3, 0.25, 0.25, 0.5, 0.5, 0.5],
         "base_hz": 0.17, "harmonics": 5, "role": "train"},
        {"seed": 7, "duration_s": 12, "amplitude_rad": [0.25, 0.2, 0.2, 0.4, 0.4, 0.4],
         "base_hz": 0.2, "harmonics": 5, "role": "test"},
    ],
    "pause_s": 0.5,
}  # fmt: skip


def noise_floor_nm() -> np.ndarray:
    """The simulator's torque-measurement noise: drive gain × current-noise std [N·m]."""
    k = np.array([j.drive_gain_nm_per_a for j in load_description().joints])
    return k * load_sim_config().sensors.current_noise_a


def train_motion_s() -> float:
    """Time the arm moves (some joint faster than the simulator's MOTION_RAD_S) in the plan's
    runs before the test run: a tool mounted after that much motion is there for the test run
    only."""
    desc = load_description()
    dt = CYCLE_S
    parts = build_plan({"plan_id": "x", **PLAN}, np.zeros(6), desc.lower_rad, desc.upper_rad, dt, 0)
    train = [dq for _label, role, _q, dq in parts if role != "test"]
    return float(sum(np.sum(np.abs(dq).max(axis=1) > MOTION_RAD_S) for dq in train)) * dt


def teaching_drift_m(truth: dict[str, np.ndarray], seconds: float) -> float:
    """Largest tool excursion [m] in the first ``seconds`` of teaching of a truth log."""
    rows = np.flatnonzero(truth["teaching"] > 0.5)
    rows = rows[truth["t_s"][rows] - truth["t_s"][rows[0]] <= seconds]
    xyz = np.stack([truth[f"tool_{a}"][rows] for a in "xyz"], axis=1)
    return float(np.linalg.norm(xyz - xyz[0], axis=1).max())


def identify(
    tmp_path, effects: list[dict], plan: dict = PLAN, plant_seed: int = 0,
    sim_overrides: dict | None = None,
) -> dict:  # fmt: skip
    """`leadthrough identify` with ``plan`` on a virtual cell that is not commissioned yet,
    the simulator injecting ``effects`` (:func:`sim_bridge.commission.commission`, as
    commissioning runs it): the summary it wrote to ``tmp_path / "ident"``."""
    overrides = {"effects": effects, **(sim_overrides or {})}
    commission(plant_seed, {"plan_id": "stack-test", **plan}, tmp_path, overrides)
    summary = tmp_path / "ident" / "summary.json"
    return json.loads(summary.read_text()) if summary.exists() else {}


def assert_inner_loop_within_20_percent(inner_loop: Path, plant_seed: int) -> None:
    """The identified ω and Υ_I against the drawn plant's truth (read only to judge)."""
    est = json.loads(inner_loop.read_text())
    truth = draw(dataclasses.replace(load_sim_config(), plant_seed=plant_seed)).inner_loop
    kp, ki = np.array(truth.kp_a_s_per_rad), np.array(truth.ki_a_per_rad)
    k = np.array([j.drive_gain_nm_per_a for j in load_description().joints])
    omega, upsilon = np.array(est["omega_rad_s_per_nm"]), np.array(est["upsilon_i_per_s"])
    print(f"seed {plant_seed}: omega/truth {omega * k * kp}, Upsilon_I/truth {upsilon * kp / ki}")
    np.testing.assert_allclose(omega, 1.0 / (k * kp), rtol=0.2)
    np.testing.assert_allclose(upsilon, ki / kp, rtol=0.2)


#: Plants 1 and 2 are commissioned by `make acceptance` only: each is a fresh commissioning
#: (2.5-3.5 minutes of the stack tier's one worker, which `make test` on a fresh clone runs
#: one after the other: issue 49's 10 minutes), where plant 0's is the one `make demo` and the
#: other stack tests teach with, built once and shared. The hidden checks and `make acceptance`
#: run the others.
ACCEPTANCE_ONLY = pytest.mark.campaign


@pytest.mark.timeout(COMMISSION_LIMIT_S)
@pytest.mark.parametrize(
    "plant_seed",
    [0, pytest.param(1, marks=ACCEPTANCE_ONLY), pytest.param(2, marks=ACCEPTANCE_ONLY)],
)
def test_commissioning_a_drawn_plant_reaches_the_noise_floor_and_its_inner_loop(plant_seed):
    """Issue 22's acceptance: the virtual cell of a drawn plant, commissioned by `leadthrough
    identify` (the cache `make demo` and the stack tests teach with, built here when missing),
    predicts held-out torque within 2× the plant's current-noise floor on every joint, and its
    inner-loop estimate is within 20 % of the drawn gains. The truth is read only to judge."""
    done = commissioned(plant_seed)
    summary = done.summary
    floor = noise_floor_nm()
    rms = np.array(summary["rms_after"])
    print(f"seed {plant_seed}: held-out RMS {rms}, noise floor {floor}, "
          f"effects {[(e['name'], e['joints']) for e in summary['effects']]}")  # fmt: skip
    assert np.all(rms <= 2.0 * floor), f"held-out RMS {rms} above 2× noise floor {floor}"
    assert_inner_loop_within_20_percent(done.inner_loop, plant_seed)
    assert_current_zero_measures_the_offsets(done.current_zero, plant_seed)


def assert_current_zero_measures_the_offsets(path: Path | None, plant_seed: int) -> None:
    """The zero the identification ran with (current_zero.json) against the drawn plant's
    current-sensor offsets (read only to judge): within 5 standard errors of its mean."""
    assert path is not None, "identify wrote no current_zero.json"
    doc = json.loads(path.read_text())
    sensors = draw(dataclasses.replace(load_sim_config(), plant_seed=plant_seed)).sensors
    zero, offset = np.array(doc["current_zero_a"]), np.array(sensors.current_offset_a)
    se = sensors.current_noise_a / np.sqrt(doc["samples"])
    print(f"seed {plant_seed}: current zero {zero} A, sensor offsets {offset} A")
    assert np.all(np.abs(zero - offset) <= 5 * se + 1e-4), (zero, offset, se)
    assert np.any(offset != 0), "the drawn plant has no current offsets to measure"


@pytest.mark.timeout(COMMISSION_LIMIT_S)
def test_identification_names_a_hose_spring_and_a_gear_ripple(tmp_path):
    effects = [
        {"kind": "spring", "joint": 1, "k_nm_per_rad": 300.0, "q0_rad": 0.0},
        {"kind": "position_ripple", "joint": 4, "amplitude_nm": 1.5, "cycles_per_rev": 27.0},
    ]
    summary = identify(tmp_path, effects)
    found = {(e["name"], tuple(e["joints"])): e for e in summary["effects"]}
    print(json.dumps(summary["effects"], indent=1))
    assert ("spring", (1,)) in found
    assert found[("spring", (1,))]["parameters"]["k_nm_per_rad"] == pytest.approx(300, rel=0.2)
    assert ("position_ripple", (4,)) in found
    ripple = found[("position_ripple", (4,))]["parameters"]
    assert ripple["cycles_per_rev"] == pytest.approx(27, abs=1)
    before, after = np.array(summary["rms_before"]), np.array(summary["rms_after"])
    for j in (0, 3):  # joints 1 and 4, 0-based
        assert after[j] <= 0.5 * before[j], f"joint {j + 1}: {before[j]:.3f} → {after[j]:.3f}"


@pytest.mark.timeout(COMMISSION_LIMIT_S)
def test_identification_names_a_spray_gun_mounted_between_training_and_test(tmp_path):
    """On the smooth friction law (truth ``stiction = false``). On the default plant, with
    stiction, the payload is the best candidate (+95 % held-out) but rule (iv) refuses it:
    fitted on the first half of the test run it makes J6 (0.18 N·m RMS) 16-28 % worse on the
    second, and three springs and a coupling are accepted instead (docs/control.md, Stiction)."""
    effects = [{"kind": "payload", "mass_kg": 8.0, "com_m": [0.0, 0.0, 0.05],
                "after_motion_s": train_motion_s() + 0.1}]  # fmt: skip
    summary = identify(tmp_path, effects, sim_overrides={"stiction": False})
    print(json.dumps(summary["effects"], indent=1))
    payloads = [e for e in summary["effects"] if e["name"] == "payload"]
    assert payloads, f"payload not found: {summary['effects']}"
    assert payloads[0]["appeared"] == "between_train_and_test"
    assert payloads[0]["parameters"]["mass_kg"] == pytest.approx(8.0, rel=0.3)
    before, after = np.array(summary["rms_before"]), np.array(summary["rms_after"])
    affected = before > 3 * noise_floor_nm()
    assert affected.any()
    assert np.all(after[affected] <= 0.5 * before[affected]), (before, after)

    # Closing the loop: the control process runs on the identified model.json (and the inner
    # loop estimated in the same run), the gun is mounted from the start, and the arm stays
    # weightless (issue 2's drift criterion).
    gun = [{k: v for k, v in effects[0].items() if k != "after_motion_s"}]
    ident = tmp_path / "ident"
    with Stack(
        tmp_path / "teach", sim_overrides={"effects": gun, "stiction": False},
        model=ident / "model.json",
        inner_loop=ident / "inner_loop.json", current_zero=ident / "current_zero.json",
    ) as stack:  # fmt: skip
        stack.start()
        stack.start_teaching()
        truth = stack.wait_teaching(5.2, 30.0)
        stack.request("stop")
    drift_mm = teaching_drift_m(truth, 5.0) * 1e3
    print(f"drift on the identified model with the gun mounted: {drift_mm:.3f} mm in 5 s")
    assert drift_mm < 1.0
