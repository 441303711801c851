"""`leadthrough export REC.mcap --out F.csv`: a recording's joint states as the measurement CSV
that `leadthrough analyze` reads (control/identification/datafile.py), with its sidecar JSON.

``--out F.parquet`` (or ``--format parquet``) writes the same columns, in the same order and
with the same numbers, as a Parquet file of float64 columns; the sidecar's keys (drive gains,
source, disturbed cycles, ...) go into its file-level metadata instead of a JSON file beside
it. `leadthrough analyze` reads either. A ``--format`` that contradicts the suffix of
``--out`` (``--format csv --out F.parquet``) is refused.

``--split 0.7`` cuts the recording in two contiguous parts, the first with 70 % of the cycles
the arm was commanded in (not held by a stopped cell), and writes ``F_train.csv`` and
``F_test.csv`` (``.parquet`` in Parquet); ``--during teaching`` keeps the first teaching
session only (or replaying, identifying). ``--urdf-out`` writes the robot description's URDF
beside them, so that the three files go straight into ``leadthrough analyze``. Motor currents
become torques with the robot description's drive gains (``--description``, default the packaged
GR630ST) or ``--gains``. Cycles the CAN driver answered with a hold or a run of coasts are left
out as in every export (gateway/recorder.py :func:`~gateway.recorder.export_csv`,
gateway/disturbed_cycles.py).
"""

from __future__ import annotations

import argparse
import contextlib
import json
import logging
import tempfile
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from gateway.errors import ConfigError, DataFileError

log = logging.getLogger("leadthrough.export")

#: output format → the suffix its files get when ``--out`` has none
FORMATS = {"csv": ".csv", "parquet": ".parquet"}
#: suffixes that name a format (datafile.PARQUET_SUFFIXES: what analyze reads as Parquet)
_SUFFIX_FORMATS = {".csv": "csv", ".parquet": "parquet", ".pq": "parquet"}


def configure_parser(p: argparse.ArgumentParser) -> None:
    p.description = (
        "Export a recording's joint states (and the latest cylinder pressures) as the "
        "measurement file `leadthrough analyze` reads: CSV (with a sidecar JSON) or Parquet."
    )
    p.add_argument("recording", type=Path, help="MCAP recording (leadthrough record / demo)")
    p.add_argument(
        "--out", type=Path, required=True, help="file to write (.csv, or .parquet for Parquet)"
    )
    p.add_argument(
        "--format",
        choices=sorted(FORMATS),
        default=None,
        help="output format (default: from the suffix of --out: .parquet is Parquet, any "
        "other CSV); one that contradicts the suffix is refused",
    )
    p.add_argument(
        "--split",
        type=float,
        default=None,
        metavar="FRACTION",
        help="write OUT_train.EXT (the first FRACTION of the cycles) and OUT_test.EXT",
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
    from gateway.messages import FLAG_PREV_COAST, FLAG_PREV_HOLD, Keys
    from gateway.recorder import export_csv, read_states
    from gateway.robot.description import load_description

    if args.split is not None and not 0.0 < args.split < 1.0:
        raise ConfigError(f"--split {args.split}: must be between 0 and 1")
    out: Path = args.out
    fmt = output_format(out, args.format)
    desc = load_description(args.description)
    gains = list(args.gains) if args.gains else [j.drive_gain_nm_per_a for j in desc.joints]
    keys = Keys(args.key_prefix)
    recorded = read_states(args.recording, keys)
    if not recorded.states:
        raise DataFileError(f"{args.recording}: no joint states with pressures to export")
    out.parent.mkdir(parents=True, exist_ok=True)
    written: list[tuple[Path, int]] = []
    span = None if args.during is None else _cycles_during(args.recording, keys, args.during)

    def export(path: Path, cycles: tuple[int, int] | None) -> int:
        if fmt == "csv":
            return export_csv(args.recording, path, gains, keys, cycles, recorded=recorded)
        return export_parquet(args.recording, path, gains, keys, cycles, recorded)

    if args.split is None:
        written.append((out, export(out, span)))
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
            path = out.with_name(f"{out.stem}_{name}{out.suffix or FORMATS[fmt]}")
            written.append((path, export(path, part)))
    for path, rows in written:
        print(f"{path}: {rows} rows")
    if args.urdf_out is not None:
        from gateway.robot.urdf import to_urdf

        args.urdf_out.write_text(to_urdf(desc))
        print(f"{args.urdf_out}: the robot's URDF")
    if args.split is not None and args.urdf_out is not None:
        train, test = (str(p) for p, _ in written)
        print(
            f"next: leadthrough analyze --urdf {args.urdf_out} --train {train} --test {test} "
            "--out DIR"
        )
    return 0


def output_format(out: Path, fmt: str | None) -> str:
    """The format to write ``out`` in: ``fmt`` (``--format``) or, without it, the one its
    suffix names (CSV for any other). A ``fmt`` the suffix contradicts is a ConfigError."""
    named = _SUFFIX_FORMATS.get(out.suffix.lower())
    if fmt is None:
        return named or "csv"
    if fmt not in FORMATS:
        raise ConfigError(f"--format {fmt}: not one of {sorted(FORMATS)}")
    if named is not None and named != fmt:
        raise ConfigError(
            f"--format {fmt} contradicts --out {out}, whose suffix {out.suffix} names {named}: "
            f"give --out a {FORMATS[fmt]} name, or leave --format out"
        )
    return fmt


def export_parquet(
    recording: Path,
    path: Path,
    gains: list[float],
    keys: Any,
    cycles: tuple[int, int] | None,
    recorded: Any,
) -> int:
    """Export as :func:`gateway.recorder.export_csv` does, to a Parquet file: the same columns
    in the same order with the same numbers (the CSV's, read back), float64, and the sidecar's
    keys in the file-level metadata. Returns the rows written."""
    import numpy as np

    from gateway.parquet_file import write_parquet
    from gateway.recorder import export_csv

    # The CSV is the one definition of the export's rows; the Parquet file is made from it,
    # so the two formats cannot drift apart.
    with tempfile.TemporaryDirectory(dir=path.parent, prefix=".export-") as tmp:
        csv = Path(tmp) / f"{path.stem}.csv"
        with _logged_as(csv, path):
            rows = export_csv(recording, csv, gains, keys, cycles, recorded=recorded)
        with csv.open() as fh:
            names = fh.readline().strip().split(",")
            data = np.loadtxt(fh, delimiter=",", dtype=np.float64, ndmin=2)
        sidecar = json.loads(csv.with_suffix(".json").read_text())
    if data.shape != (rows, len(names)):
        raise DataFileError(f"{recording}: export of {rows} rows read back as {data.shape}")
    write_parquet(path, names, data, sidecar)
    return rows


@contextlib.contextmanager
def _logged_as(scratch: Path, path: Path) -> Iterator[None]:
    """The export's log lines name ``path``, the file the user asked for, not the scratch
    CSV it is made from (which is gone when they read them)."""

    def rename(record: logging.LogRecord) -> bool:
        if isinstance(record.args, tuple):
            record.args = tuple(path if a == scratch else a for a in record.args)
        return True

    recorder_log = logging.getLogger("leadthrough.recorder")
    recorder_log.addFilter(rename)
    try:
        yield
    finally:
        recorder_log.removeFilter(rename)


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
