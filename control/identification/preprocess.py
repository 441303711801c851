"""From raw measurements to analysis samples: zero-phase filtering, derivatives, decimation.

Per recorded file (and per gap-free segment of it):

1. **Segments.** A time step above :data:`GAP_FACTOR` × the median step starts a new segment;
   segments are filtered separately and never differentiated across a gap.
2. **Uniform grid.** If the time steps jitter by more than :data:`JITTER_TOLERANCE` (relative),
   the segment is resampled onto a uniform grid at the median step by linear interpolation
   (the Franka log, for one, jitters between 0.7 and 1.8 ms).
3. **Zero-phase low-pass** (``scipy.signal.butter`` order :data:`FILTER_ORDER`, applied forward
   and backward with ``sosfiltfilt``, so no delay between signals):

   - positions (and measured velocities) at ``position_cutoff_hz`` (default
     :data:`DEFAULT_POSITION_CUTOFF_HZ` = 20 Hz): the trajectory itself lives below a few Hz,
     and the cutoff bounds the noise that double differentiation amplifies into ddq;
   - torques and pressures at ``torque_cutoff_hz`` (default :data:`DEFAULT_TORQUE_CUTOFF_HZ`
     = 40 Hz, capped at 0.4 × the analysis rate): the anti-alias filter for decimation, kept
     above the position cutoff so the sharp friction reversal (which the model computes from
     the measured velocity) is not smeared in the measurement only.

4. **Derivatives.** Velocity is the measured one when the file has ``dq`` (filtered), else the
   central difference of the filtered position; acceleration is the central difference of
   that velocity.
5. **Edges.** :data:`EDGE_PERIODS` / ``position_cutoff_hz`` seconds are dropped at both ends of
   each segment (filter start-up and one-sided differences).
6. **Decimation** to ``rate_hz`` (default :data:`DEFAULT_RATE_HZ` = 200 Hz) by keeping every
   k-th sample, k = round(f_s / rate_hz); the low-pass above is its anti-alias filter. Ten
   minutes at 1 kHz become 120,000 samples.

Units: t [s], q [rad], dq [rad/s], ddq [rad/s²], tau [N·m], p [bar].
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from itertools import pairwise

import numpy as np
from scipy import signal

from control.identification.datafile import Measurements
from gateway.errors import ConfigError, DataFileError

DEFAULT_RATE_HZ = 200.0
DEFAULT_POSITION_CUTOFF_HZ = 20.0
DEFAULT_TORQUE_CUTOFF_HZ = 40.0
FILTER_ORDER = 4
GAP_FACTOR = 10.0
JITTER_TOLERANCE = 0.01
EDGE_PERIODS = 5.0
#: A joint that moves more than this between two samples is a wrapped or corrupt position.
MAX_STEP_RAD = 1.0
#: Segments shorter than this many filtered samples (after edge trimming) are dropped.
MIN_SEGMENT_SAMPLES = 50


class TooShortError(DataFileError):
    """A file without a gap-free stretch long enough to filter."""


@dataclass(frozen=True)
class Prepared:
    """Filtered, differentiated, decimated samples of one or more files, ready to fit.

    ``t`` (T,) [s] (each file's own clock), ``q``/``dq``/``ddq`` (T, n) [rad, rad/s, rad/s²],
    ``tau`` (T, n) [N·m] measured joint torque, ``p`` (T, k) [bar] or None for ``p_joints``
    (1-based), ``segment`` (T,) id of the contiguous segment each sample belongs to,
    ``sources`` the files, ``rate_hz`` the analysis rate [Hz].
    """

    t: np.ndarray
    q: np.ndarray
    dq: np.ndarray
    ddq: np.ndarray
    tau: np.ndarray
    p: np.ndarray | None
    p_joints: tuple[int, ...]
    segment: np.ndarray
    sources: tuple[str, ...]
    rate_hz: float

    @property
    def n_samples(self) -> int:
        return int(self.t.size)

    @property
    def n_joints(self) -> int:
        return int(self.q.shape[1])

    def with_tau(self, tau: np.ndarray) -> Prepared:
        """Copy with another torque array (e.g. cylinder torque taken out)."""
        return Prepared(
            self.t,
            self.q,
            self.dq,
            self.ddq,
            np.asarray(tau, dtype=float),
            self.p,
            self.p_joints,
            self.segment,
            self.sources,
            self.rate_hz,
        )

    def select(self, mask: np.ndarray) -> Prepared:
        """The samples where ``mask`` (T,) is true."""
        return Prepared(
            self.t[mask],
            self.q[mask],
            self.dq[mask],
            self.ddq[mask],
            self.tau[mask],
            None if self.p is None else self.p[mask],
            self.p_joints,
            self.segment[mask],
            self.sources,
            self.rate_hz,
        )


def _check_cutoffs(rate_hz: float, position_cutoff_hz: float, torque_cutoff_hz: float) -> None:
    for name, value in (
        ("rate_hz", rate_hz),
        ("position_cutoff_hz", position_cutoff_hz),
        ("torque_cutoff_hz", torque_cutoff_hz),
    ):
        if not (np.isfinite(value) and value > 0):
            raise ConfigError(f"{name}: {value!r} must be a finite number > 0")


def _segments(t: np.ndarray) -> list[tuple[int, int]]:
    dt = np.diff(t)
    step = float(np.median(dt))
    cuts = np.flatnonzero(dt > GAP_FACTOR * step) + 1
    bounds = np.concatenate(([0], cuts, [t.size]))
    return [(int(a), int(b)) for a, b in pairwise(bounds)]


def _lowpass(x: np.ndarray, cutoff_hz: float, fs_hz: float) -> np.ndarray:
    cutoff = min(cutoff_hz, 0.45 * fs_hz)
    sos = signal.butter(FILTER_ORDER, cutoff, fs=fs_hz, output="sos")
    return signal.sosfiltfilt(sos, x, axis=0)


def prepare(
    m: Measurements,
    rate_hz: float = DEFAULT_RATE_HZ,
    position_cutoff_hz: float = DEFAULT_POSITION_CUTOFF_HZ,
    torque_cutoff_hz: float = DEFAULT_TORQUE_CUTOFF_HZ,
) -> Prepared:
    """Filter, differentiate and decimate one file's samples (steps in the module docstring).

    Raises :class:`DataFileError` when a position jumps by more than :data:`MAX_STEP_RAD`
    between two samples, or when no segment is long enough to filter.
    """
    _check_cutoffs(rate_hz, position_cutoff_hz, torque_cutoff_hz)
    jumps = np.abs(np.diff(m.q, axis=0)) > MAX_STEP_RAD
    parts: list[dict[str, np.ndarray]] = []
    rates = []
    for seg_id, (a, b) in enumerate(_segments(m.t)):
        seg_jumps = np.flatnonzero(jumps[a : b - 1].any(axis=1))
        if seg_jumps.size:
            row = a + int(seg_jumps[0]) + 1
            j = int(np.flatnonzero(jumps[row - 1])[0])
            raise DataFileError(
                f"{m.source}:{row + 2}: q{j + 1} jumps by "
                f"{m.q[row, j] - m.q[row - 1, j]:+.3f} rad in one sample (wrapped angle or "
                f"corrupt value; positions must be continuous)"
            )
        t = m.t[a:b]
        if t.size < 2:
            continue
        step = float(np.median(np.diff(t)))
        fs = 1.0 / step
        signals = {"q": m.q[a:b], "tau": m.tau[a:b]}
        if m.dq is not None:
            signals["dq"] = m.dq[a:b]
        if m.p is not None:
            signals["p"] = m.p[a:b]
        if np.max(np.abs(np.diff(t) - step)) > JITTER_TOLERANCE * step:
            grid = t[0] + step * np.arange(int(np.floor((t[-1] - t[0]) / step + 1e-9)) + 1)
            signals = {
                k: np.column_stack([np.interp(grid, t, v[:, c]) for c in range(v.shape[1])])
                for k, v in signals.items()
            }
            t = grid
        edge = int(np.ceil(EDGE_PERIODS / position_cutoff_hz * fs))
        if t.size < 2 * edge + MIN_SEGMENT_SAMPLES:
            continue
        tau_cut = min(torque_cutoff_hz, 0.4 * min(rate_hz, fs))
        q = _lowpass(signals["q"], position_cutoff_hz, fs)
        dq = (
            _lowpass(signals["dq"], position_cutoff_hz, fs)
            if "dq" in signals
            else np.gradient(q, step, axis=0)
        )
        ddq = np.gradient(dq, step, axis=0)
        tau = _lowpass(signals["tau"], tau_cut, fs)
        p = _lowpass(signals["p"], tau_cut, fs) if "p" in signals else None
        factor = max(1, round(fs / rate_hz))
        keep = slice(edge, t.size - edge, factor)
        part = {"t": t[keep], "q": q[keep], "dq": dq[keep], "ddq": ddq[keep], "tau": tau[keep]}
        if p is not None:
            part["p"] = p[keep]
        part["segment"] = np.full(part["t"].size, seg_id)
        parts.append(part)
        rates.append(fs / factor)
    if not parts:
        raise TooShortError(
            f"{m.source}: too short to analyse: no gap-free stretch longer than "
            f"{2 * EDGE_PERIODS / position_cutoff_hz:.2f} s plus {MIN_SEGMENT_SAMPLES} samples"
        )
    cat = {k: np.concatenate([p[k] for p in parts]) for k in parts[0]}
    return Prepared(
        t=cat["t"],
        q=cat["q"],
        dq=cat["dq"],
        ddq=cat["ddq"],
        tau=cat["tau"],
        p=cat.get("p"),
        p_joints=m.p_joints,
        segment=cat["segment"],
        sources=(m.source,),
        rate_hz=float(np.median(rates)),
    )


def concatenate(parts: Sequence[Prepared]) -> Prepared:
    """One :class:`Prepared` from several files; segment ids are renumbered to stay distinct.

    All parts must have the same joint count and the same pressure columns.
    """
    if not parts:
        raise ValueError("nothing to concatenate")
    n = parts[0].n_joints
    p_joints = parts[0].p_joints
    for part in parts[1:]:
        if part.n_joints != n:
            raise DataFileError(
                f"{part.sources[0]}: has {part.n_joints} joints, {parts[0].sources[0]} has {n}"
            )
        if part.p_joints != p_joints:
            raise DataFileError(
                f"{part.sources[0]}: pressure columns {['p' + str(j) for j in part.p_joints]} "
                f"differ from {['p' + str(j) for j in p_joints]} of {parts[0].sources[0]}"
            )
    segments = []
    offset = 0
    for part in parts:
        _, inverse = np.unique(part.segment, return_inverse=True)
        segments.append(inverse + offset)
        offset += int(inverse.max()) + 1
    return Prepared(
        t=np.concatenate([p.t for p in parts]),
        q=np.concatenate([p.q for p in parts]),
        dq=np.concatenate([p.dq for p in parts]),
        ddq=np.concatenate([p.ddq for p in parts]),
        tau=np.concatenate([p.tau for p in parts]),
        p=None if parts[0].p is None else np.concatenate([p.p for p in parts]),  # type: ignore[misc]
        p_joints=p_joints,
        segment=np.concatenate(segments),
        sources=tuple(s for p in parts for s in p.sources),
        rate_hz=float(np.median([p.rate_hz for p in parts])),
    )
