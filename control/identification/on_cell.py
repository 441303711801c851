"""`leadthrough identify`: run the identification experiments on a live cell and fit a model.

Everything goes through the product, exactly as on the real robot: the gateway enters
IDENTIFYING (the operator holds the enabling device), the control process plays the excitation
plan as position/velocity commands, the CAN driver forwards them, and this command records the
whole bus into ``OUT/identify.mcap``. Afterwards each experiment segment is exported to the
measurement CSV format, the "train" segments (friction, gravity, inertia runs and training
multi-sines) fit the model and the "test" multi-sines validate it (`leadthrough analyze`):
``OUT/model.json``, ``OUT/report.md``, ``OUT/summary.json``. The "inner_loop" segments (velocity
steps per joint) estimate the vendor loop's gains, eq. (19), and from them the outer loop's ω and
Υ_I (:mod:`control.identification.inner_loop`): ``OUT/inner_loop.json``, with the lines to put in
the cell config's ``[control]``.

On a terminal a bar on stderr counts the experiments played of those planned, with the time
left from the share of the plan's time played, then the analysis's stages (``--no-progress``:
none; in a pipe or a log the output is the same lines as without it).
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path
from typing import Any

import numpy as np

from control.experiments import VALIDATE, build_plan
from control.identification.analyze import analyze
from control.identification.inner_loop import (
    DELAYS,
    InnerLoopEstimate,
    InnerLoopRun,
    fit_inner_loop_runs,
)
from control.identification.report import write_report
from control.identification.stages import AnalyzeOptions, stage_bar
from control.identification.validation_runs import score_validation
from gateway.bus import BusConfig, bus_config_from
from gateway.config import load_toml
from gateway.current_zero_file import write_stored_zero
from gateway.errors import LeadthroughError
from gateway.messages import FLAG_PREV_COAST, FLAG_PREV_HOLD, decode_json
from gateway.operator_request import operator_request
from gateway.progress import ProgressBar, add_progress_argument, progress_bar, progress_enabled
from gateway.recorder import BusRecorder, RecordedStates, export_csv, iter_mcap, read_states
from gateway.robot.description import load_description
from gateway.robot.urdf import to_urdf

#: The inner-loop experiment: per joint, velocity steps to ±0.05 rad/s for 0.3 s (15 mrad).
INNER_LOOP_STEPS: dict[str, Any] = {"joints": [1, 2, 3, 4, 5, 6], "speed_rad_s": 0.05,
                                    "step_s": 0.3}  # fmt: skip
#: The servo rate of the vendor loop (the manual's 1 kHz, drivers/can/PROTOCOL.md §2.1) [s].
SERVO_PERIOD_S = 0.001

#: Where the multi-sines are centred, from the start pose [rad]: J2 (shoulder) and J3 (elbow)
#: over the volume a painter reaches from the home pose (J2 about -0.45..0.65, J3 -0.15..0.9
#: from a start at 0.15 / 0.25), three boxes for training and a fourth, between them, held out.
#: Gravity and the cylinders' torque depend on the pose: a model fitted around the start pose
#: alone (J2 -0.08..0.40, J3 0..0.50) was off by 4-5 N·m on J2/J3 while the operator's taught
#: path was replayed at J2 -0.38, J3 0.87 (plant seed 1), against 0.6-0.8 held out near the
#: start pose. The moves between boxes are slow sweeps (at most 0.1 rad/s): teaching speeds.
WORKSPACE_OFFSETS: tuple[list[float], ...] = (
    [0.0, -0.3, 0.35, 0.0, 0.0, 0.0],
    [0.0, 0.25, -0.15, 0.0, 0.0, 0.0],
    [0.0, 0.2, 0.4, 0.0, 0.0, 0.0],
    [0.0, -0.15, 0.1, 0.0, 0.0, 0.0],
)

#: A motion like teaching, recorded to judge the model on and never fitted (role "validate",
#: :func:`control.experiments.teaching_strokes`): every joint at once, 0.5-2 °/s, reversing at
#: each stroke and starting each from rest, in the held-out box; about 25 s of robot time.
TEACHING_VALIDATION: dict[str, Any] = {
    "seed": 11, "strokes": 4, "amplitude_rad": 0.03, "speeds_deg_s": [0.5, 2.0], "rest_s": 1.0,
    "offset_rad": WORKSPACE_OFFSETS[3], "role": "validate",
}  # fmt: skip

#: The validation's kind of motion in two training boxes (role "train", other seeds): the slow
#: sliding, the reversals and the starts from rest that teaching asks of the friction model,
#: which constant-speed sweeps at 2 and 8 °/s never reach; about 30 s of robot time each.
TEACHING_TRAINING: tuple[dict[str, Any], ...] = tuple(
    {**TEACHING_VALIDATION, "seed": seed, "offset_rad": offset, "role": "train"}
    for seed, offset in ((12, WORKSPACE_OFFSETS[0]), (13, WORKSPACE_OFFSETS[1]))
)

#: The paper's plan (Section 4): every joint's friction at 0.5–4 °/s and faster, gravity sweeps,
#: inertia runs, and multi-sine excitation; about 25 minutes on the robot.
FULL_PLAN: dict[str, Any] = {
    "friction": {"joints": [1, 2, 3, 4, 5, 6], "amplitude_rad": 0.2,
                 "speeds_deg_s": [0.5, 1.0, 2.0, 4.0, 8.0, 16.0]},
    "gravity": {"joints": [2, 3, 5], "amplitude_rad": 0.4, "speed_deg_s": 2.0},
    "inertia": {"pairs": [[1, 1], [2, 2], [3, 3], [2, 3], [3, 2], [1, 2]],
                "amplitude_rad": 0.15, "period_s": 2.0, "slow_speed_deg_s": 2.0},
    "inner_loop": INNER_LOOP_STEPS,
    "multisine": [
        {"seed": 1, "duration_s": 60, "amplitude_rad": [0.3, 0.25, 0.25, 0.5, 0.5, 0.5],
         "base_hz": 0.1, "harmonics": 5, "role": "train", "offset_rad": WORKSPACE_OFFSETS[0]},
        {"seed": 2, "duration_s": 60, "amplitude_rad": [0.3, 0.25, 0.25, 0.5, 0.5, 0.5],
         "base_hz": 0.1, "harmonics": 5, "role": "train", "offset_rad": WORKSPACE_OFFSETS[1]},
        {"seed": 3, "duration_s": 40, "amplitude_rad": [0.3, 0.25, 0.25, 0.5, 0.5, 0.5],
         "base_hz": 0.1, "harmonics": 5, "role": "train", "offset_rad": WORKSPACE_OFFSETS[2]},
        {"seed": 7, "duration_s": 40, "amplitude_rad": [0.25, 0.2, 0.2, 0.4, 0.4, 0.4],
         "base_hz": 0.13, "harmonics": 5, "role": "test", "offset_rad": WORKSPACE_OFFSETS[3]},
    ],
    "teaching": [TEACHING_VALIDATION],
    "pause_s": 1.0,
}  # fmt: skip

#: Controller-rate recordings (125–500 Hz) are analysed at (about) 125 Hz, torque and kinematics
#: filtered with one 20 Hz cutoff so neither leads the other. Measured on the virtual cell (the
#: truth model against the measurement): at 10 Hz the friction reversals, smeared in the
#: filtered torque but sharp in the model computed from the filtered velocity, left 2.4× the
#: noise floor on joint 1; at 20 Hz, 1.0×.
ANALYSIS_RATE_HZ = 125.0
ANALYSIS_CUTOFF_HZ = 20.0

#: A short plan for the virtual cell's tests and demos (338 s of robot time from the GR630ST's
#: start pose, 63 s of it the two training teaching motions).
QUICK_PLAN: dict[str, Any] = {
    "friction": {"joints": [1, 2, 3, 4, 5, 6], "amplitude_rad": 0.1,
                 "speeds_deg_s": [2.0, 8.0]},
    "inner_loop": INNER_LOOP_STEPS,
    "multisine": [
        {"seed": 1, "duration_s": 30, "amplitude_rad": [0.3, 0.25, 0.25, 0.5, 0.5, 0.5],
         "base_hz": 0.1, "harmonics": 5, "role": "train", "offset_rad": WORKSPACE_OFFSETS[0]},
        {"seed": 2, "duration_s": 30, "amplitude_rad": [0.3, 0.25, 0.25, 0.5, 0.5, 0.5],
         "base_hz": 0.12, "harmonics": 5, "role": "train", "offset_rad": WORKSPACE_OFFSETS[1]},
        {"seed": 3, "duration_s": 20, "amplitude_rad": [0.3, 0.25, 0.25, 0.5, 0.5, 0.5],
         "base_hz": 0.11, "harmonics": 5, "role": "train", "offset_rad": WORKSPACE_OFFSETS[2]},
        {"seed": 7, "duration_s": 20, "amplitude_rad": [0.25, 0.2, 0.2, 0.4, 0.4, 0.4],
         "base_hz": 0.13, "harmonics": 5, "role": "test", "offset_rad": WORKSPACE_OFFSETS[3]},
    ],
    "teaching": [*TEACHING_TRAINING, TEACHING_VALIDATION],
    "pause_s": 0.5,
}  # fmt: skip


def _last_report(mcap: Path, key: str, plan_id: str) -> dict[str, Any]:
    last: dict[str, Any] | None = None
    for _topic, _t, payload in iter_mcap(mcap, [key]):
        msg = decode_json(payload, "experiment")
        if msg.get("plan_id") == plan_id:
            last = msg
    if last is None:
        raise LeadthroughError(f"{mcap}: no progress of plan {plan_id} was recorded")
    return last


#: identification starts from standstill after servo-on (the gateway refuses it before): wait
#: this long for the gateway to accept a plan and the arm to be still this long [s]. After
#: servo-on a joint with stiction can hunt around the hold for a second or two before it sticks.
SETTLE_WAIT_S, SETTLED_S = 20.0, 0.5


def wait_until_playable(bus: BusConfig, wait_s: float = SETTLE_WAIT_S) -> None:
    """Wait until the gateway would start a plan (its status's ``play_problems`` empty: ready,
    enabling held, servo on, still) and has seen the arm still for :data:`SETTLED_S`, at most
    ``wait_s``; the request that follows says why if it never was. The standstill alone is not
    enough: the arm is still on its brakes before the controller reports servo-on (1.7 s
    between them on one CPU)."""
    deadline = time.monotonic() + wait_s
    told = None
    while time.monotonic() < deadline:
        status = operator_request(bus, "status")
        problems = status.get("play_problems")
        still = status.get("standstill") or {}
        settled = float(still.get("still_for_s") or 0.0) >= SETTLED_S
        if problems == [] and settled:
            return
        why = problems[0] if isinstance(problems, list) and problems else "the robot is settling"
        if why != told:
            print(f"waiting: {why} ...")
            told = why
        time.sleep(0.2)


#: The experiment bar: experiments played / planned, then the plan's share of time and the
#: time left (tqdm's own estimate would assume experiments of equal length: a 0.5 °/s friction
#: run takes about 30 times longer than a 16 °/s one).
EXPERIMENT_BAR_FORMAT = "{desc}: {n_fmt}/{total_fmt} experiments |{bar}| [{elapsed}{postfix}]"
#: The sample time the experiment labels are counted with [s]; labels and counts do not
#: depend on it (the control process builds the plan at the controller's cycle).
_LABEL_DT_S = 0.05


def plan_labels(plan: dict[str, Any], n_joints: int) -> list[str]:
    """The labels of ``plan``'s experiments in the order the cell plays them, as the control
    process builds them (:func:`control.experiments.build_plan`); empty for a plan it would
    refuse (the gateway's reply then says why)."""
    n = n_joints
    try:
        segments = build_plan(
            plan, np.zeros(n), np.full(n, -np.inf), np.full(n, np.inf), _LABEL_DT_S, 0.0
        )
    except ValueError:
        return []
    return [label for label, *_ in segments]


def experiments_done(labels: list[str], playing: object, done: int) -> int:
    """Experiments of ``labels`` played before ``playing`` (the label the status names), at
    least ``done``; a label a plan repeats is looked for after those already done."""
    if not isinstance(playing, str):
        return done
    for k in range(done, len(labels)):
        if labels[k] == playing:
            return k
    return done


def time_left_note(share: float, elapsed_s: float) -> str:
    """``23 % of the plan, 18:02 left``: the time left [s] extrapolated from the share of the
    plan's samples played (the cycle is fixed, so samples are time) in ``elapsed_s``."""
    if share <= 0.0:
        return f"{100 * share:.0f} % of the plan"
    left_s = max(elapsed_s * (1.0 - share) / share, 0.0)
    minutes, seconds = divmod(round(left_s), 60)
    return f"{100 * share:.0f} % of the plan, {minutes}:{seconds:02d} left"


def run_plan(
    bus: BusConfig,
    plan: dict[str, Any],
    out: Path,
    timeout_s: float,
    show_progress: bool | None = None,
    n_joints: int = 6,
) -> Path:
    """Record the bus while the cell plays ``plan``; returns the MCAP path.

    ``show_progress``: the experiment bar (:func:`gateway.progress.progress_bar`'s
    ``enabled``: None on a terminal); ``n_joints`` the robot's, to count the experiments."""
    out.mkdir(parents=True, exist_ok=True)
    mcap = out / "identify.mcap"
    rec = BusRecorder(bus, mcap, {"plan": json.dumps(plan)})
    rec.start()
    try:
        time.sleep(0.5)  # let the recorder's subscription reach the router
        wait_until_playable(bus)
        reply = operator_request(bus, "identify", plan=plan)
        if not reply.get("ok"):
            raise LeadthroughError(f"the gateway refused to identify: {reply.get('message')}")
        print(f"identification running ({reply.get('message')}); keep the enabling device held")
        labels = plan_labels(plan, n_joints)
        with progress_bar(
            len(labels) or None,
            "identify",
            "experiment",
            enabled=show_progress,
            bar_format=EXPERIMENT_BAR_FORMAT if labels else None,
        ) as bar:
            _follow_plan(bus, labels, timeout_s, bar)
    finally:
        rec.stop()
    if rec.error:
        raise LeadthroughError(f"recording failed: {rec.error}")
    return mcap


def _follow_plan(bus: BusConfig, labels: list[str], timeout_s: float, bar: ProgressBar) -> None:
    """Poll the gateway's status until the plan ends: a line per 10 % and per segment (a
    25-minute run on a real cell), and ``bar`` at the experiments played."""
    started = time.monotonic()
    deadline = started + timeout_s
    shown: tuple[int, object] = (-1, None)
    while True:
        status = operator_request(bus, "status")
        plan = status.get("plan") or {}
        if status.get("state") != "identifying":
            if plan.get("state") == "done":
                bar.update_to(len(labels), label="")
                bar.set_note("plan done")
            bar.write(f"identification ended: {status.get('reason')}")
            break
        progress = plan.get("progress")
        if isinstance(progress, int | float):
            segment = plan.get("segment")
            bar.update_to(experiments_done(labels, segment, bar.n), label=str(segment or ""))
            bar.set_note(time_left_note(float(progress), time.monotonic() - started))
            now = (int(10 * progress), segment)
            if now != shown:
                bar.write(f"identification {100 * progress:.0f} % ({segment})")
                shown = now
        if time.monotonic() > deadline:
            operator_request(bus, "stop")
            raise LeadthroughError(f"plan not finished after {timeout_s} s; robot stopped")
        time.sleep(1.0)


#: the CAN driver's name in its health key (drivers.can.driver.PROCESS_NAME, which imports
#: python-can: a test keeps the two equal)
CAN_DRIVER = "can_driver"


def write_current_zero(mcap: Path, key: str, out: Path) -> Path | None:
    """The current sensors' zero the CAN driver ran with during the recording (its newest
    health on ``key``), written to ``out/current_zero.json`` for ``[can] current_zero_file``
    (:mod:`gateway.current_zero_file`): the model is identified from currents corrected by that
    zero, so the driver keeps it. None when the driver measured no zero (it is off)."""
    last: dict[str, Any] | None = None
    for _topic, _t, payload in iter_mcap(mcap, [key]):
        msg = decode_json(payload, "health")
        if msg.get("current_zero_ready") and msg.get("current_zero_samples"):
            last = msg
    if last is None:
        return None
    path = out / "current_zero.json"
    write_stored_zero(
        path,
        np.array(last["current_zero_a"], dtype=float),
        int(last["current_zero_samples"]),
        np.array(last.get("current_zero_noise_a") or [0.0] * len(last["current_zero_a"])),
    )
    return path


def finished_report(mcap: Path, key: str, plan_id: str) -> dict[str, Any]:
    """The plan's last progress report in the recording; raises unless the plan finished."""
    report = _last_report(mcap, key, plan_id)
    if report.get("state") != "done":
        raise LeadthroughError(f"plan {plan_id} did not finish: {report.get('state')} "
                               f"{report.get('reason', '')}")  # fmt: skip
    return report


def export_segments(
    mcap: Path, report: dict[str, Any], recorded: RecordedStates, out: Path, gains: list[float]
) -> tuple[list[Path], list[Path], list[Path]]:
    """Cut the recording (``recorded``, read once: each segment is cut from it) into one CSV
    per experiment segment of ``report`` (:func:`finished_report`): (train files, test
    files, validation files)."""
    train, test, validate = [], [], []
    by_role = {"test": test, VALIDATE: validate}
    for k, seg in enumerate(report["segments"]):
        if seg["role"] == "inner_loop":
            continue  # velocity steps: fit_inner_loop_segments
        name = f"{k:02d}_{seg['label'].replace('/', '_')}.csv"
        path = out / "segments" / name
        path.parent.mkdir(parents=True, exist_ok=True)
        cycles = (seg["start_cycle"], seg["end_cycle"])
        export_csv(mcap, path, gains, cycle_range=cycles, recorded=recorded)
        by_role.get(seg["role"], train).append(path)
    return train, test, validate


def inner_loop_runs(recorded: RecordedStates, cycle_range: tuple[int, int]) -> list[InnerLoopRun]:
    """Cycle-aligned runs of one segment (:class:`InnerLoopRun`): the command answering state
    c is the one state c + 1 echoes (what the CAN driver really sent); a command the driver
    replaced by a hold or a coast is not valid, and a missing cycle starts a new run."""
    by_cycle = {st.cycle: st for st, _ in recorded.states}
    runs, rows = [], []

    def close() -> None:
        if len(rows) > max(DELAYS) + 1:
            cols = [np.array(c) for c in zip(*rows, strict=True)]
            valid = cols[5].astype(bool)
            valid[-(max(DELAYS) + 1) :] = False  # their followed cycle is not in this run
            runs.append(InnerLoopRun(*cols[:5], valid))
        rows.clear()

    for c in range(cycle_range[0], cycle_range[1]):
        st, nxt = by_cycle.get(c), by_cycle.get(c + 1)
        if st is None or nxt is None:
            close()
            continue
        answered = not nxt.flags & (FLAG_PREV_HOLD | FLAG_PREV_COAST)
        rows.append((nxt.q_cmd_rad, nxt.dq_cmd_rad_s, st.q_rad, st.dq_rad_s, st.current_a,
                     answered))  # fmt: skip
    close()
    return runs


def fit_inner_loop_segments(
    mcap: Path,
    report: dict[str, Any],
    recorded: RecordedStates,
    gains: list[float],
    out: Path,
) -> InnerLoopEstimate | None:
    """Eq. (19) from the velocity steps of ``report`` (:func:`finished_report`; None when the
    plan has none), cut from ``recorded``; writes ``out/inner_loop.json``."""
    segments = [s for s in report["segments"] if s["role"] == "inner_loop"]
    if not segments:
        return None
    runs = [r for s in segments for r in inner_loop_runs(recorded, (s["start_cycle"],
                                                                    s["end_cycle"]))]  # fmt: skip
    periods = {st.cycle_period_s for st, _ in recorded.states}
    if len(periods) != 1:
        raise LeadthroughError(f"{mcap}: the controller cycle changed during the recording "
                               f"({sorted(periods)} s)")  # fmt: skip
    (cycle_s,) = periods
    try:
        est = fit_inner_loop_runs(runs, gains, cycle_s, SERVO_PERIOD_S)
    except ValueError as exc:
        raise LeadthroughError(f"inner loop: {exc}") from None
    doc = {**est.to_json(), "cycle_period_s": cycle_s, "servo_period_s": SERVO_PERIOD_S}
    (out / "inner_loop.json").write_text(json.dumps(doc, indent=1))
    return est


def _nm(values: list[float | None]) -> str:
    return "[" + " ".join("—" if v is None else f"{v:.3g}" for v in values) + "]"


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
    add_progress_argument(p)


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
    desc = load_description()
    show = progress_enabled(args)
    mcap = run_plan(bus, plan, out, args.timeout, show, len(desc.joints))
    gains = [j.drive_gain_nm_per_a for j in desc.joints]
    report = finished_report(mcap, bus.keys.experiment, plan["plan_id"])
    zero = write_current_zero(mcap, bus.keys.health(CAN_DRIVER), out)
    if zero is not None:
        print(f"current sensors' zero the model is identified with: {zero}; in the cell "
              f'config\'s [can] set\n  current_zero_file = "{zero.resolve()}"')  # fmt: skip
    recorded = read_states(mcap)  # once: the inner loop and every segment are cut from it
    inner = fit_inner_loop_segments(mcap, report, recorded, gains, out)
    if inner is not None:
        fmt = ", ".join
        print(f"inner loop (eq. 19, command delay {inner.delay_cycles} cycles): "
              f"{out / 'inner_loop.json'}; in the cell config's [control] set")  # fmt: skip
        print(f'  inner_loop = "{(out / "inner_loop.json").resolve()}"')
        print("or write the estimate out in place of omega_rad_s_per_nm and upsilon_i_per_s:")
        print(f"  omega_rad_s_per_nm = [{fmt(f'{v:.4g}' for v in inner.omega_rad_s_per_nm)}]")
        print(f"  upsilon_i_per_s = [{fmt(f'{v:.4g}' for v in inner.upsilon_i_per_s)}]")
    train, test, validate = export_segments(mcap, report, recorded, out, gains)
    if not train and not test and inner is not None:
        return 0  # an inner-loop-only plan: nothing to fit a dynamic model on
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
    with stage_bar(show) as bar:
        summary = analyze(urdf, train, test, out, options, bar=bar)
    if validate:
        summary["validation"] = score_validation(
            out / "model.json", validate, desc, options.stick_velocity_rad_s
        )
        write_report(out, summary)
    print(json.dumps({k: summary[k] for k in ("rms_before", "rms_after", "effects")}, indent=1))
    for v in summary.get("validation", {}).get("files", []):
        teach = v["by_speed"]["teaching"]["rms_after"]
        print(f"slow, reversing motion never fitted ({Path(v['file']).name}): raw error "
              f"{_nm(v['rms_after'])} N·m, at teaching speeds {_nm(teach)} N·m (measured "
              f"torque {_nm(v['rms_measured'])} N·m)")  # fmt: skip
    print(f"model: {out / 'model.json'}  report: {out / 'report.md'}")
    return 0
