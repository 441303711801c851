"""`leadthrough demo`: the whole product on the virtual cell, with a simulated operator.

The virtual robot of ``--plant-seed`` is first commissioned as a user commissions a real one,
by `leadthrough identify` (or the cached result of that for this plant and code,
:mod:`sim_bridge.commission`). Then the operator presses the enabling device, grabs the tool
and guides it along a rectangle in a vertical plane (like the paper's Fig. 11 path) while the
lead-through law of ``--strategy`` makes the arm light (the sensorless admittance by default:
the lightest law on every plant benched, docs/results/teaching.md), pressing the teach
handle's mark button at each corner; the gateway writes the taught program. The operator lets
go, the session is stopped, and the program is replayed (`leadthrough replay`). Prints mean
and peak operator force, tool travel, the loop rate achieved, the commands missed, the
program's marks and how closely the replay followed the taught path; writes a plot and a JSON
summary.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

from control.config import STRATEGIES
from gateway.recorder import BusRecorder
from sim_bridge.baseline import run_baseline
from sim_bridge.commission import commissioned
from sim_bridge.config import load_sim_config
from sim_bridge.fault_trace import fault_trace
from sim_bridge.harness import SIM_CELL, Stack

#: [t_s, dx_m, dy_m, dz_m] from the tool position at teaching onset
DEMO_PATH = [
    [0.0, 0.0, 0.0, 0.0],
    [1.0, 0.0, 0.0, 0.0],
    [6.0, 0.30, 0.0, 0.0],
    [7.0, 0.30, 0.0, 0.0],
    [10.5, 0.30, 0.0, -0.20],
    [11.5, 0.30, 0.0, -0.20],
    [16.5, 0.0, 0.0, -0.20],
    [17.5, 0.0, 0.0, -0.20],
]
#: after onset: the hand lets go of the tool (the enabling device stays held for the replay)
HAND_OFF_AFTER_S = 18.0
#: after onset: the teach handle's mark button at the start and at each corner [s]
MARKS_AT_S = (0.5, 6.5, 11.0, 17.0)
#: tool speed of the replay [mm/s]
REPLAY_SPEED_MM_S = 100.0
#: the operator's arm: stiff enough to steer a heavy arm along a line, like a painter's grip
HAND = {"hand_stiffness_n_per_m": 1500.0, "hand_damping_n_s_per_m": 300.0, "max_force_n": 80.0}
#: the baseline's second operator: a hand stiff and strong enough to keep the tool near the
#: path, so its force is what the path needs from anyone
BASELINE_STIFF_HAND = {
    "hand_stiffness_n_per_m": 50_000.0,
    "hand_damping_n_s_per_m": 3_000.0,
    "max_force_n": 1.0e6,
}


def teaching_metrics(
    truth: dict[str, np.ndarray], summary: dict[str, Any], rows: int | None = None
) -> dict[str, Any]:
    """Figures of merit over the teaching interval of a truth log (its first ``rows``)."""
    mask = truth["teaching"] > 0.5
    if rows is not None:
        mask[rows:] = False
    if not np.any(mask):
        raise RuntimeError("the robot never followed the control process's commands")
    t = truth["t_s"][mask]
    force = np.linalg.norm(np.stack([truth[f"f_{a}"][mask] for a in "xyz"], axis=1), axis=1)
    tool = np.stack([truth[f"tool_{a}"][mask] for a in "xyz"], axis=1)
    steps = np.linalg.norm(np.diff(tool, axis=0), axis=1)
    duration = float(t[-1] - t[0]) if len(t) > 1 else 0.0
    cycles = summary.get("teaching_cycles", 0)
    missed = summary.get("teaching_missed_cycles", 0)
    # The command cycles are where the truth's cycle counter moves on: every row on the LTC
    # controller, every SYNC on CiA 402 drives (whose rows are their servo cycles).
    new_cycle = np.r_[True, np.diff(truth["cycle"]) != 0]
    starts = np.flatnonzero(new_cycle)
    period_s = float(np.median(np.diff(truth["t_s"][starts]))) if starts.size > 1 else 0.0
    if rows is not None:  # the simulator's counters span the whole run: count these rows
        sel = np.flatnonzero(mask)
        cycle_of = np.cumsum(new_cycle)[sel]  # the command cycle each row belongs to
        cycles = int(np.unique(cycle_of).size)
        answered = int(np.unique(cycle_of[np.isfinite(truth["latency_s"][sel])]).size)
        missed = cycles - answered
    return {
        "teaching_duration_s": duration,
        "mean_force_n": float(force.mean()),
        "peak_force_n": float(force.max()),
        "tool_path_length_m": float(steps.sum()),
        "tool_net_displacement_m": float(np.linalg.norm(tool[-1] - tool[0])),
        "loop_rate_hz": (cycles - missed) / duration if duration > 0 else 0.0,
        "nominal_rate_hz": 1.0 / (period_s or summary["cycle_period_s"]),
        "commands_missed": int(missed),
        "controller_faults": summary.get("faults", []),
        "latency_p50_ms": (summary.get("latency_p50_s") or float("nan")) * 1e3,
        "latency_p99_ms": (summary.get("latency_p99_s") or float("nan")) * 1e3,
    }


def plot(truth: dict[str, np.ndarray], out_png: Path, rows: int, replay: np.ndarray) -> None:
    """Tool path taught (the first ``rows`` of the truth log), the replayed tool path
    (``replay`` (T, 3) [m], world), and the operator's force while teaching."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    mask = truth["teaching"] > 0.5
    mask[rows:] = False
    t = truth["t_s"][mask] - truth["t_s"][mask][0]
    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(11, 4.2))
    x, z = truth["tool_x"][mask], truth["tool_z"][mask]
    x0, z0 = x[0], z[0]
    path = np.array(DEMO_PATH)
    ax1.plot(path[:, 1] * 1e3, path[:, 3] * 1e3, "k--", lw=1, label="operator's target")
    ax1.plot((x - x0) * 1e3, (z - z0) * 1e3, lw=1.5, label="tool, taught")
    if replay.size:
        ax1.plot((replay[:, 0] - x0) * 1e3, (replay[:, 2] - z0) * 1e3, ":", lw=1.5,
                 label="tool, replayed")  # fmt: skip
    ax1.set(xlabel="x [mm]", ylabel="z [mm]", title="Tool path during lead-through")
    ax1.axis("equal")
    ax1.legend(loc="best", fontsize=8)
    for axis in "xyz":
        ax2.plot(t, truth[f"f_{axis}"][mask], lw=1, label=f"F{axis}")
    force = np.linalg.norm(np.stack([truth[f"f_{a}"][mask] for a in "xyz"], axis=1), axis=1)
    ax2.plot(t, force, "k", lw=1.2, label="|F|")
    ax2.set(xlabel="time since teaching began [s]", ylabel="operator force [N]")
    ax2.set_title("Force the operator applies at the tool")
    ax2.legend(loc="best", fontsize=8)
    fig.tight_layout()
    fig.savefig(out_png, dpi=110)
    plt.close(fig)


