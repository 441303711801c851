"""`leadthrough teach-bench`: how hard is it to drag the tool along a spray path, per strategy.

The virtual robot of ``--plant-seed`` is commissioned as a user commissions a real one (the
product's own identification, :mod:`sim_bridge.commission`; the product never sees the plant's
truth). A simulated operator then drags the tool along a raster spray path like the paper's
Fig. 11(b) (:mod:`sim_bridge.teach_raster`): a zig-zag of horizontal passes on the vertical
plane facing the robot (y–z), centred where the tool starts (the first leg takes the tool there
from its start), at a painter's speed, stopping at each corner. The hand is a spring-damper
between where the painter wants the tool and where it is (:data:`HAND`, its force saturates at
``max_force_n``), with physiological tremor (:data:`TREMOR_M` at :data:`TREMOR_HZ`): the hand
must *push* the robot, and the force it needs is what the paper's Fig. 13 measures with its force
sensor.

Strategies:

- ``offservo``: servo off, brakes released, only the assist cylinders carry the arm (the
  paper's baseline), at the pressures that best offset gravity on joints 2 and 3 where the
  path starts; the plant alone, in this process, faster than real time. On the GR630ST's
  start pose joint 2's crank cylinder has almost no moment arm (about -11 N·m per bar against
  466 N·m of gravity), so no pressure balances it there and the hand cannot keep up;
- ``inertia``: the floor no law can beat: the plant's own arm with gravity, friction, the
  cylinders and every injected effect taken away, dragged through the same hand (the plant
  alone, faster than real time); with ``--guide`` (any but free) the gun's orientation is
  held by an ideal fixture, the floor of an orientation-locked guide. What it costs is the
  arm's inertia (and the hand's own spring-damper), which a law can only lower by rendering
  less than the arm's mass;
- ``paper``: the paper's adaptive method, ``[control] strategy = "paper"``: the zero-moment
  law with eqs. (28) and (30) adapting ω̂ and Υ̂_I together from the measured current
  (control/rt/src/law/outer_loop.rs, PaperAdaptation), Υ̂_I starting from the paper's 1.2/s
  and ω̂ from the same static gain as commissioned, run as ``best`` is;
- ``best``: the product's zero-moment lead-through (the whole product on the virtual cell as
  separate processes, real time, the controller applying each command one cycle late; ω̂
  adapted by the normalised eq. 28 alone, Υ̂_I as commissioned);
- ``admittance``: the product's sensorless admittance (``[control] strategy = "admittance"``,
  control/rt/src/law/admittance.rs), run as ``best`` is.

Eq. (29), the adaptation of the dynamic parameters, is not run while teaching: the hand's
torque is indistinguishable from a model error in the measured current, so it would be learnt
as part of the robot.

Per strategy: force statistics over the *moving* part of the path (the painter's target
moving; the corner dwells are reported apart), the moment of the hand's force about the
flange (where the paper's force sensor sits), the tool's distance from the intended path
(p95) and whether the operator got to the end of it
(:data:`.teach_bench_metrics.COMPLETED_WITHIN_M`); for the
product's strategies also the motor torque's RMS per joint (the datasheet's K × the reported
current: what the cylinders leave the motors) and the range of the cylinder set-points the
valves received (``[control] pressure_schedule``). Writes
``OUT/summary.json`` and ``OUT/teach_bench.png``.

``adaptation`` in the summary (from the ``paper`` run, else ``best``) compares the loop's
estimates with the plant's hidden inner gains, which this harness reads for scoring only: ω̂
and Υ̂_I = ω̂_I as the control process last published them against ω = 1/(K·K_p) and
K_I/K_p. K is the datasheet torque constant, the one the product measures
torque with (the plant's own differs by its drawn error). With ``--online-estimate`` the
control process also runs its online estimate of K_p and K_I (``[control]
inner_loop_estimate``, with a :data:`DITHER_A` torque dither so that teaching excites K_p) and
the summary adds its final values.

On a terminal a bar on stderr counts the strategies run (``--no-progress``: none).
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import json
import time
from pathlib import Path
from typing import Any

import mujoco
import numpy as np

from gateway.bus import open_client
from gateway.guide_modes import GUIDES
from gateway.progress import add_progress_argument, progress_bar, progress_enabled
from sim_bridge.baseline import drag_released
from sim_bridge.commission import commissioned, newest_commissioned
from sim_bridge.config import load_sim_config
from sim_bridge.harness import SIM_CELL, Stack
from sim_bridge.plant import Plant
from sim_bridge.teach_bench_metrics import (
    adaptation_report,
    commands_missed,
    flange_poses,
    metrics,
    orientation_drift_deg,
)
from sim_bridge.teach_phases import PHASES
from sim_bridge.teach_raster import (
    HEIGHT_M,
    PASSES,
    SPEED_M_S,
    WIDTH_M,
    raster_facing,
    raster_path,
    tool_axis_at_start,
)
from sim_bridge.teach_seeds import aggregate, parse_seeds, print_seed_table, seed_rows

#: the painter's hand (as the demo's): stiff enough to steer a heavy arm along a line
HAND = {"hand_stiffness_n_per_m": 1500.0, "hand_damping_n_s_per_m": 300.0, "max_force_n": 80.0}
#: physiological tremor of the hand: amplitude per axis [m] and frequency [Hz]
TREMOR_M, TREMOR_HZ = 0.0005, 9.0
STRATEGIES = ("offservo", "inertia", "paper", "best", "admittance")
#: the ``[control]`` settings of each product strategy; "paper" starts Υ̂_I from the paper's
#: 1.2/s and adapts it with ω̂ (eqs. 28, 30; control/rt/src/law/outer_loop.rs)
PRODUCT_STRATEGIES = {
    "paper": {"strategy": "paper", "paper_upsilon_i0_per_s": 1.2},
    "best": {},
    "admittance": {"strategy": "admittance"},
}
#: ``--online-estimate``: the torque dither that lets the online inner-loop estimate see K_p,
#: per joint [A] (control/rt/src/law/inner_estimate.rs)
DITHER_A = 0.03


def balancing_bar(cfg: Any) -> tuple[list[float], list[float]]:
    """The cylinder pressures [bar] that best carry the gravity torque of joints 2 and 3 at
    the arm's start pose (least squares, clipped to 0..10 bar), from the plant's own physics
    (the scorer's knowledge, as a cell engineer tunes the regulators for the working pose),
    and the gravity torque [N·m] per joint they leave."""
    plant = Plant(cfg)
    mujoco.mj_forward(plant.model, plant.data)
    gravity = plant.data.qfrc_bias[: plant.n].copy()  # at rest: the gravity torque
    q = plant.data.qpos[: plant.n].copy()
    per_bar = np.stack(
        [plant.cylinders.torque_nm(q, np.eye(2)[k]) for k in range(2)], axis=1
    )  # (n, 2): joint torque of 1 bar in each cylinder
    bar = np.clip(np.linalg.lstsq(per_bar[1:3], gravity[1:3], rcond=None)[0], 0.0, 10.0)
    return [float(v) for v in bar], [float(v) for v in gravity - per_bar @ bar]


def run_offservo(plant_seed: int, path: list[list[float]], tail_s: float = 2.0) -> dict[str, Any]:
    """The paper's baseline: the released arm dragged along ``path`` (plant only), the
    cylinders at the pressures that best offset its gravity where the path starts
    (:func:`balancing_bar`)."""
    cfg = dataclasses.replace(load_sim_config(), plant_seed=plant_seed)
    bar, unbalanced = balancing_bar(cfg)
    cfg = dataclasses.replace(
        cfg, cylinders=dataclasses.replace(cfg.cylinders, initial_bar=tuple(bar))
    )
    hand = {**HAND, "tremor_m": TREMOR_M, "tremor_hz": TREMOR_HZ}
    trace = drag_released(cfg, path, hand, path[-1][0] + tail_s)
    t = trace["t_s"]
    out = metrics(path, t - t[0], trace["tool"], trace["origin"], trace["force"], trace["flange"],
                  trace["q"])  # fmt: skip
    out["cylinders_bar"] = bar
    out["gravity_left_at_start_nm"] = unbalanced
    return out


def inertia_config(plant_seed: int) -> Any:
    """The plant of ``plant_seed`` with only its inertia left (:func:`run_inertia`); the
    caller also turns gravity off (``drag_released(..., gravity=False)``)."""
    nominal = load_sim_config()
    # the plant draws the seed's friction as factors on these (zero stays zero), the cylinders
    # hold no pressure whatever their stroke, and its inertials (drawn from the seed) are all
    # that is left
    frictionless = tuple(
        dataclasses.replace(f, tau_s_nm=0.0, tau_c_nm=0.0, tau_v1_nm_s_per_rad=0.0,
                            tau_v2_nm_s2_per_rad2=0.0, fourier_nm=(0.0,) * 6)
        for f in nominal.friction
    )  # fmt: skip
    return dataclasses.replace(
        nominal,
        plant_seed=plant_seed,
        friction=frictionless,
        effects=(),
        cylinders=dataclasses.replace(
            nominal.cylinders,
            initial_bar=(0.0, 0.0),
            noise_bar=0.0,
            # an ideal reservoir at 0 bar: no stroke compresses a gas to a pressure
            units=tuple(dataclasses.replace(u, gas_length_m=0.0) for u in nominal.cylinders.units),
        ),
    )


def run_inertia(
    plant_seed: int, path: list[list[float]], tail_s: float = 2.0, guide: str | None = None
) -> dict[str, Any]:
    """The floor (module docstring): the plant's arm of ``plant_seed`` weightless,
    frictionless, without cylinders or effects, dragged along ``path``; under a constrained
    ``guide`` (any but free) with the gun's orientation held by an ideal fixture
    (:func:`.baseline.orientation_lock`): a locked wrist no longer turns out of the hand's
    way, so the hand moves more of the arm."""
    hand = {**HAND, "tremor_m": TREMOR_M, "tremor_hz": TREMOR_HZ}
    locked = guide not in (None, "free")
    trace = drag_released(
        inertia_config(plant_seed), path, hand, path[-1][0] + tail_s, gravity=False,
        lock_orientation=locked,
    )  # fmt: skip
    t = trace["t_s"]
    out = metrics(path, t - t[0], trace["tool"], trace["origin"], trace["force"], trace["flange"],
                  trace["q"])  # fmt: skip
    _, rot = flange_poses(plant_seed, trace["q"])
    out["orientation_drift_deg"] = {"max": round(float(orientation_drift_deg(rot).max()), 3)}
    out["guide"] = "orientation-locked" if locked else "free"
    return out


class _LastTelemetry:
    """The control process's last telemetry message, from a subscriber of its own, and the
    loop's estimates over time: (stamp [s, the control process's monotonic clock], ω̂, Υ̂_I)."""

    def __init__(self) -> None:
        self.message: dict[str, Any] | None = None
        self.history: list[tuple[float, list[float], list[float]]] = []

    def __call__(self, sample: Any) -> None:  # zenoh's thread: decode only, never block
        # the scorer's view only: a bad message leaves the last good one
        with contextlib.suppress(ValueError, KeyError, TypeError):
            msg = json.loads(sample.payload.to_bytes())
            self.message = msg
            self.history.append(
                (float(msg["stamp_s"]), msg["omega_rad_s_per_nm"], msg["upsilon_i_per_s"])
            )


def run_best(
    plant_seed: int,
    path: list[list[float]],
    work: Path,
    tail_s: float = 2.0,
    online_estimate: bool = False,
    control: dict[str, Any] | None = None,
    guide: str | None = None,
    newest_commissioning: bool = False,
    cell_file: Path = SIM_CELL,
) -> dict[str, Any]:
    """The product's zero-moment lead-through on the virtual cell, as separate processes;
    ``online_estimate`` turns on the control process's online inner-loop estimate,
    ``control`` sets keys of the cell config's ``[control]`` section (a tuning to try),
    ``guide`` is the constrained guide the operator's start asks for (None: the config's),
    and ``newest_commissioning`` takes the seed's newest commissioning in the cache whatever
    code made it (:func:`.commission.newest_commissioned`; none: commissioned now);
    ``cell_file``: the product's cell config, whose drives the virtual cell runs and the robot
    is commissioned through."""
    newest = newest_commissioned(plant_seed, cell_file=cell_file) if newest_commissioning else None
    done = newest or commissioned(plant_seed, cell_file=cell_file)
    control = dict(control or {})
    if online_estimate:
        n = len(load_sim_config().drives.gain_nm_per_a)
        control |= {"inner_loop_estimate": True, "inner_loop_dither_a": [DITHER_A] * n}
    cell_overrides = {"control": control} if control else None
    operator = {
        "enabling_after_s": 0.0,
        "mode": "path",
        "path": [list(map(float, w)) for w in path],
        "tremor_m": TREMOR_M,
        "tremor_hz": TREMOR_HZ,
        **HAND,
    }
    last = _LastTelemetry()
    with Stack(
        work, sim_overrides={"operator": operator}, cell_overrides=cell_overrides,
        plant_seed=plant_seed, model=done.model, inner_loop=done.inner_loop,
        current_zero=done.current_zero, cell_file=cell_file,
    ) as stack:  # fmt: skip
        stack.start()
        session = open_client(stack.bus)
        try:
            subscriber = session.declare_subscriber(stack.bus.keys.control_telemetry, last)
            stack.start_teaching(**({"guide": guide} if guide else {}))
            teaching_from_s = time.monotonic()
            deadline = time.monotonic() + path[-1][0] + tail_s
            while time.monotonic() < deadline:  # wait cheaply: the product needs the CPU
                stack.check_alive()
                time.sleep(0.5)
            stack.request("stop")
            subscriber.undeclare()
        finally:
            session.close()
    truth = stack.truth()
    summary = json.loads(stack.sim_summary.read_text())
    rows = np.flatnonzero(truth["teaching"] > 0.5)
    if not rows.size:
        raise RuntimeError("the robot never followed the control process's commands")
    rows = np.arange(rows[0], rows[-1] + 1)
    tool = np.stack([truth[f"tool_{a}"][rows] for a in "xyz"], axis=1)
    force = np.stack([truth[f"f_{a}"][rows] for a in "xyz"], axis=1)
    q = np.stack([truth[f"q{j + 1}"][rows] for j in range(6)], axis=1)
    tau = truth["t_s"][rows] - truth["t_s"][rows[0]]
    flange, rot = flange_poses(plant_seed, q)
    out = metrics(path, tau, tool, tool[0], force, flange, q)
    drift = orientation_drift_deg(rot)
    # how far the tool turned from where the hand took it: what an orientation-locked guide
    # holds (the scorer's kinematics, the plant's joints)
    out["orientation_drift_deg"] = {
        "p95": round(float(np.percentile(drift, 95)), 3),
        "max": round(float(drift.max()), 3),
    }
    out["guide"] = guide or control.get("guide", "free")
    out["commands_missed"] = commands_missed(truth["cycle"][rows], truth["latency_s"][rows])
    # what the motors carried (the datasheet's K × the reported current), RMS per joint: the
    # cylinders' share of the load shows here ([control] pressure_schedule)
    k = np.array(load_sim_config().drives.gain_nm_per_a)
    current = np.stack([truth[f"i{j + 1}"][rows] for j in range(6)], axis=1)
    out["motor_torque_rms_nm"] = np.sqrt(np.mean((current * k) ** 2, axis=0)).round(1).tolist()
    out["pressure_set_bar"] = {
        f"p{j}": [round(float(v), 2) for v in (truth[f"p{j}_set"][rows].min(),
                                              truth[f"p{j}_set"][rows].max())]
        for j in (2, 3)
    }  # fmt: skip
    out["controller_faults"] = summary.get("faults", [])
    out["completed"] = out["completed"] and not out["controller_faults"]
    out["model"] = str(done.model)
    inner_loop = json.loads(done.inner_loop.read_text())
    out["_adaptation"] = adaptation_report(
        last.message, plant_seed, inner_loop, last.history, teaching_from_s
    )
    return out


def plot(
    series: dict[str, dict[str, np.ndarray]], phases: dict[str, dict[str, Any]], out_png: Path
) -> None:
    """The hand's force along the path (distance the painter's target travelled), per
    strategy, and beside it each strategy's mean force per phase (:mod:`.teach_phases`)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (ax, bars) = plt.subplots(
        1, 2, figsize=(14, 4), gridspec_kw={"width_ratios": [3, 1]}
    )  # fmt: skip
    for name, s in series.items():
        ax.plot(s["progress_m"], s["force_n"], lw=0.8, label=name)
    ax.set(xlabel="along the raster path [m]", ylabel="operator force [N]")
    ax.set_title("Force the painter applies at the tool")
    ax.legend(loc="best", fontsize=8)
    width = 0.8 / max(len(phases), 1)
    for i, (name, by_phase) in enumerate(phases.items()):
        means = [by_phase[p]["mean_force_n"] for p in PHASES]
        bars.bar(np.arange(len(PHASES)) + (i - (len(phases) - 1) / 2) * width, means, width,
                 label=name)  # fmt: skip
    bars.set_xticks(range(len(PHASES)), PHASES)
    bars.set(ylabel="mean force [N]", title="per phase")
    bars.legend(loc="best", fontsize=8)
    fig.tight_layout()
    fig.savefig(out_png, dpi=110)
    plt.close(fig)


