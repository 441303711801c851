"""From raw measurements to analysis samples: zero-phase filtering, derivatives, decimation.

Per recorded file (and per gap-free segment of it):

1. **Segments.** A time step above :data:`GAP_FACTOR` × the median step starts a new segment;
   segments are filtered separately and never differentiated across a gap.
2. **Uniform grid.** If the time steps jitter by more than :data:`JITTER_TOLERANCE` (relative),
   the segment is resampled onto a uniform grid at the median step (:mod:`.resample`).
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
5. **Noise floor.** Per segment, the white torque noise std is estimated from the raw samples
   (:func:`white_noise_std`, robust to the few friction reversals) and carried through the
   torque filter (:func:`filter_noise_gain`): ``noise_nm`` is the std of the noise left in the
   filtered torque, the floor no model of q, dq, ddq can go below (see its docstring).
6. **Edges.** :data:`EDGE_PERIODS` / ``position_cutoff_hz`` seconds are dropped at both ends of
   each segment (filter start-up and one-sided differences).
7. **Decimation** to ``rate_hz`` (default :data:`DEFAULT_RATE_HZ` = 200 Hz) by keeping every
   k-th sample, k = round(f_s / rate_hz); the low-pass above is its anti-alias filter. Ten
   minutes at 1 kHz become 120,000 samples. ``raw_hz`` keeps f_s per sample: a kept sample
   stands for k recorded ones, over which the friction columns are averaged
   (:meth:`.terms.Context.sample_mean`).

Units: t [s], q [rad], dq [rad/s], ddq [rad/s²], tau [N·m], p [bar].
"""

from __future__ import annotations

import functools
from collections.abc import Sequence
from dataclasses import dataclass, replace
from itertools import pairwise
from types import ModuleType

import numpy as np