def configure_parser(p: argparse.ArgumentParser) -> None:
    p.description = (
        "Run the demo: virtual cell, drivers, control and gateway as separate processes; a "
        "simulated operator guides the tool along a rectangle. Prints a table, writes "
        "OUT/demo.png, OUT/summary.json and OUT/recording.mcap (everything on the bus)."
    )
    p.add_argument("--out", type=Path, default=Path("demo_out"), help="output folder")
    p.add_argument(
        "--baseline",
        action="store_true",
        help="instead: the paper's baseline, servo off and brakes released, the operator drags "
        "the arm along the same path (the plant alone, faster than real time)",
    )
    p.add_argument(
        "--plant-seed",
        type=int,
        default=0,
        help="the virtual robot to teach (0: the documented default plant)",
    )
    p.add_argument(
        "--cell",
        type=Path,
        default=SIM_CELL,
        help="the product's cell config (default deploy/config/sim_cell.toml; "
        "deploy/config/sim_cell_cia402.toml: CiA 402 drives over CANopen); the virtual cell "
        "runs the controller its [can].adapter speaks to",
    )
    p.add_argument(
        "--strategy",
        choices=STRATEGIES,
        default="admittance",
        help="the lead-through law the operator teaches with, in place of the cell config's "
        "[control].strategy (default: admittance, the sensorless admittance with its start-up "
        "dither; zero_moment: the paper's eq. 21 with eq. 28; paper: eqs. 28 and 30)",
    )


def baseline_main(out: Path, plant_seed: int) -> int:
    """``--baseline``: the operator force with the servo off and the brakes released."""
    cfg = dataclasses.replace(load_sim_config(), plant_seed=plant_seed)
    duration = float(DEMO_PATH[-1][0])
    print(
        f"baseline: servo off, brakes released, cylinders at {cfg.cylinders.initial_bar} bar; "
        f"the operator drags the tool along the demo's path ({duration:.1f} s) ..."
    )
    human = run_baseline(cfg, DEMO_PATH, HAND, duration)
    needed = run_baseline(cfg, DEMO_PATH, BASELINE_STIFF_HAND, duration)
    (out / "baseline.json").write_text(
        json.dumps({"demo_hand": human, "stiff_unbounded_hand": needed}, indent=2)
    )
    rows = [
        ("demo's hand (max 80 N): mean / peak force", f"{human['mean_force_n']:.1f} / "
         f"{human['peak_force_n']:.1f} N"),
        ("  of the time at its limit", f"{human['force_saturated_share'] * 100:.0f} %"),
        ("  tool off the path, max", f"{human['max_tool_off_path_m'] * 1e3:.0f} mm"),
        ("force the path needs: mean / peak", f"{needed['mean_force_n']:.1f} / "
         f"{needed['peak_force_n']:.1f} N"),
        ("  tool off the path, max", f"{needed['max_tool_off_path_m'] * 1e3:.0f} mm"),
    ]  # fmt: skip
    width = max(len(r[0]) for r in rows)
    print()
    for name, value in rows:
        print(f"  {name:<{width}}  {value}")
    print(f"\nsummary: {out / 'baseline.json'}")
    return 0


