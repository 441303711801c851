"""The velocity friction is taken of: the positions' own slope where they are finer than the
measured velocity.

Friction turns with the velocity's sign at speeds a measured velocity cannot resolve: a
Coulomb law is at its full level from 1e-4 rad/s, while a drive's velocity reading carries
noise of 1e-4 to 3e-3 rad/s. A joint that creeps out of a rest (teaching: the operator's hand
starts a move), or holds still after one, is told apart from one that does not by its
positions, whose encoder steps are 1e-8 to 1e-5 rad: thirty steps in the first third of a
second of a creep at 1e-4 rad/s. So friction's velocity is the least-squares slope of the
positions over a window of 2h + 1 samples, blended with the low-passed measured velocity by
the inverse of each one's noise variance, with the blend's own noise left for the
expectation over rest and motion (:meth:`.terms.Context.sample_mean`).

- The slope of a straight-line fit keeps the sign of a monotone motion: it never reads a
  reversal where the joint only stopped (a low-passed velocity rings past zero after a stop,
  by some per cent of the speed before it, and the low-passed positions' derivative does the
  same), and it reads zero on a position that holds.
- The window is the shortest whose slope noise (the positions' white noise, at least their
  resolution over √12, through the window's gain) is at most :data:`NOISE_SHARE` of the
  measured velocity's: a longer window spreads a start-up over its half-width before the
  joint moves. It is at most one period of the torque's low-pass, which every friction column
  passes through as the measured torque does (:meth:`.terms.Context.filtered`): no longer
  than the smear the measurement itself has. (At one period of the states' cutoff, 2 Hz on a
  noisy velocity, it took a quarter of a second off each side of every reversal.)
- The rigid body's columns keep the states' velocity (:mod:`.preprocess`): their errors in
  variables are the low-pass's business, and a short window's slope is broadband.
"""

from __future__ import annotations

import numpy as np

#: The window is the shortest whose slope's noise is at most this share of the measured
#: velocity's (after the states' low-pass): the blend then takes ≥ 94 % of its weight from the
#: positions, where they are the finer reading.
NOISE_SHARE = 0.25
#: The positions' slope is blended only where it agrees with the measured velocity: their
#: difference's robust spread within this many of their joint noise (two unbiased readings: 1).
CONSISTENT_SIGMAS = 3.0
#: Floor of a position's noise [rad] where a stretch shows neither noise nor a step (a joint
#: that holds still throughout): a reading that never changes, of a joint that does not move.
MIN_POSITION_NOISE_RAD = 1e-12


#: Changes of a recorded position below this [rad] are the file's rounding, not a step: a CSV
#: written to 12 significant digits rounds by 1e-12 rad; a 24-bit encoder through a 200:1
#: gear steps 1.9e-9 rad.
ROUNDING_RAD = 1e-10


def resolution(q_raw: np.ndarray) -> np.ndarray:
    """Per joint the smallest change of the recorded positions [rad], first or second
    difference (a joint moving several steps per sample changes its step count by one), 0
    where none changes: the encoder's step through the gear, or finer."""
    q = np.asarray(q_raw, dtype=float)
    out = np.full(q.shape[1], np.inf)
    for d in (np.diff(q, axis=0), np.diff(q, n=2, axis=0)):
        d = np.abs(d)
        d = np.where(d > ROUNDING_RAD, d, np.inf)
        if d.shape[0]:
            out = np.minimum(out, np.min(d, axis=0))
    return np.where(np.isfinite(out), out, 0.0)


