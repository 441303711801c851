"""A signal shifted in time within each segment of a recording, by a band-limited (Fourier)
shift: the time-delay effect's torque model at ``t - δ`` (:mod:`.effects`, :mod:`.model`,
:mod:`.analyze`)."""

from __future__ import annotations

import numpy as np
from scipy.fft import next_fast_len


def shift_signal(
    t: np.ndarray, segment: np.ndarray | None, x: np.ndarray, delta_s: float
) -> np.ndarray:
    """``x`` evaluated at ``t + delta_s`` within each segment: a band-limited (Fourier) shift.

    ``x`` (T,) or (T, n), sampled uniformly within each segment (as :mod:`.preprocess` leaves
    it). Used for the time-delay effect: with the torque lagging by δ, ``τ_model(t - δ)`` is
    ``shift_signal(t, seg, τ_model, -δ)``. The shift multiplies the spectrum by
    ``exp(i 2π f δ)``: an all-pass, so a shifted signal keeps its noise. (Linear interpolation
    between samples would average neighbours and take up to half the white-noise power out at
    a half-sample shift, which a delay search then mistakes for a better fit.) Each segment is
    extended by reflection before the transform, so its ends do not wrap round.
    """
    if delta_s == 0.0:
        return np.array(x, dtype=float, copy=True)
    arr = np.asarray(x, dtype=float)
    flat = arr[:, None] if arr.ndim == 1 else arr
    out = np.empty_like(flat)
    seg = np.zeros(t.size, dtype=int) if segment is None else segment
    bounds = np.flatnonzero(np.diff(seg) != 0) + 1
    for a, b in zip(np.r_[0, bounds], np.r_[bounds, t.size], strict=True):
        out[a:b] = _fourier_shift(t[a:b], flat[a:b], delta_s)
    return out[:, 0] if arr.ndim == 1 else out


def _fourier_shift(t: np.ndarray, x: np.ndarray, delta_s: float) -> np.ndarray:
    """One uniformly sampled segment ``x`` (L, m) at ``t + delta_s`` (see :func:`shift_signal`).

    The segment is extended at both ends by point reflection (value and slope continue) and
    the straight line through the extension's ends is taken out, so the transform's circular
    wrap meets no step; the line is shifted exactly and added back.
    """
    length = x.shape[0]
    if length < 2:
        return x.copy()
    dt = float(np.median(np.diff(t)))
    pad = min(length - 1, int(np.ceil(abs(delta_s) / dt)) + 128)
    # the right end takes a few samples more up to a length the FFT factors well (a segment
    # whose length has a large prime factor transforms several times slower)
    extra = next_fast_len(length + 2 * pad, real=True) - (length + 2 * pad)
    ext = np.pad(x, ((pad, pad + extra), (0, 0)), mode="reflect", reflect_type="odd")
    size = ext.shape[0]
    k = np.arange(size, dtype=float)[:, None]
    slope = (ext[-1] - ext[0]) / size  # the wrap from the last sample to the first is a step
    base = ext[0] + slope * k
    spec = np.fft.rfft(ext - base, axis=0)
    spec *= np.exp(2j * np.pi * np.fft.rfftfreq(size, d=dt) * delta_s)[:, None]
    shifted = np.fft.irfft(spec, n=size, axis=0) + base + slope * (delta_s / dt)
    return shifted[pad : pad + length]
