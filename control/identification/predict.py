"""An identified model's joint torque on every row of a measured file.

What ``leadthrough predict`` writes and what analyze's held-out figures are computed on: the
model is judged against the raw measured torque, row for row, never against a filtered one.

Per gap-free stretch of the file (:func:`.preprocess.gap_free_segments`):

1. **States.** q (and a measured dq) are low-passed zero-phase at the model's position cutoff
   (the one its identification used, ``analysis.position_cutoff_hz``); dq is the measured one
   or the central difference of the filtered q, ddq the central difference of dq. A stretch
   whose time steps jitter is filtered on a uniform grid at its median step and read back at
   the recorded times by linear interpolation (the states are smooth far below the grid).
2. **Delay.** With a ``time_delay`` effect (torque lagging the kinematics by δ), row t is
   answered with the states at ``t - δ``; the rows of the first δ of a stretch, whose states
   were not recorded, are declined.
3. **Torque.** :meth:`.model.IdentifiedModel.measured_torque_nm` at those states (the physical
   torque through the torque channel's gain and offset, :mod:`.chain`); with the cylinders'
   torque taken out when the model was identified (pressure columns), the cylinders' torque
   (eqs. 10, 12, the identification's measured piston diameters, the pressure low-passed at the
   model's torque cutoff) is taken off again, through the same gain (the channel reads the
   motor's torque, rigid body less cylinders): the prediction is of what the torque channel
   reads.

Declined rows are NaN: those of a stretch too short to filter (:data:`MIN_STRETCH_ROWS`) and the
first δ of each stretch. Nothing else is: a stretch's ends are answered through the run-on of
:func:`.preprocess.states_to_the_edges`.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from control.identification.datafile import Measurements
from control.identification.fit import cylinder_joint_map
from control.identification.friction_law import rest_log_odds_per_joint
from control.identification.model import IdentifiedModel
from control.identification.preprocess import (
    FILTER_ORDER,
    JITTER_TOLERANCE,
    friction_states,
    gap_free_segments,
    lowpass_to_the_edges,
    states_to_the_edges,
)
from control.model.cylinders import torque_per_pa
from gateway.errors import ConfigError, DataFileError
from gateway.robot.description import BAR_TO_PA, RobotDescription

#: A stretch shorter than this is declined: the zero-phase filter needs 3 × (2 × order + 1)
#: samples of padding to run, and fewer rows than that give no usable derivative.
MIN_STRETCH_ROWS = 3 * (2 * FILTER_ORDER + 1) + 1
#: Rows evaluated at once (bounds the regressor's temporary memory: n × rows × columns).
CHUNK_ROWS = 20_000
#: Significant digits written per torque (the model's own precision is far coarser).
WRITE_DIGITS = 10


def _states(
    t: np.ndarray,
    q: np.ndarray,
    dq: np.ndarray | None,
    cutoff_hz: float,
    at: np.ndarray,
    torque_cutoff_hz: float = np.inf,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Filtered q, dq, ddq of one gap-free stretch, friction's velocity (the window bounded by
    ``torque_cutoff_hz``'s period), read at the times ``at`` (within it), and its noise."""
    step = raw_step = float(np.median(np.diff(t)))
    fs = 1.0 / step
    signals = [q] if dq is None else [q, dq]
    grid = t
    if np.max(np.abs(np.diff(t) - step)) > JITTER_TOLERANCE * step:
        # a uniform grid from the first to the last time stamp (its step within one part in
        # the row count of the median), so that no recorded row lies outside it
        grid = np.linspace(t[0], t[-1], round((t[-1] - t[0]) / step) + 1)
        step = float(grid[1] - grid[0])
        fs = 1.0 / step
        signals = [_interp(grid, t, s) for s in signals]
    q_f, dq_f, ddq_f = states_to_the_edges(
        signals[0], None if dq is None else signals[1], cutoff_hz, fs
    )
    v_fr, s_fr = friction_states(
        signals[0], q, None if dq is None else signals[1], dq_f, step, raw_step, cutoff_hz,
        min(torque_cutoff_hz, 0.4 * fs),
    )  # fmt: skip
    if grid is t and at.size == t.size and np.array_equal(at, t):
        return q_f, dq_f, ddq_f, v_fr, s_fr
    return (
        _interp(at, grid, q_f), _interp(at, grid, dq_f), _interp(at, grid, ddq_f),
        _interp(at, grid, v_fr), s_fr,
    )  # fmt: skip


def _interp(at: np.ndarray, t: np.ndarray, x: np.ndarray) -> np.ndarray:
    return np.column_stack([np.interp(at, t, x[:, c]) for c in range(x.shape[1])])


