"""The joint states as the gateway's lifecycle needs them: each StateWindow checked and folded
in once per tick (the newest state, the fastest joint, whether the arm moved)."""

from __future__ import annotations

import math
from collections.abc import Iterable

import numpy as np

from gateway.errors import MessageError
from gateway.messages import (
    LAYOUT_VERSION,
    SERVO_ON,
    ControllerState,
    JointState,
    StateWindow,
)

_STATE_HEAD = JointState._HEAD  #: magic, version, n, cycle, stamp, state, flags, period
_CONTROLLER_STATES = {int(s): s for s in ControllerState}


def joint_state_summary(data: bytes) -> tuple[ControllerState, float, float, np.ndarray]:
    """Controller state, driver stamp [s], fastest joint speed max|dq| [rad/s] and the joint
    positions [rad] (a read-only view of ``data``) of a JointState payload, checked as
    :meth:`JointState.from_bytes` checks it (layout, every value finite) but without building
    one. Raises MessageError naming what is wrong."""
    if len(data) < _STATE_HEAD.size:
        raise MessageError(f"JointState: payload is {len(data)} bytes, shorter than its header")
    magic, version, n, _, stamp_s, state, _, period_s = _STATE_HEAD.unpack_from(data)
    if magic != JointState.MAGIC or version != LAYOUT_VERSION:
        raise MessageError(f"JointState: magic {magic!r} / layout version {version} unsupported")
    if not 1 <= n <= 16 or len(data) != _STATE_HEAD.size + 5 * n * 8:
        raise MessageError(f"JointState: {len(data)} bytes do not hold {n} joints")
    if not (math.isfinite(stamp_s) and math.isfinite(period_s) and period_s >= 0):
        raise MessageError(f"JointState: stamp_s {stamp_s} / cycle_period_s {period_s} invalid")
    controller_state = _CONTROLLER_STATES.get(state)
    if controller_state is None:
        raise MessageError(f"JointState: controller_state {state} unknown")
    body = np.frombuffer(data, dtype="<f8", count=5 * n, offset=_STATE_HEAD.size)
    if not np.isfinite(body).all():
        raise MessageError("JointState: a value is not finite")
    return controller_state, stamp_s, float(np.abs(body[n : 2 * n]).max()), body[:n]