def print_adaptation(adaptation: dict[str, Any]) -> None:
    """Per joint, estimate / truth of ω and ω_I (and of the online estimate, if any)."""
    rows = [(f"omega ({adaptation['omega_source']})", adaptation["omega_ratio"]),
            (f"omega_I ({adaptation['omega_i_source']})", adaptation["omega_i_ratio"])]  # fmt: skip
    online = adaptation.get("online_estimate")
    if online:
        rows += [(f"omega (online, {online['seconds']} s)", online["omega_ratio"]),
                 ("omega_I (online)", online["omega_i_ratio"])]  # fmt: skip
    n = len(adaptation["omega_ratio"])
    print("\nestimate / truth" + " " * 19 + " ".join(f"{f'J{j + 1}':>7}" for j in range(n)))
    for label, ratios in rows:
        cells = " ".join(f"{'-':>7}" if r is None else f"{r:7.3f}" for r in ratios)
        print(f"{label:>34} {cells}")
    if "within_5pct_after_s" in adaptation:
        settled = adaptation["within_5pct_after_s"]
        print(
            f"every joint's omega and omega_I within 5 % of the truth after "
            f"{settled} s of {adaptation['teaching_s']} s of teaching"
            if settled is not None
            else f"not every joint's omega and omega_I within 5 % of the truth at the end of "
            f"{adaptation['teaching_s']} s of teaching"
        )