from control.identification.datafile import Measurements
from control.identification.friction_law import rest_log_odds_per_joint
from control.identification.friction_velocity import friction_velocity
from control.identification.resample import uniform_grid
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
#: Columns :meth:`Prepared.lowpass` filters at once (bounds its temporary memory).
LOWPASS_COLUMNS = 32
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

    ``filter_hz`` (T,) is the torque low-pass cutoff [Hz] and ``sample_hz`` (T,) the sample
    rate [Hz] of each sample's segment after decimation: what :meth:`lowpass` needs to pass a
    model's torque through the same filter as the measured one. ``noise_nm`` (n,) is the
    measured noise floor of ``tau`` [N·m] (module docstring, step 5), ``raw_noise_nm`` (n,)
    the white noise std of the raw recording [N·m]; ``noise_dof_nm2`` (n,) the share of the
    noise one fitted column takes out on average [N²·m²] (one χ² degree of freedom): the raw
    variance over the decimation factor, ``σ_raw² / k`` — the low-frequency noise level a
    smooth column sees, whatever the filter (see :func:`filter_noise_gain`). None where unknown.
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
    filter_hz: np.ndarray | None = None
    sample_hz: np.ndarray | None = None
    noise_nm: np.ndarray | None = None
    raw_noise_nm: np.ndarray | None = None
    noise_dof_nm2: np.ndarray | None = None
    #: (T,) the recorded rate [Hz] of each sample's segment before decimation (None: unknown,
    #: taken as ``sample_hz``): a kept sample stands for ``raw_hz / sample_hz`` recorded ones
    #: (:meth:`.terms.Context.sample_mean`)
    raw_hz: np.ndarray | None = None
    #: (n,) the std of the noise on friction's velocity [rad/s] (:attr:`dq_friction`, else
    #: ``dq``; None: unknown): friction's sign is taken in expectation over it
    #: (:meth:`.terms.Context.sample_mean`)
    dq_noise_rad_s: np.ndarray | None = None
    #: (T, n) the log prior odds that each joint rests (:func:`.friction_law.rest_log_odds`),
    #: estimated per gap-free stretch from its own filtered velocities (None: unknown): a
    #: multi-sine that only crosses 0 and a teaching motion that dwells differ in them, and
    #: the training and test files may be one of each
    dq_rest_odds: np.ndarray | None = None
    #: (T, n) the velocity friction is taken of [rad/s] (:mod:`.friction_velocity`; None:
    #: ``dq``); ``dq_noise_rad_s`` and ``dq_rest_odds`` are its noise and odds
    dq_friction: np.ndarray | None = None
    #: (T, 3) how a resampled sample mixes the recorded ones around it (:mod:`.resample`;
    #: zeros: not resampled): the torque is that mix, so is each friction column
    resample_mix: np.ndarray | None = None

    @property
    def n_samples(self) -> int:
        return int(self.t.size)

    @property
    def n_joints(self) -> int:
        return int(self.q.shape[1])

    def with_tau(self, tau: np.ndarray) -> Prepared:
        """Copy with another torque array (e.g. cylinder torque taken out)."""
        return replace(self, tau=np.asarray(tau, dtype=float))

    def select(self, mask: np.ndarray) -> Prepared:
        """The samples where ``mask`` (T,) is true (a boolean array or index array)."""
        per_sample = ("t", "q", "dq", "ddq", "tau", "segment")
        changes = {k: getattr(self, k)[mask] for k in per_sample}
        for k in ("p", "filter_hz", "sample_hz", "raw_hz", "dq_rest_odds", "dq_friction",
                  "resample_mix"):  # fmt: skip
            v = getattr(self, k)
            changes[k] = None if v is None else v[mask]
        return replace(self, **changes)

    def lowpass(self, x: np.ndarray) -> np.ndarray:
        """``x`` (T, ...) through the torque's zero-phase low-pass, segment by segment.

        The measured torque was filtered before decimation; a model's torque computed on the
        samples is passed through the same Butterworth filter here (at the decimated rate), so
        measurement and model are compared on one target: a sharp friction reversal, smeared
        by the filter in the measurement, is smeared the same way in the model. Without filter
        information (``filter_hz`` None) ``x`` is returned unchanged.
        """
        arr = np.asarray(x, dtype=float)
        if self.filter_hz is None or self.sample_hz is None or arr.shape[0] == 0:
            return arr
        out = np.empty(arr.shape)
        flat_in, flat_out = arr.reshape(arr.shape[0], -1), out.reshape(arr.shape[0], -1)
        bounds = np.flatnonzero(np.diff(self.segment) != 0) + 1
        for a, b in pairwise(np.r_[0, bounds, arr.shape[0]]):
            cut, fs = float(self.filter_hz[a]), float(self.sample_hz[a])
            # a few columns at a time: the filter's padded copies of a whole regressor
            # (hundreds of columns) cost more memory than the analysis keeps
            for c in range(0, flat_in.shape[1], LOWPASS_COLUMNS):
                cols = slice(c, c + LOWPASS_COLUMNS)
                flat_out[a:b, cols] = lowpass_padded(flat_in[a:b, cols], cut, fs)
        return out


def _check_cutoffs(rate_hz: float, position_cutoff_hz: float, torque_cutoff_hz: float) -> None:
    for name, value in (
        ("rate_hz", rate_hz),
        ("position_cutoff_hz", position_cutoff_hz),
        ("torque_cutoff_hz", torque_cutoff_hz),
    ):
        if not (np.isfinite(value) and value > 0):
            raise ConfigError(f"{name}: {value!r} must be a finite number > 0")


def gap_free_segments(t: np.ndarray) -> list[tuple[int, int]]:
    dt = np.diff(t)
    step = float(np.median(dt))
    cuts = np.flatnonzero(dt > GAP_FACTOR * step) + 1
    bounds = np.concatenate(([0], cuts, [t.size]))
    return [(int(a), int(b)) for a, b in pairwise(bounds)]