def _fmt(values: list[float | None]) -> str:
    return "[" + " ".join("-" if v is None else f"{v:.3g}" for v in values) + "]"


def cli_main(args: argparse.Namespace) -> int:
    out: Path = args.out
    out.mkdir(parents=True, exist_ok=True)
    if args.baseline:
        return baseline_main(out, args.plant_seed)
    operator = {
        "enabling_after_s": 0.0,
        "hand_off_after_s": HAND_OFF_AFTER_S,
        "mark_at_s": list(MARKS_AT_S),
        "mode": "path",
        "path": DEMO_PATH,
        **HAND,
    }
    t0 = time.monotonic()
    # The product knows nothing of this plant: it teaches with what `leadthrough identify`
    # measured on it through this cell's drives (built now, 5-7 minutes, or reused).
    done = commissioned(args.plant_seed, cell_file=args.cell)
    ident = done.summary
    print(f"model: identified on plant seed {args.plant_seed} ({done.folder}); held-out torque "
          f"RMS per joint {_fmt(ident['rms_after'])} N·m, effects found: "
          f"{', '.join(e['name'] for e in ident['effects']) or 'none'}")  # fmt: skip
    print(f"starting the virtual cell, the drivers, the control process ({args.strategy}) and "
          "the gateway ...")  # fmt: skip
    with Stack(
        out / "run", sim_overrides={"operator": operator}, plant_seed=args.plant_seed,
        model=done.model, inner_loop=done.inner_loop, current_zero=done.current_zero,
        cell_file=args.cell, cell_overrides={"control": {"strategy": args.strategy}},
    ) as stack:  # fmt: skip
        stack.start()
        # Everything on the bus, as `leadthrough record` writes it (self-describing MCAP).
        recorder = BusRecorder(stack.bus, out / "recording.mcap", {"source": "leadthrough demo"})
        recorder.start()
        try:
            status = stack.start_teaching()
            program = Path(status["program"]["path"])
            print(f"teaching: the simulated operator guides the tool ({HAND_OFF_AFTER_S:.0f} s) "
                  f"and marks the corners; the gateway writes {program} ...")  # fmt: skip
            # Wait cheaply (reading the growing truth log would take CPU from the product);
            # a cell that leaves teaching (a fault) ends the demo at once, naming why.
            taught_from = time.monotonic()
            while time.monotonic() < taught_from + HAND_OFF_AFTER_S + 0.5:
                stack.check_alive()
                status = stack.request("status", timeout_s=1.0)
                if status.get("state") != "teaching":
                    elapsed = time.monotonic() - taught_from
                    print(f"leadthrough demo: teaching ended {elapsed:.1f} s in: the cell is "
                          f"{status.get('state')} ({status.get('reason')}); the demo stops "
                          f"(logs in {out / 'run'})", file=sys.stderr)  # fmt: skip
                    print(fault_trace(stack.truth()), file=sys.stderr)
                    return 1
                time.sleep(0.5)
            taught_rows = stack.truth()["t_s"].size
            stack.request("stop")
            try:
                replay = replay_program(stack, program)
            except RuntimeError:
                print(fault_trace(stack.truth()), file=sys.stderr)
                raise
        finally:
            recorder.stop()
    truth = stack.truth()
    summary = json.loads(stack.sim_summary.read_text())
    m = teaching_metrics(truth, summary, taught_rows)
    first_row = replay.pop("first_row")
    m.update(replay)
    replayed = np.stack([truth[f"tool_{a}"][first_row:] for a in "xyz"], axis=1)
    plot(truth, out / "demo.png", taught_rows, replayed)
    m["wall_time_s"] = time.monotonic() - t0
    m["plant_seed"] = args.plant_seed
    m["strategy"] = args.strategy
    m["model"] = str(done.model)
    m["recording"] = str(out / "recording.mcap")
    m["recording_messages"] = recorder.count
    (out / "summary.json").write_text(json.dumps(m, indent=2))
    replay_line = f"{m['replay_result']}, {m['replay_duration_s']:.1f} s"
    if m["replay_result"] != "done":
        replay_line += f" ({m['replay_reason'] or 'no reason given'})"
    rows = [
        ("lead-through law", args.strategy),
        ("mean operator force", f"{m['mean_force_n']:.1f} N"),
        ("peak operator force", f"{m['peak_force_n']:.1f} N"),
        ("tool travel (path length)", f"{m['tool_path_length_m'] * 1e3:.0f} mm"),
        ("loop rate achieved", f"{m['loop_rate_hz']:.1f} Hz of {m['nominal_rate_hz']:.0f} Hz"),
        ("commands missed", f"{m['commands_missed']}"),
        (
            "wire-to-wire latency p50/p99",
            f"{m['latency_p50_ms']:.2f} / {m['latency_p99_ms']:.2f} ms",
        ),
        ("controller faults", ", ".join(m["controller_faults"]) or "none"),
        ("taught program", f"{m['program']} ({m['marks']} marks)"),
        ("replay at 100 mm/s", replay_line),
        ("taught path from the replayed, p95", f"{m['replay_path_error_mm']:.2f} mm"),
        *_adaptation_rows(m.get("model_adaptation") or {}),
    ]
    width = max(len(r[0]) for r in rows)
    print()
    for name, value in rows:
        print(f"  {name:<{width}}  {value}")
    print(f"\nplot: {out / 'demo.png'}   summary: {out / 'summary.json'}   "
          f"recording: {out / 'recording.mcap'} ({recorder.count} messages)")  # fmt: skip
    return 0 if not m["controller_faults"] and m["replay_result"] == "done" else 1


