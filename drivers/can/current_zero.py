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
"""

from __future__ import annotations

import numpy as np


class CurrentZero:
    """Running mean of the currents reported while the servo power is off (module docstring).
    ``window`` 0 disables it (:attr:`offset_a` stays zero)."""

    def __init__(self, joints: int, window: int, settle: int) -> None:
        if window < 0 or settle < 0:
            raise ValueError(f"window {window} and settle {settle} must be >= 0")
        self.window, self.settle = window, settle
        self._ring = np.zeros((max(window, 1), joints))
        self._sum = np.zeros(joints)
        self._next = 0
        #: cycles in the mean (≤ window)
        self.samples = 0
        self._off_cycles = 0
        #: the current sensors' zero [A], (joints,): what :meth:`correct` subtracts
        self.offset_a = np.zeros(joints)
        #: the window was full once (stays True)
        self.ready = window == 0

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
        self.offset_a = self._sum / self.samples
        self.ready = self.ready or self.samples == self.window

    def correct(self, current_a: np.ndarray) -> np.ndarray:
        """The motor's current [A]: ``current_a`` less the sensors' zero."""
        return current_a - self.offset_a