def _edge_samples(cutoff_hz: float, fs_hz: float) -> int:
    """Samples a filter at ``cutoff_hz`` spoils at each end of a stretch (EDGE_PERIODS)."""
    return int(np.ceil(EDGE_PERIODS / cutoff_hz * fs_hz))


def keeps_a_stretch(m: Measurements, cutoff_hz: float) -> bool:
    """Whether :func:`prepare` at position cutoff ``cutoff_hz`` keeps some stretch of ``m``:
    a lower cutoff trims more at each end of every gap-free stretch (from the time stamps
    only, not the values)."""
    for a, b in gap_free_segments(m.t):
        t = m.t[a:b]
        if t.size < 2:
            continue
        step = float(np.median(np.diff(t)))
        n = min(t.size, int(np.floor((t[-1] - t[0]) / step + 1e-9)) + 1)  # after any regrid
        if n >= 2 * _edge_samples(cutoff_hz, 1.0 / step) + MIN_SEGMENT_SAMPLES:
            return True
    return False


def _signal() -> ModuleType:
    """scipy.signal, imported at the first filter: it costs 1.2-1.5 s to import (2026-12-04,
    a fast machine), and the control process imports this module through the identified model
    without ever filtering (its boot was 2.0 s, 1.5 s of it this import)."""
    from scipy import signal

    return signal


@functools.lru_cache(maxsize=64)
def _butter_sos(cutoff_hz: float, fs_hz: float) -> np.ndarray:
    """The low-pass's second-order sections, designed once per (cutoff, rate): the analysis
    filters thousands of column blocks at a handful of pairs, and the design costs as much as
    filtering a column. Callers get a copy (scipy's filter wants a writable array)."""
    return _signal().butter(FILTER_ORDER, min(cutoff_hz, 0.45 * fs_hz), fs=fs_hz, output="sos")


def _lowpass(x: np.ndarray, cutoff_hz: float, fs_hz: float) -> np.ndarray:
    sos = _butter_sos(float(cutoff_hz), float(fs_hz)).copy()
    return _signal().sosfiltfilt(sos, x, axis=0)


def lowpass_padded(x: np.ndarray, cutoff_hz: float, fs_hz: float) -> np.ndarray:
    """:func:`_lowpass` that leaves a stretch too short for the filter's padding unchanged."""
    if x.shape[0] <= 3 * (2 * FILTER_ORDER + 1) or cutoff_hz >= 0.5 * fs_hz:
        return x.copy()
    return _lowpass(x, cutoff_hz, fs_hz)


#: Degree of the polynomial :func:`lowpass_to_the_edges` runs a stretch's ends on with, and the
#: span it is fitted over: at least one period of the cutoff (the noise the filter would
#: average) and at least :data:`EDGE_FIT_S`, within the settling time. The fit must follow the
#: motion over its span: half a second is half a period of the fastest content an arm's
#: recorded motion carries (excitation plans reach 1 Hz; teaching is slower). Measured, ddq's
#: RMS error on the rows within half a cutoff period of either end over the interior's (a sine
#: with q noise 1e-5 rad and dq noise 1e-3 rad/s, 10 draws, from positions / from a measured
#: dq): 500 Hz, 20 Hz cut, 0.7 Hz: 0.9 / 1.9; 1 kHz, 20 Hz, 1 Hz: 3.4 / 1.5; 250 Hz, 2 Hz,
#: 1 Hz: 7.9 / 2.5; 100 Hz, 5 Hz, 0.5 Hz: 6.8 / 2.5; 200 Hz, 8 Hz, 0.3 Hz: 1.3 / 2.0; 1 kHz,
#: 40 Hz, 1 Hz: 1.1 / 1.6. Fitted over the whole settling time instead (5 cutoff periods, 2.5 s
#: at 2 Hz) the quintic could not follow a 1 Hz motion: 770 / 350 at 2 Hz; a cubic over 0.5 s
#: is too stiff where it extrapolates: 250 / 33 at 2 Hz, 62 / 1.0 at 20 Hz.
EDGE_POLY_DEGREE = 5
EDGE_FIT_S = 0.5