def _control_settings(text: str) -> dict[str, Any]:
    try:
        value = json.loads(text)
    except json.JSONDecodeError as exc:
        raise argparse.ArgumentTypeError(f"--control is not JSON: {exc}") from None
    if not isinstance(value, dict):
        raise argparse.ArgumentTypeError("--control must be a JSON object of [control] keys")
    return value


def configure_parser(p: argparse.ArgumentParser) -> None:
    p.description = (
        "Benchmark lead-through strategies: a simulated painter drags the tool along a raster "
        "spray path (1.0 m x 0.6 m, 0.1 m/s, hand tremor) on a commissioned virtual robot. "
        "Prints a table, writes OUT/summary.json."
    )
    which = p.add_mutually_exclusive_group()
    which.add_argument("--plant-seed", type=int, default=0, help="the virtual robot (0: default)")
    which.add_argument(
        "--seeds",
        type=parse_seeds,
        default=None,
        metavar="A-B",
        help="every plant seed from A to B (or one, A): each commissioned and benched into "
        "OUT/seedS/, then a table over the seeds and OUT/summary.json",
    )
    p.add_argument("--out", type=Path, default=Path("teach_bench_out"), help="output folder")
    p.add_argument(
        "--online-estimate",
        action="store_true",
        help="run the control process's online inner-loop estimate in 'best' (with a "
        f"{DITHER_A} A torque dither) and report it",
    )
    p.add_argument(
        "--control",
        type=_control_settings,
        default={},
        metavar="JSON",
        help="settings of the cell config's [control] section for the product's strategies, "
        "as a JSON object, e.g. '{\"damping_nm_s_per_rad\": [20, 20, 10, 5, 5, 2]}'",
    )
    p.add_argument(
        "--guide",
        choices=GUIDES,
        default=None,
        help="the constrained guide the painter's start asks for in the product's strategies "
        "(`leadthrough start --guide`); the summary gives the tool's orientation drift; with "
        "'plane' the raster lies in the plane the gun faces",
    )
    p.add_argument(
        "--strategies",
        nargs="+",
        choices=STRATEGIES,
        default=list(STRATEGIES),
        help="which to run (default: all)",
    )
    p.add_argument(
        "--cell",
        type=Path,
        default=SIM_CELL,
        help="the product's cell config for its strategies (default deploy/config/"
        "sim_cell.toml; deploy/config/sim_cell_cia402.toml: CiA 402 drives): the virtual cell "
        "runs the controller its [can].adapter speaks to, and each robot is commissioned "
        "through it",
    )
    p.add_argument(
        "--newest-commissioning",
        action="store_true",
        help="take each seed's newest commissioning in the cache, whatever version of the "
        "code made it (a change to the laws, benched without commissioning every seed again: "
        "valid only while the identification is the same; each summary names its model)",
    )
    add_progress_argument(p)


