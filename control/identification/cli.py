"""``leadthrough analyze``: identify a dynamic model from measured trajectories and report.

Example::

    leadthrough analyze --urdf robot.urdf --train run1.csv run2.csv --test run3.csv --out ident/

reads the measurement files, CSV or Parquet (format: :mod:`control.identification.datafile`),
fits rigid body + friction on the ``--train`` files, validates on the ``--test`` files (other
trajectories), searches the residual for unmodelled effects, and writes ``ident/model.json``
(for the control process), ``ident/report.md``, ``ident/summary.json`` and plots. Progress
goes to stdout, and on a terminal a bar on stderr counts the stages (``--no-progress``: none).
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

from control.identification import effect_rules
from control.identification.analyze import analyze
from control.identification.friction_law import FRICTION_MODELS
from control.identification.preprocess import (
    DEFAULT_RATE_HZ,
    DEFAULT_STICK_VELOCITY_RAD_S,
)
from control.identification.report import NO_SAMPLES
from control.identification.rigid import DEFAULT_GRAVITY_M_S2
from control.identification.stages import AUTO, AnalyzeOptions, stage_bar
from gateway.errors import ConfigError, LeadthroughError
from gateway.progress import add_progress_argument, progress_enabled


def configure_parser(p: argparse.ArgumentParser) -> None:
    """Options of ``leadthrough analyze``."""
    p.description = (
        "Identify the robot's dynamic model (rigid body + joint friction) from measured "
        "trajectories, check it on held-out test trajectories, look for effects the model "
        "lacks (position ripple, payload, spring, Stribeck, load-dependent friction, time delay, "
        "thermal drift, wrist coupling), add them and report RMS before/after."
    )
    p.add_argument("--urdf", type=Path, required=True, help="robot URDF (any serial arm)")
    p.add_argument(
        "--train",
        type=Path,
        nargs="+",
        required=True,
        metavar="FILE",
        help="training measurement files (CSV, or Parquet from `leadthrough export`)",
    )
    p.add_argument(
        "--test",
        type=Path,
        nargs="+",
        required=True,
        metavar="FILE",
        help="held-out test files (other trajectories; CSV or Parquet)",
    )
    p.add_argument("--out", type=Path, required=True, metavar="DIR", help="output folder (created)")
    p.add_argument(
        "--friction",
        choices=(AUTO, *FRICTION_MODELS),
        default=AUTO,
        help="friction model kept in model.json (default: auto, the family with the lowest "
        "held-out error on the training files; all three are compared in the report)",
    )
    p.add_argument(
        "--drive-gains",
        default=None,
        metavar="K1,K2,..",
        help="drive gains [N·m/A] turning current columns i1..iN into torque (default: each "
        "CSV's sidecar JSON)",
    )
    p.add_argument(
        "--gear-ratios",
        default=None,
        metavar="R1,R2,..",
        help="gear ratios for eq. (15)'s q/R terms (default: from --description when its joints "
        "match the URDF, else 1)",
    )
    p.add_argument(
        "--description",
        type=Path,
        default=None,
        metavar="TOML",
        help="robot description with the assist cylinders for p2/p3 pressure columns "
        "(default: packaged GR630ST)",
    )
    p.add_argument(
        "--gravity",
        default=",".join(str(g) for g in DEFAULT_GRAVITY_M_S2),
        metavar="GX,GY,GZ",
        help="gravity in the URDF base frame [m/s²] (default: 0,0,-9.81)",
    )
    p.add_argument(
        "--rate-hz",
        type=float,
        default=DEFAULT_RATE_HZ,
        help=f"analysis rate after decimation [Hz] (default {DEFAULT_RATE_HZ:g})",
    )
    p.add_argument(
        "--cutoff-hz",
        type=float,
        default=None,
        help="low-pass cutoff of positions and velocities [Hz] (default: chosen from the "
        "training files by held-out error, reported in summary.json's cutoff_hz)",
    )
    p.add_argument(
        "--torque-cutoff-hz",
        type=float,
        default=None,
        help="low-pass cutoff of the torque, pressures and every regressor column [Hz] "
        "(default: the highest --cutoff-hz candidate, 0.4 x the analysis rate, at most 40; "
        "never below --cutoff-hz)",
    )
    p.add_argument(
        "--stick-velocity",
        type=float,
        default=DEFAULT_STICK_VELOCITY_RAD_S,
        metavar="RAD_S",
        help="a joint slower than this is stuck: its rows neither fit nor score the model "
        f"(default {DEFAULT_STICK_VELOCITY_RAD_S}; 0 keeps every row)",
    )
    p.add_argument(
        "--margin",
        type=float,
        default=effect_rules.MARGIN,
        help="held-out RMS gain an effect must bring on its joint (default 0.10 = 10 %%)",
    )
    p.add_argument(
        "--folds",
        type=int,
        default=effect_rules.DEFAULT_FOLDS,
        help="contiguous blocks for cross-validation (default 5)",
    )
    p.add_argument(
        "--max-effects",
        type=int,
        default=effect_rules.MAX_EFFECTS,
        help="stop after this many effects (default 6)",
    )
    p.add_argument(
        "--no-effects", action="store_true", help="fit and validate only; no effect search"
    )
    p.add_argument("--no-plots", action="store_true", help="do not draw PNG plots")
    add_progress_argument(p)


def _floats(text: str | None, option: str, count: int | None = None) -> tuple[float, ...] | None:
    if text is None:
        return None
    try:
        values = tuple(float(v) for v in text.split(","))
    except ValueError:
        raise ConfigError(f"{option}: {text!r} is not a comma-separated list of numbers") from None
    if count is not None and len(values) != count:
        raise ConfigError(f"{option}: {text!r} needs {count} values")
    return values


def options_from_args(args: argparse.Namespace) -> AnalyzeOptions:
    """:class:`AnalyzeOptions` from parsed arguments; bad values raise ConfigError."""
    gravity = _floats(args.gravity, "--gravity", 3)
    assert gravity is not None
    if args.max_effects < 0:
        raise ConfigError(f"--max-effects: {args.max_effects} must be >= 0")
    return AnalyzeOptions(
        friction=args.friction,
        rate_hz=args.rate_hz,
        position_cutoff_hz=args.cutoff_hz,
        torque_cutoff_hz=args.torque_cutoff_hz,
        drive_gains=_floats(args.drive_gains, "--drive-gains"),
        gear_ratios=_floats(args.gear_ratios, "--gear-ratios"),
        description_path=args.description,
        gravity_m_s2=(gravity[0], gravity[1], gravity[2]),
        find_effects=not args.no_effects,
        plots=not args.no_plots,
        search=effect_rules.Options(
            margin=args.margin, folds=args.folds, max_effects=args.max_effects
        ),
        stick_velocity_rad_s=args.stick_velocity,
    )


def _cell(v: float) -> str:
    return f"{v:12.4g}" if math.isfinite(v) else f"{NO_SAMPLES:>12}"


def cli_main(args: argparse.Namespace) -> int:
    """Run the analysis; prints progress and a per-joint RMS table. Returns 0.

    On a terminal a bar on stderr counts the analysis's stages (``--no-progress``: none)."""
    options = options_from_args(args)
    with stage_bar(progress_enabled(args)) as bar:
        summary = analyze(args.urdf, args.train, args.test, args.out, options, bar=bar)
    print(f"{'joint':>10} {'RMS before':>12} {'RMS after':>12}  [N·m, held-out test files]")
    unjudged = []
    for name, b, a in zip(
        summary["joints"], summary["rms_before"], summary["rms_after"], strict=True
    ):
        if not (math.isfinite(b) and math.isfinite(a)):
            unjudged.append(name)
        print(f"{name:>10} {_cell(b)} {_cell(a)}")
    if unjudged:
        print(f"{NO_SAMPLES:>10}: {', '.join(unjudged)} did not slide in the test files")
    if summary["effects"]:
        for e in summary["effects"]:
            print(
                f"effect {e['name']} on joints {e['joints']} ({e['appeared']}): {e['parameters']}"
            )
    elif summary["effects_searched"]:
        print("no further effect found")
    if summary["plain_ls_joints"]:
        print(f"joints {summary['plain_ls_joints']} kept on plain least squares (lower error)")
    print(f"report: {Path(args.out) / 'report.md'}")
    return 0


def main(argv: list[str] | None = None) -> int:
    """Stand-alone entry, ``python -m control.identification.cli``."""
    parser = argparse.ArgumentParser(prog="leadthrough analyze")
    configure_parser(parser)
    try:
        return cli_main(parser.parse_args(argv))
    except LeadthroughError as exc:
        print(f"leadthrough analyze: error: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    raise SystemExit(main())