def lowpass_to_the_edges(x: np.ndarray, cutoff_hz: float, fs_hz: float) -> np.ndarray:
    """:func:`_lowpass` whose ends are usable for derivatives up to the second.

    Each end of the stretch is run on, over the filter's settling time (:data:`EDGE_PERIODS`
    periods of the cutoff), by the least-squares polynomial (:data:`EDGE_POLY_DEGREE`) of the
    samples near that end (:data:`EDGE_FIT_S`); the whole is filtered and the run-ons dropped.
    scipy's padding (a few samples, odd reflection) flips the curvature at the end, so the
    filtered acceleration there tends to zero: :func:`prepare` cuts those edges off, a
    prediction for every row cannot."""
    y, pad = _lowpass_run_on(x, cutoff_hz, fs_hz)
    return y[pad : pad + x.shape[0]]


def states_to_the_edges(
    q: np.ndarray, dq: np.ndarray | None, cutoff_hz: float, fs_hz: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """q, dq, ddq of one uniformly sampled stretch, usable on every row: q (and a measured dq)
    through :func:`lowpass_to_the_edges`, dq otherwise and ddq the central difference taken
    on the run-on stretch (so central at the ends as well)."""
    step = 1.0 / fs_hz
    q_f, pad = _lowpass_run_on(q, cutoff_hz, fs_hz)
    dq_f = (
        np.gradient(q_f, step, axis=0) if dq is None else _lowpass_run_on(dq, cutoff_hz, fs_hz)[0]
    )
    ddq_f = np.gradient(dq_f, step, axis=0)
    rows = slice(pad, pad + q.shape[0])
    return q_f[rows], dq_f[rows], ddq_f[rows]


def _lowpass_run_on(x: np.ndarray, cutoff_hz: float, fs_hz: float) -> tuple[np.ndarray, int]:
    """``x`` run on at both ends and filtered, and the run-on's length (rows at each end)."""
    if x.shape[0] <= 3 * (2 * FILTER_ORDER + 1) or cutoff_hz >= 0.5 * fs_hz:
        return x.copy(), 0
    sos = _butter_sos(float(cutoff_hz), float(fs_hz)).copy()
    pad = _edge_samples(cutoff_hz, fs_hz)
    span = max(1.0 / cutoff_hz, EDGE_FIT_S)
    fit = min(pad, x.shape[0], max(EDGE_POLY_DEGREE + 2, int(np.ceil(span * fs_hz))))
    k = np.arange(-pad, 0, dtype=float)
    head = _run_on(x[:fit], k, EDGE_POLY_DEGREE)
    tail = _run_on(x[::-1][:fit], k, EDGE_POLY_DEGREE)[::-1]
    return _signal().sosfiltfilt(sos, np.concatenate([head, x, tail]), axis=0, padtype=None), pad


def _run_on(x: np.ndarray, k: np.ndarray, degree: int) -> np.ndarray:
    """The polynomial fit of ``x`` (rows 0, 1, ..) evaluated at sample indices ``k`` (< 0)."""
    s = np.arange(x.shape[0], dtype=float)
    scale = max(float(x.shape[0]), 1.0)
    deg = min(degree, x.shape[0] - 1)
    basis = np.vander(s / scale, deg + 1)
    coef, *_ = np.linalg.lstsq(basis, x.reshape(x.shape[0], -1), rcond=None)
    return (np.vander(k / scale, deg + 1) @ coef).reshape(k.size, *x.shape[1:])


def white_noise_std(x: np.ndarray) -> np.ndarray:
    """Std of white noise on the raw samples ``x`` (T, n), per column [units of x].

    From second differences: white noise of std σ gives ``x[k+1] - 2x[k] + x[k-1]`` of std
    ``sqrt(6) σ``, while a trajectory sampled far above its bandwidth contributes next to
    nothing. A friction reversal is a step and spoils a few differences, so the spread is
    taken robustly (1.4826 × the median absolute deviation). Coloured (already filtered)
    noise reads lower than its total std: what is measured is its high-frequency level.
    """
    d2 = np.diff(np.asarray(x, dtype=float), n=2, axis=0)
    if d2.shape[0] < 3:
        return np.full(np.shape(x)[1], np.nan)
    mad = np.median(np.abs(d2 - np.median(d2, axis=0)), axis=0)
    return 1.4826 * mad / np.sqrt(6.0)


def velocity_noise_std(
    q: np.ndarray, dq: np.ndarray | None, step_s: float, cutoff_hz: float
) -> np.ndarray:
    """Std of the noise on the velocity after the states' low-pass at ``cutoff_hz`` [rad/s],
    per joint, from one gap-free stretch's raw samples ``q`` and ``dq`` (T, n) taken every
    ``step_s``: the raw velocity's white noise (:func:`white_noise_std`; without a velocity
    column, that of q's central difference, which the states are then made from) through the
    filter's noise gain (:func:`filter_noise_gain`).

    At rest the measured velocity is this noise alone, and a friction sign taken of it flips
    between ± the Coulomb level from one sample to the next while the joint holds still (a
    slow teaching motion, its rests and reversals, are full of such samples)."""
    raw = np.asarray(dq, dtype=float) if dq is not None else np.gradient(q, step_s, axis=0)
    return white_noise_std(raw) * np.sqrt(filter_noise_gain(cutoff_hz, 1.0 / step_s))


def friction_states(
    q: np.ndarray,
    q_raw: np.ndarray,
    dq: np.ndarray | None,
    dq_f: np.ndarray,
    step_s: float,
    raw_step_s: float,
    position_cutoff_hz: float,
    torque_cutoff_hz: float,
) -> tuple[np.ndarray, np.ndarray]:
    """Friction's velocity (T, n) [rad/s] of one gap-free stretch and its noise's std (n,), over
    which friction is taken in expectation (:mod:`.friction_velocity`).

    ``q`` and ``dq`` (None without a velocity column) are the stretch's samples on its uniform
    grid of ``step_s``, ``q_raw`` the recorded positions taken every ``raw_step_s``, ``dq_f``
    the states' velocity low-passed at ``position_cutoff_hz``; ``torque_cutoff_hz`` is the
    torque's low-pass, whose period bounds the positions' window. From positions alone the
    states' velocity is made of them already and is friction's own.
    """
    if dq is None:
        return dq_f, velocity_noise_std(q_raw, None, raw_step_s, position_cutoff_hz)
    return friction_velocity(
        q, q_raw, white_noise_std(q), dq_f,
        velocity_noise_std(q, dq, step_s, position_cutoff_hz), torque_cutoff_hz, 1.0 / step_s,
    )  # fmt: skip


def filter_noise_gain(cutoff_hz: float, fs_hz: float) -> float:
    """Variance gain of the torque filter on white noise: sum of its squared impulse response.

    White noise of std σ leaves the zero-phase Butterworth of :func:`_lowpass` with std
    ``σ sqrt(gain)`` (about ``σ sqrt(2 · 0.9 f_c / f_s)`` for order 4 run forward and back).
    """
    if cutoff_hz >= 0.5 * fs_hz:
        return 1.0
    length = int(40 * fs_hz / cutoff_hz) + 101
    impulse = np.zeros(length)
    impulse[length // 2] = 1.0
    return float(np.sum(_lowpass(impulse, cutoff_hz, fs_hz) ** 2))


def prepare(
    m: Measurements,
    rate_hz: float = DEFAULT_RATE_HZ,
    position_cutoff_hz: float = DEFAULT_POSITION_CUTOFF_HZ,
    torque_cutoff_hz: float = DEFAULT_TORQUE_CUTOFF_HZ,
    edge_cutoff_hz: float | None = None,
) -> Prepared:
    """Filter, differentiate and decimate one file's samples (steps in the module docstring).

    ``edge_cutoff_hz`` (default ``position_cutoff_hz``) sets the edges dropped: analyses of the
    same file at several cutoffs pass their lowest so that all keep the same rows.

    Raises :class:`DataFileError` when a position jumps by more than :data:`MAX_STEP_RAD`
    between two samples, or when no segment is long enough to filter.
    """
    _check_cutoffs(rate_hz, position_cutoff_hz, torque_cutoff_hz)
    jumps = np.abs(np.diff(m.q, axis=0)) > MAX_STEP_RAD
    parts: list[dict[str, np.ndarray]] = []
    rates = []
    noise: list[tuple[int, np.ndarray, np.ndarray, np.ndarray]] = []
    dq_noise: list[tuple[int, np.ndarray]] = []
    for seg_id, (a, b) in enumerate(gap_free_segments(m.t)):
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
        raw_noise = white_noise_std(m.tau[a:b])
        signals = {"q": m.q[a:b], "tau": m.tau[a:b]}
        if m.dq is not None:
            signals["dq"] = m.dq[a:b]
        if m.p is not None:
            signals["p"] = m.p[a:b]
        mix = np.zeros((t.size, 3))
        if np.max(np.abs(np.diff(t) - step)) > JITTER_TOLERANCE * step:
            t, signals, mix = uniform_grid(t, signals, step)
        edge = _edge_samples(edge_cutoff_hz or position_cutoff_hz, fs)
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
        # friction's velocity and its noise, over which friction is taken in expectation
        dq_fr, raw_dq_noise = friction_states(
            signals["q"], m.q[a:b], signals.get("dq"), dq, step, step, position_cutoff_hz, tau_cut
        )
        tau = _lowpass(signals["tau"], tau_cut, fs)
        p = _lowpass(signals["p"], tau_cut, fs) if "p" in signals else None
        factor = max(1, round(fs / rate_hz))
        keep = slice(edge, t.size - edge, factor)
        part = {"t": t[keep], "q": q[keep], "dq": dq[keep], "ddq": ddq[keep], "tau": tau[keep]}
        part["dq_friction"] = dq_fr[keep]
        part["resample_mix"] = mix[keep]
        if p is not None:
            part["p"] = p[keep]
        part["segment"] = np.full(part["t"].size, seg_id)
        part["filter_hz"] = np.full(part["t"].size, tau_cut)
        part["sample_hz"] = np.full(part["t"].size, fs / factor)
        part["raw_hz"] = np.full(part["t"].size, fs)
        odds = rest_log_odds_per_joint(part["dq_friction"], raw_dq_noise)
        part["rest_odds"] = np.tile(odds, (part["t"].size, 1))
        parts.append(part)
        rates.append(fs / factor)
        floor = raw_noise * np.sqrt(filter_noise_gain(tau_cut, fs))
        noise.append((part["t"].size, raw_noise, floor, raw_noise / np.sqrt(factor)))
        dq_noise.append((part["t"].size, raw_dq_noise))
    if not parts:
        raise TooShortError(
            f"{m.source}: too short to analyse: no gap-free stretch longer than "
            f"{2 * EDGE_PERIODS / (edge_cutoff_hz or position_cutoff_hz):.2f} s plus "
            f"{MIN_SEGMENT_SAMPLES} samples"
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
        filter_hz=cat["filter_hz"],
        sample_hz=cat["sample_hz"],
        raw_hz=cat["raw_hz"],
        noise_nm=_pooled([(k, f) for k, _, f, _ in noise]),
        raw_noise_nm=_pooled([(k, r) for k, r, _, _ in noise]),
        noise_dof_nm2=_squared(_pooled([(k, d) for k, _, _, d in noise])),
        dq_noise_rad_s=_pooled(dq_noise),
        dq_rest_odds=cat["rest_odds"],
        dq_friction=cat["dq_friction"],
        resample_mix=cat["resample_mix"],
    )


def _squared(x: np.ndarray | None) -> np.ndarray | None:
    return None if x is None else x**2


def _pooled(parts: Sequence[tuple[int, np.ndarray | None]]) -> np.ndarray | None:
    """Sample-weighted RMS of per-part stds ``(samples, std (n,))``; None if any is unknown."""
    if not parts or any(v is None for _, v in parts):
        return None
    w = np.array([k for k, _ in parts], dtype=float)
    v = np.array([np.asarray(x, dtype=float) for _, x in parts])
    return np.sqrt(np.einsum("k,kj->j", w, v**2) / w.sum())


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
        filter_hz=_cat_optional([p.filter_hz for p in parts]),
        sample_hz=_cat_optional([p.sample_hz for p in parts]),
        raw_hz=_cat_optional([p.raw_hz for p in parts]),
        noise_nm=_pooled([(p.n_samples, p.noise_nm) for p in parts]),
        raw_noise_nm=_pooled([(p.n_samples, p.raw_noise_nm) for p in parts]),
        noise_dof_nm2=_squared(_pooled([(p.n_samples, _sqrt(p.noise_dof_nm2)) for p in parts])),
        dq_noise_rad_s=_pooled([(p.n_samples, p.dq_noise_rad_s) for p in parts]),
        dq_rest_odds=_cat_optional([p.dq_rest_odds for p in parts]),
        dq_friction=_cat_optional([p.dq_friction for p in parts]),
        resample_mix=_cat_optional([p.resample_mix for p in parts]),
    )


def _sqrt(x: np.ndarray | None) -> np.ndarray | None:
    return None if x is None else np.sqrt(x)


def _cat_optional(arrays: Sequence[np.ndarray | None]) -> np.ndarray | None:
    if any(a is None for a in arrays):
        return None
    return np.concatenate(arrays)  # type: ignore[arg-type]


#: Below this joint speed a joint is taken as stuck in its static friction [rad/s]: a quarter
#: of the slowest friction run of the paper's plan (0.5 °/s), far above the velocity noise of
#: an encoder-based velocity (a 17-bit encoder behind a 100:1 gear resolves 5e-5 rad/s at
#: 125 Hz). See :func:`sliding_mask`.
DEFAULT_STICK_VELOCITY_RAD_S = 2e-3


def sliding_mask(data: Prepared, stick_velocity_rad_s: float, window_s: float) -> np.ndarray:
    """(T, n) 1.0 where joint j slides at sample t, 0.0 where it is stuck or was within
    ``window_s`` of being stuck (in the same segment).

    A geared joint below its breakaway torque does not move, and its friction is then any
    torque up to that level: whatever the servo's integrator has wound up, not a function of
    the motion. No friction model of (q, dq) predicts those rows, so they neither fit the model
    nor score it. The window covers the torque filter's smearing of the breakaway transient
    (about one period of the cutoff frequency). ``stick_velocity_rad_s`` 0 keeps every row.
    """
    n_rows, n = data.dq.shape
    if stick_velocity_rad_s <= 0:
        return np.ones((n_rows, n))
    stuck = np.abs(data.dq) < stick_velocity_rad_s
    rates = data.sample_hz if data.sample_hz is not None else np.full(n_rows, data.rate_hz)
    out = np.ones((n_rows, n))
    bounds = np.flatnonzero(np.diff(data.segment) != 0) + 1
    for a, b in pairwise(np.r_[0, bounds, n_rows]):
        seg = stuck[a:b]
        half = int(np.ceil(window_s * float(rates[a])))
        if half > 0:
            # dilate: a row is out when any row within ``half`` of it is stuck (any length)
            padded = np.pad(seg, ((half, half), (0, 0))).astype(np.int64)
            counts = np.cumsum(np.vstack([np.zeros((1, n), np.int64), padded]), axis=0)
            seg = (counts[2 * half + 1 :] - counts[: -2 * half - 1]) > 0
        out[a:b] = ~seg
    return out
