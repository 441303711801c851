"""``current_zero.json``: the current sensors' zero of the commissioning, written by
`leadthrough identify` (control/identification/on_cell.py) and read by the CAN driver
(drivers/can/driver.py).

The dynamic model is identified from currents corrected by the zero the CAN driver measured
(with the servo power off, drivers/can/rt/src/current_zero.rs) when the cell was commissioned.
A zero measured again at every start differs from it by the noise of both means (about
0.0018 A for two 250-cycle means at 0.02 A: 0.12 N·m on J2), a constant torque error that
nothing in the zero-moment loop holds: the tool creeps (1.1 mm in 5 s with a spray gun on the
virtual cell). So `leadthrough identify` writes the zero it ran with to this file
(:func:`write_stored_zero`), ``[can] current_zero_file`` names it, and the driver then uses
*that* zero, ready at once (:func:`read_stored_zero`): model and currents agree. It still
measures a fresh zero whenever the power is off and reports it; a drift beyond what the noise
of the two means explains means the sensors changed since the commissioning: commission again.
"""

from __future__ import annotations

import json
import math
import os
from pathlib import Path

import numpy as np

#: current_zero.json's format name and version
ZERO_FORMAT = "leadthrough-current-zero"
ZERO_VERSION = 1


class StoredZeroError(ValueError):
    """A current_zero.json that cannot be used (the message names the file and why)."""


def write_stored_zero(
    path: str | Path, offset_a: np.ndarray, samples: int, noise_a: np.ndarray
) -> None:
    """Write the zero ``offset_a`` [A] (the mean of ``samples`` cycles whose per-cycle standard
    deviation was ``noise_a``) to ``path``, atomically (temporary file, fsync, rename)."""
    path = Path(path)
    doc = {
        "format": ZERO_FORMAT,
        "version": ZERO_VERSION,
        "current_zero_a": [float(v) for v in offset_a],
        "samples": int(samples),
        "noise_a": [float(v) for v in noise_a],
    }
    tmp = path.with_name(path.name + ".tmp")
    with tmp.open("w", encoding="utf-8") as fh:
        json.dump(doc, fh, indent=1)
        fh.flush()
        os.fsync(fh.fileno())
    os.replace(tmp, path)


def read_stored_zero(path: str | Path, joints: int) -> tuple[np.ndarray, int, np.ndarray]:
    """(zero [A] (joints,), samples, per-cycle noise [A] (joints,)) from ``path``; raises
    :class:`StoredZeroError` naming the file and what is wrong with it."""
    path = Path(path)
    try:
        doc = json.loads(path.read_text(encoding="utf-8"))
    except OSError as exc:
        raise StoredZeroError(
            f"{path}: cannot read the current zero: {exc.strerror or exc}"
        ) from None
    except ValueError as exc:
        raise StoredZeroError(f"{path}: not JSON: {exc}") from None
    if not isinstance(doc, dict) or doc.get("format") != ZERO_FORMAT:
        raise StoredZeroError(f"{path}: not a {ZERO_FORMAT} file")
    if doc.get("version") != ZERO_VERSION:
        raise StoredZeroError(
            f"{path}: version {doc.get('version')!r}, this driver reads {ZERO_VERSION}"
        )
    out = []
    for key in ("current_zero_a", "noise_a"):
        values = doc.get(key)
        if (
            not isinstance(values, list)
            or len(values) != joints
            or not all(
                isinstance(v, int | float) and not isinstance(v, bool) and math.isfinite(v)
                for v in values
            )
        ):
            raise StoredZeroError(f"{path}: {key} must be {joints} finite numbers, got {values!r}")
        out.append(np.array(values, dtype=float))
    samples = doc.get("samples")
    if not isinstance(samples, int) or isinstance(samples, bool) or samples < 1:
        raise StoredZeroError(f"{path}: samples must be a whole number >= 1, got {samples!r}")
    if np.any(out[1] < 0):
        raise StoredZeroError(f"{path}: noise_a must not be negative")
    return out[0], samples, out[1]