def _cylinder_torque(
    model: IdentifiedModel, m: Measurements, q: np.ndarray, rows: slice, desc: RobotDescription
) -> np.ndarray:
    """The cylinders' joint torque [N·m] on ``rows`` of ``m`` at the filtered ``q`` (the
    measured piston diameters; pressure low-passed at the model's torque cutoff)."""
    assert m.p is not None
    t = m.t[rows]
    fs = 1.0 / float(np.median(np.diff(t)))
    p = lowpass_to_the_edges(m.p[rows], float(model.metadata["torque_cutoff_hz"]), fs)
    out = np.zeros_like(q)
    for col, spec in cylinder_joint_map(model.regressor, desc, m.p_joints, m.source):
        j = spec.joint_index
        out[:, j] += torque_per_pa(spec, q[:, j]) * p[:, col] * BAR_TO_PA
    return out


def predict_rows(
    model: IdentifiedModel, m: Measurements, desc: RobotDescription | None = None
) -> np.ndarray:
    """The torque channel's reading the model predicts for every row of ``m``, (T, n) [N·m];
    NaN on the rows it declines (module docstring). ``desc`` (the robot description with its
    cylinders) is needed when the model was identified with pressure columns."""
    if m.n_joints != model.n:
        raise DataFileError(
            f"{m.source}:1: has {m.n_joints} joints (q1..q{m.n_joints}), the model has {model.n}"
        )
    cylinders = bool(model.metadata.get("cylinders_removed", False))
    if cylinders and m.p is None:
        raise DataFileError(
            f"{m.source}:1: the model was identified with the assist cylinders' torque taken "
            "out (pressure columns): this file has no pressure columns to add it back"
        )
    if cylinders and desc is None:
        raise ConfigError(
            f"{m.source}: has pressure columns; the model needs the robot description with "
            "the cylinders (--description)"
        )
    desc_measured = model.with_measured_cylinders(desc) if cylinders and desc else None
    cutoff = float(model.metadata.get("position_cutoff_hz", 0.0))
    if not (np.isfinite(cutoff) and cutoff > 0):
        raise DataFileError(f"model: analysis.position_cutoff_hz {cutoff!r} is not > 0")
    torque_cut = float(model.metadata.get("torque_cutoff_hz", np.inf))
    delay = model.delay_s
    gain = model.chain_arrays()[0]
    out = np.full((m.n_samples, model.n), np.nan)
    # a friction with memory follows the whole file: across gaps (the travel over a gap is
    # the positions' difference) and across chunks
    direction, q_last = np.zeros(model.n), None
    for a, b in gap_free_segments(m.t):
        if b - a < MIN_STRETCH_ROWS:
            continue
        t = m.t[a:b]
        # the states the torque of row t answers to: those at t - delay (recorded from t[0])
        at = t - delay
        ok = at >= t[0]
        dq = None if m.dq is None else m.dq[a:b]
        # friction's velocity and this stretch's own noise on it, which friction is taken in
        # expectation over (:mod:`.friction_velocity`)
        q_f, dq_f, ddq_f, v_fr, noise = _states(t, m.q[a:b], dq, cutoff, at[ok], torque_cut)
        # and how much of it the joint rests, from the stretch's velocities as a whole
        odds = rest_log_odds_per_joint(v_fr, noise)
        rows = np.flatnonzero(ok) + a
        directions, direction = model.friction_directions(q_f, v_fr, noise, direction, q_last, odds)
        q_last = q_f[-1] if len(q_f) else q_last
        for c in range(0, rows.size, CHUNK_ROWS):
            r = slice(c, c + CHUNK_ROWS)
            out[rows[r]] = model.measured_torque_nm(
                q_f[r], dq_f[r], ddq_f[r], at[ok][r], noise, directions[r], odds, v_fr[r]
            )
        if desc_measured is not None:
            # the cylinders push at the time of the row itself: only the drive's torque lags
            q_now = q_f if not delay else _states(t, m.q[a:b], dq, cutoff, t)[0]
            cyl = _cylinder_torque(model, m, q_now, slice(a, b), desc_measured)
            # the channel reads the motor's torque, the cylinders' share too
            out[rows] -= gain * cyl[ok]
    return out


def write_predictions(path: str | Path, t: np.ndarray, tau_nm: np.ndarray) -> None:
    """``t,tau1..tauN`` rows as :func:`predict_rows` returns them (NaN written ``nan``)."""
    n = tau_nm.shape[1]
    data = np.column_stack([np.asarray(t, dtype=float), tau_nm])
    header = ",".join(["t", *(f"tau{j}" for j in range(1, n + 1))])
    row_fmt = ",".join([f"%.{WRITE_DIGITS}g"] * data.shape[1])
    with Path(path).open("w", encoding="ascii", newline="\n") as fh:
        fh.write(header + "\n")
        for start in range(0, data.shape[0], 50_000):
            rows = map(tuple, data[start : start + 50_000].tolist())
            fh.write("\n".join(map(row_fmt.__mod__, rows)) + "\n")
