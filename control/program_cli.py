"""`leadthrough program`: look at a taught program and get it out for other tools.

    leadthrough program show PROGRAM
    leadthrough program export PROGRAM --csv OUT.csv
    leadthrough program export PROGRAM --csv OUT.csv --processed [--speed-mm-s V] [--period-s T]

``show`` prints its teaching segments, marks and tool path length. ``export`` writes the raw
trace as CSV (:func:`gateway.program.write_csv`), or with ``--processed`` the path as replay
plays it (:func:`control.taught_path.replay_trajectory` from the program's first pose: the
hand tremor filtered out, constant tool speed, sampled every ``--period-s``):
``t_s, piece, <joint>_rad..., <joint>_rad_s...``.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from gateway.program import DEFAULT_SPEED_MM_S, MAX_JOINT_SPEED_RAD_S, MAX_SPEED_MM_S


def configure_parser(p: argparse.ArgumentParser) -> None:
    p.description = __doc__.split("\n\n")[0] if __doc__ else None
    sub = p.add_subparsers(dest="action", required=True)
    show = sub.add_parser("show", help="segments, marks and path length of a program")
    show.add_argument("program", type=Path)
    exp = sub.add_parser("export", help="the trace (or the processed path) as CSV")
    exp.add_argument("program", type=Path)
    exp.add_argument("--csv", type=Path, required=True, help="CSV file to write")
    exp.add_argument(
        "--processed",
        action="store_true",
        help="the path as replay plays it: tremor filtered, constant tool speed",
    )
    exp.add_argument("--speed-mm-s", type=float, default=DEFAULT_SPEED_MM_S)
    exp.add_argument("--period-s", type=float, default=0.004, help="sample period [s]")


def _show(path: Path) -> int:
    from control.taught_path_kinematics import tool_path
    from gateway.program import read_program
    from gateway.robot.description import load_description

    prog = read_program(path)
    desc = load_description()
    print(f"{path}: {prog.header.get('created_utc', '?')}, joints {', '.join(prog.joints)}")
    for k, (t, q) in enumerate(prog.segments(), 1):
        xyz = tool_path(desc, q) if len(prog.joints) == desc.n_dof else np.zeros((len(q), 3))
        length = float(np.sum(np.linalg.norm(np.diff(xyz, axis=0), axis=1)))
        print(f"  segment {k}: {t.size} samples, {t[-1] - t[0]:.1f} s, tool path {length:.3f} m")
    t0 = float(prog.t_s[0]) if prog.t_s.size else 0.0
    for m in prog.marks:
        label = f" {m.label!r}" if m.label else ""
        print(f"  mark {m.index}{label} ({m.source}) {m.t_s - t0:+.2f} s from the first sample")
    for w in prog.warnings:
        print(f"  warning: {w}")
    return 0


def _export(args: argparse.Namespace) -> int:
    from gateway.errors import LeadthroughError
    from gateway.program import read_program, write_csv

    prog = read_program(args.program)
    for w in prog.warnings:
        print(f"warning: {w}")
    if not args.processed:
        print(f"wrote {write_csv(prog, args.csv)} ({prog.t_s.size} samples)")
        return 0
    from control.taught_path import replay_trajectory
    from gateway.robot.description import load_description

    if not 0 < args.speed_mm_s <= MAX_SPEED_MM_S:
        raise LeadthroughError(f"--speed-mm-s {args.speed_mm_s}: must be in (0, {MAX_SPEED_MM_S}]")
    if not 1e-4 <= args.period_s <= 0.1:
        raise LeadthroughError(f"--period-s {args.period_s}: must be in [0.0001, 0.1]")
    if not prog.t_s.size:
        raise LeadthroughError(f"{args.program}: no taught path to process")
    desc = load_description()
    try:
        pieces = replay_trajectory(
            prog, desc, prog.q_rad[0], args.period_s, args.speed_mm_s / 1000.0,
            max_joint_speed_rad_s=MAX_JOINT_SPEED_RAD_S,
        )  # fmt: skip
    except ValueError as exc:
        raise LeadthroughError(f"{args.program}: {exc}") from None
    names = prog.joints
    k = 0
    with args.csv.open("w", encoding="utf-8") as f:
        f.write(",".join(["t_s", "piece", *(f"{j}_rad" for j in names)]))
        f.write("," + ",".join(f"{j}_rad_s" for j in names) + "\n")
        for piece in pieces:
            for q, dq in zip(piece.q_rad, piece.dq_rad_s, strict=True):
                row = [f"{k * args.period_s:.6f}", piece.label]
                row += [f"{v:.9g}" for v in q] + [f"{v:.9g}" for v in dq]
                f.write(",".join(row) + "\n")
                k += 1
    print(f"wrote {args.csv} ({k} samples, {k * args.period_s:.1f} s, {len(pieces)} pieces)")
    return 0


def cli_main(args: argparse.Namespace) -> int:
    if args.action == "show":
        return _show(args.program)
    return _export(args)
