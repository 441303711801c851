"""Hand tremor out of a taught recording: :func:`remove_tremor`, a zero-phase low-pass of
every joint (step 1 of :func:`control.taught_path.replay_trajectory`)."""

from __future__ import annotations

import math

import numpy as np
from scipy.signal import butter, sosfiltfilt

from control.taught_path_checks import _finite_array

#: tremor low-pass cut-off [Hz], -6 dB point of the zero-phase filter (see remove_tremor)
TREMOR_CUTOFF_HZ = 2.5
#: order of the Butterworth design; sosfiltfilt runs it forward and backward (|H|² overall)
TREMOR_FILTER_ORDER = 4

_MIN_FILTER_SAMPLES = 3  #: fewer samples are returned unfiltered
#: shorter segments (in cut-off periods) are returned unfiltered: on a synthetic 0.6 s move
#: the low-pass erred more than the tremor it removed
_MIN_FILTER_PERIODS = 2.0
_MAX_RESAMPLE_FACTOR = 100  #: uniform grid at most this many times the samples (a time gap)
_MAX_CUTOFF_OF_NYQUIST = 0.8  #: the cut-off must lie well below the Nyquist frequency


def remove_tremor(
    t_s: np.ndarray, q_rad: np.ndarray, cutoff_hz: float = TREMOR_CUTOFF_HZ
) -> np.ndarray:
    """Joint positions (T, n) or (T,) [rad] at times ``t_s`` (T,) [s] with the hand tremor
    low-passed away, at the same times.

    Filter: Butterworth of order :data:`TREMOR_FILTER_ORDER` (4) run forward and backward
    (``sosfiltfilt``): no phase lag, so the path is not shifted, and |H(f)|² = 1 / (1 +
    (f/f_c)^8) overall, -6 dB at f_c. Physiological hand tremor lies at 4-12 Hz, a painter's
    deliberate motion below ~1.5 Hz. f_c = 2.5 Hz sits midway between 1.5 and 4 Hz on a log
    scale: 1.5 Hz keeps 98 % (at 2 Hz it would keep 91 %), 4 Hz is cut 44x, 8 Hz 11,000x.

    Non-uniform time: the samples are interpolated (linearly) onto a uniform grid at their
    median rate, filtered, and interpolated back. Ends: each end is extended by a least-squares
    quadratic through its first 1/(2 f_c) s (value, slope and curvature carry on) plus the
    samples' deviation from it reflected through the end (:func:`_odd_extension`).
    sosfiltfilt's own odd reflection about the raw end sample flips the path's curvature
    there: on the tests' 0.3 Hz sweep a bias of up to 1.3 mm at the tool, 0.2 mm this way.
    The first and last ~50 ms keep part of the tremor all the same: there is no later sample
    to average it with. A segment shorter than two periods of the cut-off (0.8 s), or of
    fewer than 3 samples, is returned unfiltered: too short to tell tremor from motion.
    Raises ValueError on non-finite values, times that do not increase, or a cut-off the
    sample rate cannot carry.
    """
    t = _finite_array(t_s, "t_s")
    q = _finite_array(q_rad, "q_rad")
    if t.ndim != 1 or q.ndim not in (1, 2) or q.shape[0] != t.size:
        raise ValueError(f"t_s must be (T,) and q_rad (T,) or (T, n); got {t.shape}, {q.shape}")
    if not (math.isfinite(cutoff_hz) and cutoff_hz > 0):
        raise ValueError(f"cutoff_hz must be a finite frequency > 0, got {cutoff_hz!r}")
    steps = np.diff(t)
    if np.any(steps <= 0):
        k = int(np.flatnonzero(steps <= 0)[0]) + 1
        raise ValueError(f"t_s must increase: sample {k} at {t[k]!r} s follows {t[k - 1]!r} s")
    if t.size < _MIN_FILTER_SAMPLES or t[-1] - t[0] < _MIN_FILTER_PERIODS / cutoff_hz:
        return q.copy()  # too short to tell tremor from motion
    y = q.reshape(t.size, -1)
    duration = float(t[-1] - t[0])
    n_uniform = max(_MIN_FILTER_SAMPLES, round(duration / float(np.median(steps))) + 1)
    if n_uniform > _MAX_RESAMPLE_FACTOR * t.size:
        gap = int(np.argmax(steps))
        raise ValueError(
            f"t_s has a gap of {steps[gap]:.3f} s after sample {gap} in samples "
            f"{np.median(steps):.4f} s apart: a uniform grid would be too large"
        )
    fs_hz = (n_uniform - 1) / duration
    if cutoff_hz >= _MAX_CUTOFF_OF_NYQUIST * fs_hz / 2:
        raise ValueError(
            f"a {cutoff_hz} Hz tremor cut-off needs samples faster than "
            f"{2 * cutoff_hz / _MAX_CUTOFF_OF_NYQUIST:.1f} Hz; these come at {fs_hz:.1f} Hz"
        )
    t_u = np.linspace(t[0], t[-1], n_uniform)
    y_u = np.column_stack([np.interp(t_u, t, y[:, j]) for j in range(y.shape[1])])
    y_f = _zero_phase_lowpass(y_u, fs_hz, cutoff_hz)
    out = np.column_stack([np.interp(t, t_u, y_f[:, j]) for j in range(y.shape[1])])
    return out.reshape(q.shape)


def _zero_phase_lowpass(y: np.ndarray, fs_hz: float, cutoff_hz: float) -> np.ndarray:
    """sosfiltfilt of uniform samples y (N, n) with the ends extended (remove_tremor)."""
    sos = butter(TREMOR_FILTER_ORDER, cutoff_hz, fs=fs_hz, output="sos")
    n = y.shape[0]
    window = int(np.clip(round(fs_hz / (2 * cutoff_hz)), 3, n))
    pad = math.ceil(3 * fs_hz / cutoff_hz)  # ~3 periods of the cut-off: the start-up dies out
    front = _odd_extension(y, window, pad)
    back = _odd_extension(y[::-1], window, pad)[::-1]
    out = sosfiltfilt(sos, np.vstack([front, y, back]), axis=0, padtype=None)
    return out[pad : pad + n]


def _odd_extension(y: np.ndarray, window: int, pad: int) -> np.ndarray:
    """``pad`` rows to put before y (N, n): y(-k) = Q(-k) - (y(k) - Q(k)) for k = pad..1, Q the
    least-squares quadratic through the first ``window`` rows (y(k) - Q(k) taken as 0 for
    k >= N). The trend Q carries on with its value, slope and curvature; the tremor about it
    is reflected through the fitted end value, so the end sample's own tremor is not taken as
    the end point."""
    x = np.arange(window, dtype=float)
    basis = np.column_stack([np.ones_like(x), x, x**2])
    coef = np.linalg.lstsq(basis, y[:window], rcond=None)[0]
    k = np.arange(pad, 0, -1)
    trend = np.column_stack([np.ones(pad), -k, k**2]) @ coef
    mirrored = k < y.shape[0]
    kk = k[mirrored]
    trend[mirrored] -= y[kk] - np.column_stack([np.ones(kk.size), kk, kk**2]) @ coef
    return trend