def _adaptation_rows(adapted: dict[str, Any]) -> list[tuple[str, str]]:
    """The summary's lines for eq. (29) in the replay (control/model_adaptation.py)."""
    if not adapted.get("windows_used"):
        return []
    return [
        ("payload learned in the replay", f"{adapted['mass_kg']:+.2f} kg "
                                          f"({adapted['windows_used']} windows of 0.1 s)"),
        ("model error in the replay, as identified",
         f"{_fmt(adapted['residual_rms_identified_nm'])} N·m RMS"),
        ("model error in the replay, as adapted",
         f"{_fmt(adapted['residual_rms_adapted_nm'])} N·m RMS"),
        ("the law compensates the learned payload",
         "yes" if adapted.get("applied") else f"no: {adapted.get('not_taken') or 'not yet'}"),
    ]  # fmt: skip


def replay_program(stack: Stack, program: Path) -> dict[str, Any]:
    """Start a new session and replay ``program`` as `leadthrough replay` does; its figures
    (``first_row``: the truth log's first row of the replay session)."""
    from control.taught_path_kinematics import path_error_m
    from gateway.program import read_program
    from gateway.replay import replay_plan
    from gateway.robot.description import load_description

    taught = read_program(program)
    print(f"taught program: {len(taught.marks)} marks, {taught.t_s.size} trace samples; "
          f"replaying it at {REPLAY_SPEED_MM_S:.0f} mm/s ...")  # fmt: skip
    stack.request("start")
    status = stack.wait_status(
        lambda s: s.get("state") in ("teaching", "fault"), 20.0, "arm at rest, enabling held"
    )
    if status.get("state") == "fault":
        raise RuntimeError(f"the cell faulted before the replay: {status.get('reason')}")
    first_row = stack.truth()["t_s"].size
    plan = replay_plan(program, REPLAY_SPEED_MM_S)
    reply = stack.request("replay", plan=plan)
    if not reply.get("ok"):
        raise RuntimeError(f"replay refused: {reply.get('message')}")
    t0 = time.monotonic()
    status = stack.wait_status(
        lambda s: (s.get("plan") or {}).get("state") != "running", 120.0, "replay finished"
    )
    duration = time.monotonic() - t0
    stack.request("stop")
    # eq. (29) took the replay's free motion: the model checked on data it was not fitted to
    time.sleep(1.0)  # the control process's slow loop processes the last windows
    adapted = stack.request("status").get("model_adaptation") or {}
    truth = stack.truth()
    q = np.stack([truth[f"q{j + 1}"][first_row:] for j in range(taught.q_rad.shape[1])], axis=1)
    error = path_error_m(load_description(), q, taught.q_rad) if len(q) > 1 else float("nan")
    return {
        "program": str(program),
        "marks": len(taught.marks),
        "replay_result": status["plan"]["state"],
        # why a replay that did not finish stopped (the fault, the released device, ...)
        "replay_reason": status["plan"].get("reason", ""),
        "replay_duration_s": duration,
        "replay_path_error_mm": error * 1e3,
        "first_row": first_row,
        "model_adaptation": adapted,
    }
