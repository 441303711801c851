"""`leadthrough identify`: run the identification experiments on a live cell and fit a model.

Everything goes through the product, exactly as on the real robot: the gateway enters
IDENTIFYING (the operator holds the enabling device), the control process plays the excitation
plan as position/velocity commands, the CAN driver forwards them, and this command records the
whole bus into ``OUT/identify.mcap``. Afterwards each experiment segment is exported to the
measurement CSV format, the "train" segments (friction, gravity, inertia runs and training
multi-sines) fit the model and the "test" multi-sines validate it (`leadthrough analyze`):
``OUT/model.json``, ``OUT/report.md``, ``OUT/summary.json``.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path
from typing import Any

from control.identification.analyze import AnalyzeOptions, analyze
from control.robot.description import load_description
from control.robot.urdf import to_urdf
from gateway.bus import BusConfig, bus_config_from
from gateway.config import load_toml
from gateway.errors import LeadthroughError
from gateway.messages import decode_json
from gateway.recorder import BusRecorder, export_csv, iter_mcap, read_states
from gateway.supervisor import operator_request

#: The paper's plan (Section 4): every joint's friction at 0.5–4 °/s and faster, gravity sweeps,
#: inertia runs, and multi-sine excitation; about 25 minutes on the robot.
FULL_PLAN: dict[str, Any] = {
    "friction": {"joints": [1, 2, 3, 4, 5, 6], "amplitude_rad": 0.2,
                 "speeds_deg_s": [0.5, 1.0, 2.0, 4.0, 8.0, 16.0]},
    "gravity": {"joints": [2, 3, 5], "amplitude_rad": 0.4, "speed_deg_s": 2.0},
    "inertia": {"pairs": [[1, 1], [2, 2], [3, 3], [2, 3], [3, 2], [1, 2]],
                "amplitude_rad": 0.15, "period_s": 2.0, "slow_speed_deg_s": 2.0},
    "multisine": [
        {"seed": 1, "duration_s": 60, "amplitude_rad": [0.3, 0.25, 0.25, 0.5, 0.5, 0.5],
         "base_hz": 0.1, "harmonics": 5, "role": "train"},
        {"seed": 2, "duration_s": 60, "amplitude_rad": [0.3, 0.25, 0.25, 0.5, 0.5, 0.5],
         "base_hz": 0.1, "harmonics": 5, "role": "train"},
        {"seed": 7, "duration_s": 40, "amplitude_rad": [0.25, 0.2, 0.2, 0.4, 0.4, 0.4],
         "base_hz": 0.13, "harmonics": 5, "role": "test"},
    ],
    "pause_s": 1.0,
}  # fmt: skip

#: Controller-rate recordings (125–500 Hz) are analysed at (about) 125 Hz, torque and kinematics
#: filtered with one 20 Hz cutoff so neither leads the other. Measured on the virtual cell (the
#: truth model against the measurement): at 10 Hz the friction reversals, smeared in the
#: filtered torque but sharp in the model computed from the filtered velocity, left 2.4× the
#: noise floor on joint 1; at 20 Hz, 1.0×.
ANALYSIS_RATE_HZ = 125.0
ANALYSIS_CUTOFF_HZ = 20.0

#: A short plan for the virtual cell's tests and demos (about 2 minutes of robot time).
QUICK_PLAN: dict[str, Any] = {
    "friction": {"joints": [1, 2, 3, 4, 5, 6], "amplitude_rad": 0.1,
                 "speeds_deg_s": [2.0, 8.0]},
    "multisine": [
        {"seed": 1, "duration_s": 30, "amplitude_rad": [0.3, 0.25, 0.25, 0.5, 0.5, 0.5],
         "base_hz": 0.1, "harmonics": 5, "role": "train"},
        {"seed": 2, "duration_s": 30, "amplitude_rad": [0.3, 0.25, 0.25, 0.5, 0.5, 0.5],
         "base_hz": 0.12, "harmonics": 5, "role": "train"},
        {"seed": 7, "duration_s": 20, "amplitude_rad": [0.25, 0.2, 0.2, 0.4, 0.4, 0.4],
         "base_hz": 0.13, "harmonics": 5, "role": "test"},
    ],
    "pause_s": 0.5,
}  # fmt: skip


def _last_report(mcap: Path, key: str, plan_id: str) -> dict[str, Any]:
    last: dict[str, Any] | None = None
    for topic, _t, payload in iter_mcap(mcap):
        if topic == key:
            msg = decode_json(payload, "experiment")
            if msg.get("plan_id") == plan_id:
                last = msg
    if last is None:
        raise LeadthroughError(f"{mcap}: no progress of plan {plan_id} was recorded")
    return last


def run_plan(bus: BusConfig, plan: dict[str, Any], out: Path, timeout_s: float) -> Path:
    """Record the bus while the cell plays ``plan``; returns the MCAP path."""
    out.mkdir(parents=True, exist_ok=True)
    mcap = out / "identify.mcap"
    rec = BusRecorder(bus, mcap, {"plan": json.dumps(plan)})
    rec.start()
    try:
        time.sleep(0.5)  # let the recorder's subscription reach the router
        reply = operator_request(bus, "identify", plan=plan)
        if not reply.get("ok"):
            raise LeadthroughError(f"the gateway refused to identify: {reply.get('message')}")
        print(f"identification running ({reply.get('message')}); keep the enabling device held")
        deadline = time.monotonic() + timeout_s
        while True:
            status = operator_request(bus, "status")
            if status.get("state") != "identifying":
                print(f"identification ended: {status.get('reason')}")
                break
            if time.monotonic() > deadline:
                operator_request(bus, "stop")
                raise LeadthroughError(f"plan not finished after {timeout_s} s; robot stopped")
            time.sleep(1.0)
    finally:
        rec.stop()
    if rec.error:
        raise LeadthroughError(f"recording failed: {rec.error}")
    return mcap


def export_segments(
    mcap: Path, plan_id: str, out: Path, gains: list[float], key: str
) -> tuple[list[Path], list[Path]]:
    """Cut the recording into one CSV per experiment segment: (train files, test files)."""
    report = _last_report(mcap, key, plan_id)
    if report.get("state") != "done":
        raise LeadthroughError(f"plan {plan_id} did not finish: {report.get('state')} "
                               f"{report.get('reason', '')}")  # fmt: skip
    train, test = [], []
    recorded = read_states(mcap)  # once: each segment is cut from it
    for k, seg in enumerate(report["segments"]):
        name = f"{k:02d}_{seg['label'].replace('/', '_')}.csv"
        path = out / "segments" / name
        path.parent.mkdir(parents=True, exist_ok=True)
        cycles = (seg["start_cycle"], seg["end_cycle"])
        export_csv(mcap, path, gains, cycle_range=cycles, recorded=recorded)
        (test if seg["role"] == "test" else train).append(path)
    return train, test


def configure_parser(p: argparse.ArgumentParser) -> None:
    p.description = (
        "Run the identification experiments on the live cell (the robot MOVES by itself: keep "
        "clear and hold the enabling device), record the bus, fit and validate the model. "
        "Needs the gateway in state ready (`leadthrough start`)."
    )
    p.add_argument("--config", type=Path, required=True, help="cell config TOML")
    p.add_argument("--bus", default=None, help="zenoh endpoint of the gateway")
    p.add_argument("--out", type=Path, default=Path("identify_out"), help="output folder")
    plan = p.add_mutually_exclusive_group()
    plan.add_argument("--plan", type=Path, default=None, help="excitation plan (JSON)")
    plan.add_argument("--quick", action="store_true", help="the short plan (virtual cell)")
    p.add_argument("--timeout", type=float, default=3600.0, help="give up after [s]")
    p.add_argument("--friction", default="eq15", help="friction model: simple, eq14, eq15")


def cli_main(args: argparse.Namespace) -> int:
    raw = load_toml(args.config)
    bus = bus_config_from(raw, str(args.config))
    bus = bus.with_overrides(args.bus)
    if args.plan:
        plan = json.loads(args.plan.read_text())
    else:
        plan = dict(QUICK_PLAN if args.quick else FULL_PLAN)
    plan["plan_id"] = plan.get("plan_id") or f"ident-{int(time.time())}"
    out: Path = args.out
    mcap = run_plan(bus, plan, out, args.timeout)
    desc = load_description()
    gains = [j.drive_gain_nm_per_a for j in desc.joints]
    train, test = export_segments(mcap, plan["plan_id"], out, gains, bus.keys.experiment)
    urdf = out / "robot.urdf"
    urdf.write_text(to_urdf(desc))
    ratios = tuple(j.gear_ratio for j in desc.joints)
    options = AnalyzeOptions(
        friction=args.friction,
        gear_ratios=ratios,
        rate_hz=ANALYSIS_RATE_HZ,
        position_cutoff_hz=ANALYSIS_CUTOFF_HZ,
        torque_cutoff_hz=ANALYSIS_CUTOFF_HZ,
        skip_short_files=True,
    )
    summary = analyze(urdf, train, test, out, options)
    print(json.dumps({k: summary[k] for k in ("rms_before", "rms_after", "effects")}, indent=1))
    print(f"model: {out / 'model.json'}  report: {out / 'report.md'}")
    return 0
