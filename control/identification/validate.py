"""Held-out validation: per-joint torque errors and plots like the paper's Figs. 7-10.

Validation uses the ``--test`` files, which are other trajectories than the training ones
(never a random split of samples: neighbouring samples are nearly equal, so a random split
would grade the fit on data it has practically seen).

Numbers per joint: RMS of ``τ_measured - τ_model`` [N·m], and the relative error
``RMS / RMS(τ_measured)`` (the RMS of the measured torque itself, not its standard deviation).
"""

from __future__ import annotations

import contextlib
from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np

#: Points drawn per curve at most (plots thin evenly beyond).
PLOT_MAX_POINTS = 4000


def rms(x: np.ndarray) -> np.ndarray:
    """RMS over samples, per joint: (T, n) → (n,)."""
    return np.sqrt(np.mean(np.square(np.asarray(x, dtype=float)), axis=0))


def masked_rms(x: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """RMS over the samples where ``mask`` (T, n) is 1, per joint (NaN for a joint with none)."""
    sq = np.square(np.asarray(x, dtype=float)) * mask
    count = mask.sum(axis=0)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.sqrt(sq.sum(axis=0) / count)


def relative_error(tau_measured: np.ndarray, tau_model: np.ndarray) -> np.ndarray:
    """RMS error / RMS of the measured torque, per joint (0 where the torque is all zero)."""
    scale = rms(tau_measured)
    return np.where(scale > 0, rms(tau_measured - tau_model) / np.where(scale > 0, scale, 1), 0.0)


def _pyplot():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def import_plotting() -> None:
    """Import matplotlib with its Agg backend ahead of the first plot (e.g. while worker
    processes compute). A failure is left for the plot itself to report."""
    with contextlib.suppress(Exception):  # the plot raises it again, where it is reported
        _pyplot()


def _thin(n: int) -> slice:
    return slice(None, None, max(1, int(np.ceil(n / PLOT_MAX_POINTS))))


def plot_torques(
    path: str | Path,
    tau_measured: np.ndarray,
    curves: Mapping[str, np.ndarray],
    joint_names: Sequence[str],
    rate_hz: float,
    title: str,
) -> Path:
    """Measured vs model torque per joint over time (Figs. 9-10 style); returns the PNG path.

    Samples of several files are drawn one after another; time is the sample count / rate.
    """
    plt = _pyplot()
    n = len(joint_names)
    t = np.arange(tau_measured.shape[0]) / rate_hz
    s = _thin(t.size)
    fig, axes = plt.subplots(n, 1, figsize=(10, 1.9 * n + 0.8), sharex=True, squeeze=False)
    for j, ax in enumerate(axes[:, 0]):
        ax.plot(t[s], tau_measured[s, j], color="k", lw=0.8, label="measured")
        for k, (label, tau) in enumerate(curves.items()):
            ax.plot(t[s], tau[s, j], lw=0.8, color=f"C{k}", label=label)
        ax.set_ylabel(f"{joint_names[j]}\n[N·m]")
        ax.grid(alpha=0.3)
    axes[0, 0].legend(loc="upper right", fontsize=8, ncol=len(curves) + 1)
    axes[0, 0].set_title(title)
    axes[-1, 0].set_xlabel("time [s] (test samples, files one after another)")
    # fixed margins: tight_layout measures every tick label and costs a third of the plot
    height = 1.9 * n + 0.8
    fig.subplots_adjust(
        left=0.09, right=0.98, top=1 - 0.35 / height, bottom=0.5 / height, hspace=0.12
    )
    out = Path(path)
    fig.savefig(out, dpi=90)
    plt.close(fig)
    return out


def plot_friction(
    path: str | Path,
    dq: np.ndarray,
    friction_measured: np.ndarray,
    curves: Mapping[str, np.ndarray],
    joint_names: Sequence[str],
) -> Path:
    """Friction vs velocity per joint (Figs. 7-8 style): the measured torque minus the
    identified rigid-body torque against dq, with each friction model's torque."""
    plt = _pyplot()
    n = len(joint_names)
    cols = min(3, n)
    rows = int(np.ceil(n / cols))
    fig, axes = plt.subplots(rows, cols, figsize=(4.2 * cols, 3.2 * rows), squeeze=False)
    s = _thin(dq.shape[0])
    for j in range(rows * cols):
        ax = axes[j // cols, j % cols]
        if j >= n:
            ax.axis("off")
            continue
        ax.plot(dq[s, j], friction_measured[s, j], ".", ms=1.5, color="0.6", label="measured")
        for k, (label, tau) in enumerate(curves.items()):
            ax.plot(dq[s, j], tau[s, j], ".", ms=1.0, color=f"C{k}", label=label)
        ax.set_title(joint_names[j], fontsize=9)
        ax.set_xlabel("dq [rad/s]")
        ax.set_ylabel("friction [N·m]")
        ax.grid(alpha=0.3)
    axes[0, 0].legend(fontsize=7, markerscale=6)
    fig.subplots_adjust(left=0.08, right=0.98, top=1 - 0.3 / (3.2 * rows),
                        bottom=0.55 / (3.2 * rows), wspace=0.32, hspace=0.45)  # fmt: skip
    out = Path(path)
    fig.savefig(out, dpi=90)
    plt.close(fig)
    return out
