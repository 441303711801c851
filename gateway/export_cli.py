"""`leadthrough export REC.mcap --out F.csv`: a recording's joint states as the measurement CSV
that `leadthrough analyze` reads (control/identification/datafile.py), with its sidecar JSON.

``--split 0.7`` cuts the recording in two contiguous parts, the first with 70 % of the cycles
the arm was commanded in (not held by a stopped cell), and writes ``F_train.csv`` and
``F_test.csv``; ``--during teaching`` keeps the first teaching session only (or replaying,
identifying). ``--urdf-out`` writes the robot description's URDF beside them, so that the
three files go straight into ``leadthrough analyze``. Motor currents become
torques with the robot description's drive gains (``--description``, default the packaged
GR630ST) or ``--gains``. Cycles the CAN driver answered with a hold or a coast are left out as
in every export (gateway/recorder.py :func:`~gateway.recorder.export_csv`).
"""

from __future__ import annotations

import argparse
import logging
from pathlib import Path
from typing import Any

from gateway.errors import ConfigError, DataFileError

log = logging.getLogger("leadthrough.export")


def configure_parser(p: argparse.ArgumentParser) -> None:
    p.description = (
        "Export a recording's joint states (and the latest cylinder pressures) as the "
        "measurement CSV `leadthrough analyze` reads."
    )
    p.add_argument("recording", type=Path, help="MCAP recording (leadthrough record / demo)")
    p.add_argument("--out", type=Path, required=True, help="CSV file to write")
    p.add_argument("--format", choices=["csv"], default="csv", help="output format (csv)")
    p.add_argument(
        "--split",
        type=float,
        default=None,
        metavar="FRACTION",
        help="write OUT_train.csv (the first FRACTION of the cycles) and OUT_test.csv",
    )
    p.add_argument(
        "--during",
        choices=["teaching", "replaying", "identifying"],
        default=None,
        help="only the cycles recorded while the gateway's lifecycle was in this state",
    )
    p.add_argument("--description", type=Path, default=None, help="robot description TOML")
    p.add_argument(
        "--gains", type=float, nargs="+", default=None, help="drive gains [N·m/A] per joint"
    )
    p.add_argument("--urdf-out", type=Path, default=None, help="also write the robot's URDF")
    p.add_argument("--key-prefix", default="lt", help="zenoh key prefix of the recording")


def cli_main(args: argparse.Namespace) -> int:
    from control.robot.description import load_description
    from gateway.messages import FLAG_PREV_COAST, FLAG_PREV_HOLD, Keys
    from gateway.recorder import export_csv, read_states

    if args.split is not None and not 0.0 < args.split < 1.0:
        raise ConfigError(f"--split {args.split}: must be between 0 and 1")
    desc = load_description(args.description)
    gains = list(args.gains) if args.gains else [j.drive_gain_nm_per_a for j in desc.joints]
    keys = Keys(args.key_prefix)
    recorded = read_states(args.recording, keys)
    if not recorded.states:
        raise DataFileError(f"{args.recording}: no joint states with pressures to export")
    out: Path = args.out
    out.parent.mkdir(parents=True, exist_ok=True)
    written: list[tuple[Path, int]] = []
    span = None if args.during is None else _cycles_during(args.recording, keys, args.during)
    if args.split is None:
        rows = export_csv(args.recording, out, gains, keys, span, recorded=recorded)
        written.append((out, rows))
    else:
        # Split the commanded cycles (a stopped cell's held ones are left out by the export).
        held = FLAG_PREV_HOLD | FLAG_PREV_COAST
        commanded = [
            st.cycle - 1
            for st, _ in recorded.states
            if not st.flags & held and (span is None or span[0] <= st.cycle - 1 <= span[1])
        ]
        if len(commanded) < 2:
            raise DataFileError(f"{args.recording}: no commanded cycles to split")
        first, last = span or (recorded.states[0][0].cycle, recorded.states[-1][0].cycle)
        cut = commanded[min(int(args.split * len(commanded)), len(commanded) - 1)]
        for name, part in (("train", (first, cut)), ("test", (cut + 1, last))):
            path = out.with_name(f"{out.stem}_{name}{out.suffix or '.csv'}")
            rows = export_csv(args.recording, path, gains, keys, part, recorded=recorded)
            written.append((path, rows))
    for path, rows in written:
        print(f"{path}: {rows} rows")
    if args.urdf_out is not None:
        from control.robot.urdf import to_urdf

        args.urdf_out.write_text(to_urdf(desc))
        print(f"{args.urdf_out}: the robot's URDF")
    if args.split is not None and args.urdf_out is not None:
        train, test = (str(p) for p, _ in written)
        print(
            f"next: leadthrough analyze --urdf {args.urdf_out} --train {train} --test {test} "
            "--out DIR"
        )
    return 0


def _cycles_during(recording: Path, keys: Any, state: str) -> tuple[int, int]:
    """First and last controller cycle recorded while the lifecycle announced ``state`` (the
    first such stretch)."""
    from gateway.errors import MessageError
    from gateway.messages import JointState, LifecycleMsg
    from gateway.recorder import iter_mcap

    current = ""
    cycles: list[int] = []
    for key, _t_ns, payload in iter_mcap(recording, [keys.lifecycle, keys.joint_state]):
        try:
            if key == keys.lifecycle:
                current = LifecycleMsg.from_bytes(payload).state.name.lower()
            elif current == state:
                cycles.append(JointState.from_bytes(payload).cycle)
            elif cycles:
                break  # the first stretch is over
        except MessageError:
            continue
    if len(cycles) < 2:
        raise DataFileError(f"{recording}: no joint states recorded while {state}")
    return cycles[0], cycles[-1]