def run_seed(
    plant_seed: int, strategies: list[str], out: Path, args: argparse.Namespace, bar: Any
) -> dict[str, Any]:
    """Every strategy of ``strategies`` on plant ``plant_seed``: writes ``out/summary.json``
    and ``out/teach_bench.png``, prints the table, returns the summary."""
    out.mkdir(parents=True, exist_ok=True)
    path = raster_path()
    facing = args.guide == "plane"
    if facing:  # the raster on the panel the gun faces, where the plane guide holds it
        path = raster_facing(path, tool_axis_at_start(plant_seed))
    print(f"raster spray path: {PASSES} passes of {WIDTH_M} m over {HEIGHT_M} m at "
          f"{SPEED_M_S} m/s, {path[-1][0]:.0f} s; plant seed {plant_seed}"
          + ("; in the plane the gun faces" if facing else ""))  # fmt: skip
    results: dict[str, dict[str, Any]] = {}
    for name in strategies:
        t0 = time.monotonic()
        bar.write(f"seed {plant_seed}: {name} ...")
        bar.set_label(f"{plant_seed} {name}")
        if name == "offservo":
            results[name] = run_offservo(plant_seed, path)
        elif name == "inertia":
            results[name] = run_inertia(plant_seed, path, guide=args.guide)
        else:
            results[name] = run_best(
                plant_seed,
                path,
                out / name,
                online_estimate=args.online_estimate,
                control=PRODUCT_STRATEGIES[name] | args.control,
                guide=args.guide,
                newest_commissioning=args.newest_commissioning,
                cell_file=args.cell,
            )
        results[name]["wall_time_s"] = time.monotonic() - t0
        bar.advance(label="")
    summary = {
        "plant_seed": plant_seed,
        "path": {
            "kind": "raster facing the gun" if facing else "raster",
            "width_m": WIDTH_M,
            "height_m": HEIGHT_M,
            "passes": PASSES,
            "speed_m_s": SPEED_M_S,
            "waypoints": path,
        },
        "hand": {**HAND, "tremor_m": TREMOR_M, "tremor_hz": TREMOR_HZ},
        "cell": str(args.cell),
        "control_settings": args.control,
        "guide": args.guide,
        "strategies": results,
    }
    reports = {name: r.pop("_adaptation", None) for name, r in results.items()}
    # the paper's law adapts ω̂ and Υ̂_I (eqs. 28, 30), best's ω̂ only (eq. 28); the
    # admittance's ω̂ stays calibrated
    adaptation = reports.get("paper") or reports.get("best") or reports.get("admittance")
    if adaptation is not None:
        summary["adaptation"] = adaptation
    series = {name: r.pop("_series") for name, r in results.items()}
    (out / "summary.json").write_text(json.dumps(summary, indent=2))
    plot(series, {name: r["phases"] for name, r in results.items()}, out / "teach_bench.png")
    cols = ("mean_force_n", "p95_force_n", "peak_force_n", "mean_moment_nm",
            "dwell_mean_force_n", "path_error_mm", "completed")  # fmt: skip
    head = ("strategy", "mean N", "p95 N", "peak N", "moment N·m", "dwell N", "path mm", "done")
    print("\n" + " ".join(f"{h:>11}" for h in head))
    for name, r in results.items():
        cells = [f"{r[c]:11.1f}" if isinstance(r[c], float) else f"{r[c]!s:>11}" for c in cols]
        print(f"{name:>11} " + " ".join(cells))
    print("\nmean force per phase [N] (seconds of the run in it)")
    print(f"{'strategy':>11} " + " ".join(f"{p:>16}" for p in PHASES))
    for name, r in results.items():
        cells = [f"{r['phases'][p]['mean_force_n']:7.1f} ({r['phases'][p]['seconds']:5.1f} s)"
                 for p in PHASES]  # fmt: skip
        print(f"{name:>11} " + " ".join(f"{c:>16}" for c in cells))
    if adaptation is not None:
        print_adaptation(adaptation)
    print(f"\nsummary: {out / 'summary.json'}")
    return summary


def completed(summary: dict[str, Any]) -> bool:
    """Every product strategy of a seed's ``summary`` got to the end of the path (offservo
    and inertia are the plant's references, not the product)."""
    return all(r["completed"] for n, r in summary["strategies"].items() if n in PRODUCT_STRATEGIES)


def cli_main(args: argparse.Namespace) -> int:
    out: Path = args.out
    out.mkdir(parents=True, exist_ok=True)
    seeds = args.seeds if args.seeds is not None else [args.plant_seed]
    strategies = list(args.strategies)
    summaries: dict[int, dict[str, Any]] = {}
    with progress_bar(
        len(seeds) * len(strategies), "teach-bench", "run", enabled=progress_enabled(args)
    ) as bar:
        for seed in seeds:
            folder = out if args.seeds is None else out / f"seed{seed}"
            summaries[seed] = run_seed(seed, strategies, folder, args, bar)
    if args.seeds is not None:
        rows = seed_rows(summaries)
        (out / "summary.json").write_text(json.dumps(aggregate(rows), indent=2))
        print_seed_table(rows)
        print(f"\nsummary over seeds: {out / 'summary.json'}")
    # only a product strategy that did not get to the end of the path fails the run
    return 0 if all(completed(s) for s in summaries.values()) else 1
