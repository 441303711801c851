"""LTC-1 seen from the host: the adapter (:class:`LtcAdapter`, registry name ``ltc_dbc``) over
:class:`~drivers.can.ltc_protocol.LtcProtocol`, and the adapter helpers both profiles share.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import can
import numpy as np

from drivers.can.adapter import CanAdapter, CycleFeedback, HostRequest
from drivers.can.ltc_frames import ControllerStatus, JointFeedback, NmtState
from drivers.can.ltc_protocol import DEFAULT_DBC_PATH, LtcProtocol
from gateway.errors import FrameError

__all__ = ["LtcAdapter"]


def cycle_feedback(
    status: ControllerStatus,
    q_rad: Sequence[float],
    dq_rad_s: Sequence[float],
    current_a: Sequence[float],
) -> CycleFeedback:
    """The adapter contract's CycleFeedback from a decoded status and the joints' values (both
    profiles)."""
    return CycleFeedback(
        counter=status.cycle_counter,
        q_rad=np.array(q_rad),
        dq_rad_s=np.array(dq_rad_s),
        current_a=np.array(current_a),
        controller_state=status.state,
        estop_active=status.estop_active,
        servo_power=status.servo_power,
        fault=status.fault_code.name,
        cycle_period_s=status.cycle_period_us * 1e-6,
        status=status,
    )


def command_arrays(
    q_cmd_rad: Any, dq_cmd_rad_s: Any, n_joints: int, what: str
) -> tuple[np.ndarray, np.ndarray]:
    """Position and velocity commands as flat float arrays of ``n_joints`` each, or FrameError
    naming ``what`` (the frame or set being built)."""
    q = np.asarray(q_cmd_rad, dtype=float).reshape(-1)
    dq = np.asarray(dq_cmd_rad_s, dtype=float).reshape(-1)
    if q.shape != (n_joints,) or dq.shape != (n_joints,):
        raise FrameError(
            f"{what} needs {n_joints} positions and velocities, got {q.size} and {dq.size}"
        )
    return q, dq


class LtcAdapter(CanAdapter):
    """LTC-1 seen from the host: cycle assembly, command sets, requests and heartbeats.

    A cycle is complete when CTRL_STATUS arrives and every configured joint's JOINT_FB frame
    since the previous CTRL_STATUS carries the status's counter low byte. Any bad frame among
    the controller's per-cycle frames (or a bus error frame) drops the whole cycle: a cycle is
    either entirely valid or not reported at all.
    """

    name = "ltc_dbc"
    counter_modulus = 1 << 16  # CTRL_STATUS.cycle_counter is 16 bits
    host_heartbeat_timeout_s = 0.5  # DBC comment on HEARTBEAT_HOST
    max_joints = 6

    def __init__(self, n_joints: int = 6, dbc_path: str | Path = DEFAULT_DBC_PATH) -> None:
        super().__init__(n_joints)
        self.protocol = LtcProtocol(n_joints, dbc_path)
        self._fb: list[JointFeedback | None] = [None] * n_joints
        self._tainted = ""  #: why the cycle being assembled is already lost ("" = it is not)
        self._request_counter = 0

    def feed(self, msg: can.Message) -> CycleFeedback | None:
        stats = self.stats
        stats.frames += 1
        try:
            frame = self.protocol.decode(msg)
        except FrameError as exc:
            stats.bad_frames += 1
            stats.last_error = str(exc)
            if msg.arbitration_id == self.protocol.status_id and not msg.is_error_frame:
                # The status that would close this cycle is lost: so is the cycle.
                self._fb, self._tainted = [None] * self.n_joints, ""
                stats.corrupt_cycles += 1
            elif msg.is_error_frame or self.is_cycle_frame(msg):
                self._tainted = str(exc)
            return None
        if frame is None:
            stats.unknown_frames += 1
            return None
        if isinstance(frame, JointFeedback):
            if frame.joint <= self.n_joints:  # a bigger arm's extra joints are not ours
                self._fb[frame.joint - 1] = frame
            return None
        if isinstance(frame, ControllerStatus):
            return self._close_cycle(frame)
        return None  # heartbeats; other hosts' commands

    def _close_cycle(self, status: ControllerStatus) -> CycleFeedback | None:
        fb, tainted = self._fb, self._tainted
        self._fb, self._tainted = [None] * self.n_joints, ""
        stats = self.stats
        if tainted:
            stats.corrupt_cycles += 1
            stats.last_error = f"cycle {status.cycle_counter} dropped: {tainted}"
            return None
        low = status.cycle_counter & 0xFF
        missing = [k + 1 for k, f in enumerate(fb) if f is None or f.counter != low]
        if missing:
            stats.incomplete_cycles += 1
            stats.last_error = (
                f"cycle {status.cycle_counter} dropped: no JOINT_FB with counter {low} "
                f"for joint(s) {missing}"
            )
            return None
        stats.cycles += 1
        frames: list[JointFeedback] = fb  # type: ignore[assignment]  # none missing
        return cycle_feedback(
            status,
            [f.q_rad for f in frames],
            [f.dq_rad_s for f in frames],
            [f.current_a for f in frames],
        )

    def command_frames(
        self, counter: int, q_cmd_rad: np.ndarray, dq_cmd_rad_s: np.ndarray, hold: bool
    ) -> list[can.Message]:
        q, dq = command_arrays(q_cmd_rad, dq_cmd_rad_s, self.n_joints, "JOINT_CMD set")
        low = int(counter) & 0xFF
        hold_bit = bool(hold)
        q_list, dq_list = q.tolist(), dq.tolist()
        return [
            self.protocol.encode_command(k + 1, q_list[k], dq_list[k], hold_bit, low)
            for k in range(self.n_joints)
        ]

    def request_frames(self, request: HostRequest) -> list[can.Message]:
        msg = self.protocol.encode_request(request, self._request_counter)
        self._request_counter = (self._request_counter + 1) & 0xFF
        return [msg]

    def heartbeat_frame(self) -> can.Message:
        return self.protocol.encode_heartbeat("HOST", NmtState.OPERATIONAL)

    def is_cycle_frame(self, msg: can.Message) -> bool:
        return msg.arbitration_id in self.protocol.cycle_frame_ids
