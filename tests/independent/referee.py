"""The referee's scoring of an identified model: its predictions against the raw file.

The product is asked, as a user would ask it (a child process), for its torque on every row of
a file it has never seen (``leadthrough predict``); the referee reads that CSV and the raw
measurement with its own parser and does the arithmetic here: measured torque minus
prediction, no filter, per joint over the rows the model answers. The product's own figures
(``summary.json``) are never read for a score.

A model may decline rows (NaN), at most :data:`MAX_DECLINED_SHARE` of them; more is a failing
draw.
"""

from __future__ import annotations

import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

#: The share of a generated test run the referee keeps to itself: analyze gets the first
#: ``1 - HOLDOUT_SHARE`` as ``test.csv``, the rest (``holdout.csv``) is what the model is scored
#: on: rows neither the fit nor the effect search (which uses the start of the test file) saw,
#: of the same motion and measurement chain, continuing in time (a drift goes on).
HOLDOUT_SHARE = 1.0 / 3.0
#: The share of rows a model may decline (issue 46: NaN only where the model declines, at most
#: 5 % of rows).
MAX_DECLINED_SHARE = 0.05


def run_cli(
    args: list[str], timeout_s: float, cwd: Path | None = None, log: Path | None = None
) -> dict[str, Any]:
    """``python -m gateway.cli ARGS`` in a child process from ``cwd``, as a user runs it:
    the command, exit code, seconds and an error text (None on exit 0); stdout and stderr go
    to ``log`` when given."""
    cmd = [sys.executable, "-m", "gateway.cli", *args]
    start = time.perf_counter()
    result: dict[str, Any] = {"command": cmd, "error": None}
    try:
        proc = subprocess.run(
            cmd, capture_output=True, text=True, timeout=timeout_s, check=False, cwd=cwd
        )
        result["exit_code"] = proc.returncode
        if log is not None:
            log.write_text(
                f"$ {' '.join(cmd)}\n--- stdout\n{proc.stdout}\n--- stderr\n{proc.stderr}"
            )
        if proc.returncode != 0:
            tail = (proc.stderr or proc.stdout).strip().splitlines()[-3:]
            result["error"] = f"exit {proc.returncode}: " + " | ".join(tail)
    except subprocess.TimeoutExpired:
        result["exit_code"] = None
        result["error"] = f"timeout after {timeout_s:.0f} s"
    except OSError as exc:
        result["exit_code"] = None
        result["error"] = f"could not start: {exc}"
    result["seconds"] = round(time.perf_counter() - start, 2)
    return result


def run_predict(
    model: Path, data: Path, out: Path, timeout_s: float, cwd: Path | None = None
) -> dict[str, Any]:
    """``leadthrough predict --model MODEL --data DATA --out OUT`` (:func:`run_cli`); the error
    also when it wrote no ``out``."""
    args = ["predict", "--model", str(model), "--data", str(data), "--out", str(out)]
    result = run_cli(args, timeout_s, cwd)
    if result["error"] is not None:
        result["error"] = f"predict {result['error']}"
    elif not out.is_file():
        result["error"] = f"predict wrote no {out}"
    return result


def read_predictions(path: Path, t: np.ndarray, n: int) -> np.ndarray:
    """``t,tau1..tauN`` of ``path``, (T, n) [N·m] (``nan`` kept); ValueError when the header is
    not that, the row count or the times differ from the file predicted (``t`` [s])."""
    with open(path, encoding="ascii") as fh:
        header = fh.readline().strip().split(",")
    want = ["t", *(f"tau{j}" for j in range(1, n + 1))]
    if header != want:
        raise ValueError(f"{path}: header {header} is not {want}")
    data = np.loadtxt(path, delimiter=",", skiprows=1, ndmin=2)
    if data.shape != (t.size, n + 1):
        raise ValueError(f"{path}: {data.shape} values, expected {(t.size, n + 1)}")
    if not np.allclose(data[:, 0], t, rtol=0, atol=1e-6 * max(1.0, float(np.abs(t).max()))):
        raise ValueError(f"{path}: its times differ from the file predicted")
    return data[:, 1:]


def heldout_figures(tau: np.ndarray, noise: np.ndarray, pred: np.ndarray) -> dict[str, Any]:
    """Raw held-out RMS [N·m] per joint of ``tau - pred`` over the rows ``pred`` answers (all
    joints finite), the RMS of the file's own torque ``noise`` over the same rows (the floor:
    no model of the motion can do better on average) and the declined share."""
    answered = np.isfinite(pred).all(axis=1)
    share = 1.0 - float(answered.mean()) if answered.size else 1.0
    if not answered.any():
        nan = [float("nan")] * tau.shape[1]
        return {"after": nan, "floor": nan, "declined_share": share, "answered": answered}
    err = tau[answered] - pred[answered]
    return {
        "after": np.sqrt(np.mean(err**2, axis=0)).tolist(),
        "floor": np.sqrt(np.mean(noise[answered] ** 2, axis=0)).tolist(),
        "declined_share": share,
        "answered": answered,
    }