class JointStateWatch:
    """What the lifecycle needs from the joint states, taken in once per gateway tick.

    The CAN driver publishes a JointState every controller cycle (250–500 Hz) for the control
    process, and for the gateway, which is not on the cycle, one StateWindow every
    ``[can] state_window_s`` (and at once when the controller's state changes): how many
    states, the fastest joint speed among them, each joint's lowest and highest position, and
    the newest state. The gateway receives the windows into a zenoh ring channel, so no Python
    runs per message, and folds them in at its tick; the newest state is kept as bytes and
    decoded only when the status asks for it. Every cycle's state still counts.

    Arrival times are not known exactly, so each is bounded on the safe side:

    * ``rx_s``, when the newest valid state arrived, is a lower bound: the later of the
      previous fold (the state was not there yet) and the state's own stamp (the CAN driver
      stamps it before publishing, on the same CLOCK_MONOTONIC). The joint-state age is
      never under-reported, so a stream that stops is seen at the first tick more than
      ``joint_state_timeout_s`` after its last state, as when each state was stamped on arrival.
    * ``moving_s``, the last time the arm was seen moving (or the first state), is an upper
      bound: the time of the fold that saw it. Every state counts, so standstill is never
      over-reported.

    "Moving" is judged as a drive's measurements allow. A measured speed is an encoder
    difference, noisy, and a vendor loop holding on a quantised encoder hunts by a few mrad/s
    without going anywhere; a joint's position is exact to the encoder step. So the arm moves
    when a joint leaves the band of ``standstill_rad_s · standstill_s`` it has kept since the
    last motion (its mean speed over the standstill time is then above ``standstill_rad_s``),
    or when a state shows a joint faster than ``FAST_FACTOR · standstill_rad_s``, which no
    hold's dither reaches. The lifecycle also asks the newest state's speed to be below
    ``standstill_rad_s``: a weightless arm keeps the velocity it has when teaching takes over.
    """

    #: one state faster than this many standstill speeds is a motion, whatever the band says
    FAST_FACTOR = 10.0

    def __init__(self, standstill_rad_s: float, start_s: float, standstill_s: float = 0.3) -> None:
        self.standstill_rad_s = standstill_rad_s
        self.band_rad = standstill_rad_s * standstill_s
        self.fast_rad_s = self.FAST_FACTOR * standstill_rad_s
        self.rx_s: float | None = None
        self.moving_s: float | None = None
        self.controller_state: ControllerState | None = None
        #: since when the drives hold or follow (servo on) without a break, as seen by the
        #: folds (a lower bound on the time the servo has been on); None: servo off
        self.servo_on_s: float | None = None
        self.max_speed_rad_s: float | None = None  #: fastest joint in the newest state
        self._fold_s = start_s
        self._raw: bytes | None = None
        self._state: JointState | None = None
        self._lo: np.ndarray | None = None  #: each joint's lowest position since the motion
        self._hi: np.ndarray | None = None  #: ... and its highest

    def _moved(self, speed: float, lo: np.ndarray, hi: np.ndarray, q: np.ndarray) -> bool:
        """Take in one window (its fastest speed, each joint's lowest and highest position, the
        newest position); True if it shows a motion (and the band restarts at ``q``)."""
        if self._lo is None or self._hi is None or speed > self.fast_rad_s:
            self._lo, self._hi = q.copy(), q.copy()
            return speed > self.fast_rad_s
        np.minimum(self._lo, lo, out=self._lo)
        np.maximum(self._hi, hi, out=self._hi)
        if float(np.max(self._hi - self._lo)) > self.band_rad:
            self._lo, self._hi = q.copy(), q.copy()
            return True
        return False

    @property
    def band_used_rad(self) -> float:
        """The widest joint excursion since the last motion [rad] (0 before the first state)."""
        if self._lo is None or self._hi is None:
            return 0.0
        return float(np.max(self._hi - self._lo))

    def fold(
        self, payloads: Iterable[bytes], start_s: float, end_s: float | None = None
    ) -> list[str]:
        """Take in the StateWindows received since the previous fold, oldest first, taken from
        the channel after ``start_s`` and before ``end_s`` (default: ``start_s``) [s]. Returns
        why windows were ignored, one line per bad one."""
        now_s = start_s if end_s is None else end_s
        since_s, self._fold_s = self._fold_s, max(self._fold_s, start_s)
        problems, newest, moved = [], None, False
        for data in payloads:
            try:
                window = StateWindow.from_bytes(data)
                summary = joint_state_summary(window.newest)
                if summary[3].shape != window.q_lo_rad.shape:
                    raise MessageError("StateWindow: its newest state has another joint count")
            except MessageError as exc:
                problems.append(str(exc))
                continue
            newest = window.newest, summary
            speed = max(window.max_speed_rad_s, summary[2])
            moved = self._moved(speed, window.q_lo_rad, window.q_hi_rad, summary[3]) or moved
        if newest is None:
            return problems
        self._raw, (self.controller_state, stamp_s, self.max_speed_rad_s, _) = newest
        self._state = None
        self.rx_s = max(since_s, min(stamp_s, now_s))
        if moved or self.moving_s is None:
            self.moving_s = now_s
        if self.controller_state not in SERVO_ON:
            self.servo_on_s = None
        elif self.servo_on_s is None:
            self.servo_on_s = now_s
        return problems

    @property
    def state(self) -> JointState | None:
        """The newest valid state, decoded (None before the first)."""
        if self._state is None and self._raw is not None:
            try:
                self._state = JointState.from_bytes(self._raw)
            except MessageError:  # summary and decoder disagree: report no state
                return None
        return self._state
