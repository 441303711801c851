"""A short taught program for the replay tests: 3 s of teaching, the tool moving 0.15 rad on J1
and 0.05 rad on J3 from ``q_start`` along a cosine ramp, 300 trace samples."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from gateway.program import ProgramWriter


def write_program(path: Path, q_start: np.ndarray) -> None:
    w = ProgramWriter(path, [f"j{k}" for k in range(1, 7)])
    w.open()
    w.teach(True, 0.0)
    for k in range(300):
        s = 0.5 - 0.5 * np.cos(np.pi * k / 299)
        w.trace(0.01 * k, k, q_start + s * np.array([0.15, 0.0, 0.05, 0.0, 0.0, 0.0]))
    w.close(3.0)
