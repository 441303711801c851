"""Benchmark of the identification pipeline on a long synthetic GR630ST recording.

``bench_identify(minutes=10, rate_hz=1000)`` synthesises a training recording of that length
(pinocchio inverse dynamics of the packaged GR630ST + eq. (15) friction + assist cylinders with
varying pressures + noise, along a multi-sine trajectory) and a test recording of a fifth of it
(at least one minute), writes both as CSV, then runs the whole ``analyze`` pipeline on them and
reports seconds per stage (read, preprocess, regressor, fit, effects, validate, report).

Run: ``python -m control.identification.bench [--minutes 10] [--rate-hz 1000] [--keep DIR]``;
on a terminal a bar on stderr counts the stages (``--no-progress``: none).
"""

from __future__ import annotations

import argparse
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
from threadpoolctl import threadpool_limits

from control.identification.analyze import analyze
from control.identification.datafile import write_measurements
from control.identification.rigid import RobotRegressor
from control.identification.stages import AnalyzeOptions, stage_bar
from control.identification.synthetic import (
    GR630ST_MAX_SPEED_RAD_S,
    GR630ST_NOISE_NM,
    MultiSine,
    default_friction,
    synthesize,
)
from gateway.progress import ProgressBar, add_progress_argument, progress_enabled
from gateway.robot.description import load_description
from gateway.robot.urdf import to_urdf

#: Torque scale per GR630ST joint for the synthetic friction [N·m].
_TORQUE_SCALE_NM = (300.0, 1500.0, 600.0, 30.0, 10.0, 5.0)
#: The benchmark's own stages ahead of the analysis's (:data:`.stages.STAGES`), as its
#: progress bar counts them.
BENCH_STAGES = ("synthesising the recordings", "writing the CSVs")


def _pressures(t: np.ndarray, nominal: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Cylinder pressures [bar] wandering ±10 % around nominal (a regulator following set
    points)."""
    phase = rng.uniform(0, 2 * np.pi, size=nominal.size)
    return nominal * (1.0 + 0.1 * np.sin(2 * np.pi * 0.013 * t[:, None] + phase))


def bench_identify(
    minutes: float = 10.0,
    rate_hz: float = 1000.0,
    workdir: str | Path | None = None,
    progress: Callable[[str], None] | None = None,
    bar: ProgressBar | None = None,
) -> dict[str, Any]:
    """Synthesise, write and analyse a ``minutes``-long ``rate_hz`` GR630ST recording.

    Returns ``{"synthesize_s", "write_s", "stages_s": {stage: s}, "total_s", "samples",
    "summary"}``; prints seconds per stage. ``bar`` (``stage_bar(before=len(BENCH_STAGES))``
    of :mod:`.stages`) advances through :data:`BENCH_STAGES`, then the analysis's stages.
    """
    say = progress or (bar.write if bar is not None else (lambda s: print(s, flush=True)))
    if bar is not None:
        bar.set_label(BENCH_STAGES[0])
    desc = load_description()
    urdf_xml = to_urdf(desc)
    reg = RobotRegressor(urdf_xml, desc.gravity_m_s2)
    rng = np.random.default_rng(2024)
    friction = default_friction(desc.gear_ratios, _TORQUE_SCALE_NM, rng)
    nominal = np.array([c.nominal_pressure_bar for c in desc.cylinders])
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(workdir) if workdir is not None else Path(tmp)
        root.mkdir(parents=True, exist_ok=True)
        (root / "gr630st.urdf").write_text(urdf_xml)
        t0 = time.perf_counter()
        recordings = {}
        with threadpool_limits(limits=1, user_api="blas"):  # as analyze runs
            for name, seconds, base_hz in (
                ("train", 60.0 * minutes, 0.05),
                ("test", max(60.0, 12.0 * minutes), 0.07),
            ):
                traj = MultiSine.random(
                    desc.lower_rad, desc.upper_rad, rng, GR630ST_MAX_SPEED_RAD_S, base_hz=base_hz
                )
                t = np.arange(round(seconds * rate_hz)) / rate_hz
                recordings[name] = synthesize(
                    reg,
                    traj,
                    t,
                    friction,
                    GR630ST_NOISE_NM,
                    rng,
                    desc=desc,
                    pressures_bar=_pressures(t, nominal, rng),
                    source=name,
                )
        synth_s = time.perf_counter() - t0
        count = sum(m.n_samples for m in recordings.values())
        say(f"bench: synthesised {count} samples in {synth_s:.1f} s")
        if bar is not None:
            bar.advance(label=BENCH_STAGES[1])
        t0 = time.perf_counter()
        for name, m in recordings.items():
            write_measurements(root / f"{name}.csv", m)
        write_s = time.perf_counter() - t0
        say(f"bench: wrote CSVs in {write_s:.1f} s")
        if bar is not None:
            bar.advance()  # the analysis names its own stages
        t0 = time.perf_counter()
        summary = analyze(
            root / "gr630st.urdf",
            [root / "train.csv"],
            [root / "test.csv"],
            root / "out",
            AnalyzeOptions(),
            progress=say,
            bar=bar,
        )
        total = time.perf_counter() - t0
    stages = {k: v for k, v in summary["timing_s"].items() if k != "total"}
    for stage, seconds in stages.items():
        say(f"bench: {stage:>10} {seconds:7.2f} s")
    say(f"bench: {'analyze':>10} {total:7.2f} s for {minutes:g} min at {rate_hz:g} Hz")
    return {
        "synthesize_s": round(synth_s, 3),
        "write_s": round(write_s, 3),
        "stages_s": stages,
        "total_s": round(total, 3),
        "samples": recordings["train"].n_samples,
        "summary": summary,
    }


def build_parser() -> argparse.ArgumentParser:
    """The options of ``python -m control.identification.bench``."""
    p = argparse.ArgumentParser(prog="python -m control.identification.bench")
    p.add_argument("--minutes", type=float, default=10.0)
    p.add_argument("--rate-hz", type=float, default=1000.0)
    p.add_argument(
        "--keep",
        type=Path,
        default=None,
        metavar="DIR",
        help="write the URDF, train.csv, test.csv and the analysis there and keep them (to time "
        "`leadthrough analyze` on them as a user runs it)",
    )
    add_progress_argument(p)
    return p


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    with stage_bar(progress_enabled(args), before=len(BENCH_STAGES), desc="bench") as bar:
        bench_identify(args.minutes, args.rate_hz, workdir=args.keep, bar=bar)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