def slope(x: np.ndarray, half: int, fs_hz: float) -> np.ndarray:
    """Least-squares slope of ``x`` (N,) per second over the window of ``2 half + 1`` samples
    centred on each (shrunk to the samples there are at the ends)."""
    x = np.asarray(x, dtype=float)
    n = x.shape[0]
    if n < 2:
        return np.zeros(n)
    half = min(half, (n - 1) // 2)  # a window no longer than the stretch
    k = np.arange(-half, half + 1, dtype=float)
    out = np.convolve(x, k[::-1] / np.sum(k**2) * fs_hz, mode="same")
    for r in sorted(set(range(min(half, n))) | set(range(max(n - half, 0), n))):
        lo, hi = max(0, r - half), min(n, r + half + 1)
        kk = np.arange(lo, hi, dtype=float)
        kk -= kk.mean()
        out[r] = float(kk @ x[lo:hi]) / float(np.sum(kk**2)) * fs_hz
    return out


def slope_noise(position_noise: float, step: float, half: int, fs_hz: float) -> float:
    """The error [rad/s] of the slope over 2 half + 1 samples of positions with white noise
    ``position_noise`` [rad] read in steps of ``step`` [rad]: the white noise through the
    window's gain, ``σ fs / sqrt(Σ k²)``, and at least one step over the window's span. A
    quantised reading of a slow motion is a staircase, not white noise: one step more or less
    inside the window moves its slope by about ``step · fs / (2 half + 1)``, √half times what
    the white model of the step (``step / √12``) says."""
    white = position_noise * fs_hz / np.sqrt(half * (half + 1) * (2 * half + 1) / 3.0)
    return float(max(white, step * fs_hz / (2 * half + 1)))


def window_half(
    position_noise: float, step: float, velocity_noise: float, fs_hz: float, longest: int
) -> int:
    """The half-width h (samples) of the shortest window whose :func:`slope_noise` is at most
    :data:`NOISE_SHARE` × ``velocity_noise``; ``longest`` when none is (or the velocity's
    noise is unknown)."""
    if not (np.isfinite(velocity_noise) and velocity_noise > 0.0):
        return longest
    for h in range(1, longest + 1):
        if slope_noise(position_noise, step, h, fs_hz) <= NOISE_SHARE * velocity_noise:
            return h
    return longest


def friction_velocity(
    q: np.ndarray,
    q_raw: np.ndarray,
    q_noise: np.ndarray,
    v_measured: np.ndarray,
    v_noise: np.ndarray,
    torque_cutoff_hz: float,
    fs_hz: float,
) -> tuple[np.ndarray, np.ndarray]:
    """Friction's velocity (T, n) [rad/s] of one uniformly sampled stretch and its noise's std
    (n,) (module docstring).

    ``q`` (T, n) the positions on the stretch's grid, ``q_raw`` the recorded ones (for their
    resolution), ``q_noise`` (n,) the positions' white noise [rad]; ``v_measured`` (T, n) the
    low-passed measured velocity and ``v_noise`` (n,) its noise; ``torque_cutoff_hz`` the
    torque's low-pass, whose period bounds the window.
    """
    q = np.asarray(q, dtype=float)
    n = q.shape[1]
    step = resolution(q_raw)
    noise = np.maximum(
        np.maximum(np.asarray(q_noise, dtype=float), step / np.sqrt(12.0)),
        MIN_POSITION_NOISE_RAD,
    )
    longest = max(1, round(0.5 * fs_hz / torque_cutoff_hz))
    v = np.zeros_like(q)
    sigma = np.zeros(n)
    for j in range(n):
        vn = float(v_noise[j])
        if not (np.isfinite(vn) and vn > 0.0):  # an exact reading, or one too short to tell
            v[:, j], sigma[j] = v_measured[:, j], vn
            continue
        half = window_half(float(noise[j]), float(step[j]), vn, fs_hz, longest)
        v_q = slope(q[:, j], half, fs_hz)
        s_q = slope_noise(float(noise[j]), float(step[j]), half, fs_hz)
        # two readings of one velocity agree within their noise; a velocity column that is not
        # the positions' derivative (a controller's estimate, another filter) is not blended.
        # Robustly (1.4826 × the median absolute difference): the two filters' bandwidths
        # differ at a sudden stop or start, a few rows of the stretch
        diff = np.abs(v_measured[:, j] - v_q)
        gap = 1.4826 * float(np.median(diff)) if diff.size else 0.0
        if gap > CONSISTENT_SIGMAS * np.hypot(s_q, vn):
            v[:, j], sigma[j] = v_measured[:, j], vn
            continue
        w = s_q**2 / (s_q**2 + vn**2)  # the measured velocity's weight
        v[:, j] = w * v_measured[:, j] + (1.0 - w) * v_q
        sigma[j] = np.sqrt(w**2 * vn**2 + (1.0 - w) ** 2 * s_q**2)
    return v, sigma
