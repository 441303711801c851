"""The motor-current sensors' zero, measured while the drives are unpowered.

A drive's current sensor reads a small constant offset (typically within 0.5 % of its range)
in every current it reports, the servo on or off. With the servo power off no current flows
(brakes engaged, or released for the servo-off baseline), so what the drive reports then is
its offset plus noise. :class:`CurrentZero` averages the newest ``window`` such cycles, after
skipping ``settle`` cycles once the power went off (a drive's current filter still holds the
last powered ticks), and freezes while the power is on. The driver subtracts it from every
current it publishes, so identification, the control law and recordings see the motor's
current, and reports it in its health. The servo power is first requested once the window is
full (:attr:`CurrentZero.ready`, the driver's health says when it waits): a zero from a
handful of cycles would be off by the current noise over their root, a constant torque error
that the zero-moment loop turns into a creeping wrist (at 0.02 A noise, 20 cycles leave
0.0045 A, 0.05 N·m on J5 of the GR630ST; 250 cycles 0.0013 A).

**The zero of the commissioning.** The dynamic model is identified from currents corrected by
the zero measured when the cell was commissioned. A zero measured again at every start differs
from it by the noise of both means (about 0.0018 A for two 250-cycle means at 0.02 A: 0.12 N·m
on J2), a constant torque error that nothing in the zero-moment loop holds: the tool creeps
(1.1 mm in 5 s with a spray gun on the virtual cell). So `leadthrough identify` writes the zero
it ran with to ``current_zero.json`` (:func:`write_stored_zero`), ``[can] current_zero_file``
names it, and the driver then uses *that* zero, ready at once: model and currents agree. It
still measures a fresh zero whenever the power is off and reports it (``measured_a``,
:attr:`CurrentZero.drift_a`); a drift beyond what the noise of the two means explains
(:data:`DRIFT_SIGMAS`, :attr:`CurrentZero.drift_significant`) means the sensors changed since
the commissioning, and the driver says so: commission again.
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
#: a fresh zero this many standard errors (of the two means' difference) from the stored one
#: is a drift, not noise
DRIFT_SIGMAS = 5.0


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


class CurrentZero:
    """Running mean of the currents reported while the servo power is off (module docstring).
    ``window`` 0 disables it (:attr:`offset_a` stays zero). ``stored`` (zero [A], samples,
    per-cycle noise [A], as :func:`read_stored_zero` returns) is the commissioning's zero: it
    is used from the start, and the running mean only watches it."""

    def __init__(
        self,
        joints: int,
        window: int,
        settle: int,
        stored: tuple[np.ndarray, int, np.ndarray] | None = None,
    ) -> None:
        if window < 0 or settle < 0:
            raise ValueError(f"window {window} and settle {settle} must be >= 0")
        self.window, self.settle = window, settle
        self._ring = np.zeros((max(window, 1), joints))
        self._sum = np.zeros(joints)
        self._next = 0
        #: cycles in the mean (≤ window)
        self.samples = 0
        self._off_cycles = 0
        #: the running mean of the newest unpowered cycles [A], (joints,)
        self.measured_a = np.zeros(joints)
        self.stored = stored
        #: the current sensors' zero [A], (joints,): what :meth:`correct` subtracts
        self.offset_a = np.zeros(joints) if stored is None else np.array(stored[0], dtype=float)
        #: the zero can be used: the window was full once, or the commissioning's is loaded
        self.ready = window == 0 or stored is not None

    @property
    def source(self) -> str:
        """Where :attr:`offset_a` comes from: "commissioning", "measured" or "off"."""
        if self.stored is not None:
            return "commissioning"
        return "measured" if self.window else "off"

    def noise_a(self) -> np.ndarray:
        """Per-cycle standard deviation of the unpowered currents in the window [A]."""
        if self.samples < 2:
            return np.zeros(self._sum.shape)
        ring = self._ring[: self.samples]
        return ring.std(axis=0, ddof=1)

    @property
    def drift_a(self) -> np.ndarray | None:
        """Fresh zero less the stored one [A] once the window is full (None before, or with
        no stored zero)."""
        if self.stored is None or self.samples < self.window or not self.window:
            return None
        return self.measured_a - self.stored[0]

    def drift_significant(self, noise_a: np.ndarray | None = None) -> bool:
        """The fresh zero differs from the stored one by more than :data:`DRIFT_SIGMAS`
        standard errors of the two means on some joint (``noise_a``: :meth:`noise_a`, when
        the caller has it already)."""
        drift = self.drift_a
        if drift is None or self.stored is None:
            return False
        _, n_stored, noise_stored = self.stored
        noise = self.noise_a() if noise_a is None else noise_a
        se = np.sqrt(noise_stored**2 / n_stored + noise**2 / self.samples)
        return bool(np.any(np.abs(drift) > DRIFT_SIGMAS * np.maximum(se, 1e-12)))

    def update(self, current_a: np.ndarray, servo_power: bool) -> None:
        """Take one cycle's reported currents [A] and whether the servo power was on."""
        if servo_power or not self.window:
            self._off_cycles = 0
            return
        self._off_cycles += 1
        if self._off_cycles <= self.settle or not np.all(np.isfinite(current_a)):
            return
        old = self._ring[self._next]
        if self.samples == self.window:
            self._sum -= old
        else:
            self.samples += 1
        self._ring[self._next] = current_a
        self._sum += current_a
        self._next = (self._next + 1) % self.window
        self.measured_a = self._sum / self.samples
        if self.stored is None:
            self.offset_a = self.measured_a
        self.ready = self.ready or self.samples == self.window

    def correct(self, current_a: np.ndarray) -> np.ndarray:
        """The motor's current [A]: ``current_a`` less the sensors' zero."""
        return current_a - self.offset_a
