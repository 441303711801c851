"""``leadthrough predict``: an identified model's joint torque on every row of a measured file.

Example::

    leadthrough predict --model ident/model.json --data run3.csv --out run3_pred.csv

reads the model written by ``leadthrough analyze`` and a measurement file (CSV or Parquet, the
``t,q1..,dq1..,tau1..`` layout of :mod:`.datafile`; the torque columns are not used) and writes
``t,tau1..tauN``: the torque the model predicts the torque channel reads, one row per input row
(:mod:`.predict`; ``nan`` where it declines). Scoring is then anyone's arithmetic: measured
torque minus prediction, on the raw file.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from control.identification.datafile import read_measurements
from control.identification.model import IdentifiedModel
from control.identification.predict import predict_rows, write_predictions
from gateway.errors import ConfigError

#: Declined rows above this share are reported as a warning: the model answers nearly all.
DECLINED_WARN_SHARE = 0.05


def configure_parser(p: argparse.ArgumentParser) -> None:
    p.description = (
        "Predict the joint torque of every row of a measured file with an identified model "
        "(model.json from `leadthrough analyze`); writes t,tau1..tauN"
    )
    p.add_argument("--model", type=Path, required=True, help="model.json from analyze")
    p.add_argument(
        "--data", type=Path, required=True, help="measurement file (CSV or Parquet, t,q1..)"
    )
    p.add_argument("--out", type=Path, required=True, metavar="CSV", help="predictions written")
    p.add_argument(
        "--drive-gains",
        default=None,
        metavar="K1,K2,..",
        help="drive gains [N·m/A] for current columns i1..iN (default: the file's sidecar JSON)",
    )
    p.add_argument(
        "--description",
        type=Path,
        default=None,
        metavar="TOML",
        help="robot description with the assist cylinders, for a model identified with "
        "pressure columns (default: packaged GR630ST)",
    )


def _gains(text: str | None) -> tuple[float, ...] | None:
    if text is None:
        return None
    try:
        return tuple(float(v) for v in text.split(","))
    except ValueError:
        raise ConfigError(f"--drive-gains: {text!r} is not a comma-separated list") from None


def cli_main(args: argparse.Namespace) -> int:
    """Predict and write; prints the rows answered. Returns 0."""
    from gateway.robot.description import load_description

    model = IdentifiedModel.load(args.model)
    m = read_measurements(args.data, _gains(args.drive_gains))
    desc = None
    if model.metadata.get("cylinders_removed") and m.p is not None:
        desc = load_description(args.description) if args.description else load_description()
    tau = predict_rows(model, m, desc)
    declined = int(np.count_nonzero(~np.isfinite(tau).all(axis=1)))
    args.out.parent.mkdir(parents=True, exist_ok=True)
    write_predictions(args.out, m.t, tau)
    share = declined / max(m.n_samples, 1)
    print(
        f"{args.out}: {m.n_samples - declined} of {m.n_samples} rows predicted"
        + (f", {declined} declined ({100 * share:.2f} %)" if declined else "")
    )
    if share > DECLINED_WARN_SHARE:
        print(
            f"warning: {100 * share:.1f} % of the rows declined: the file's gap-free stretches "
            "are too short to filter",
            file=sys.stderr,
        )
    return 0
