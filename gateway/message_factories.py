"""Validated JointStates and JointCommands built from array-likes (for the control process,
benches, tests and simulators); the decoders in gateway/messages.py check what arrives."""

from __future__ import annotations

from typing import Any

import numpy as np

from gateway.errors import MessageError
from gateway.messages import ControllerState, JointCommand, JointState, _finite


def _vec(values: Any, n: int, name: str) -> np.ndarray:
    arr = np.asarray(values, dtype=np.float64).reshape(-1)
    if arr.shape != (n,):
        raise MessageError(f"{name} has {arr.size} values, expected {n}")
    return _finite(name, arr)


def make_joint_state(
    cycle: int,
    stamp_s: float,
    controller_state: ControllerState,
    flags: int,
    q_rad: Any,
    dq_rad_s: Any,
    current_a: Any,
    q_cmd_rad: Any,
    dq_cmd_rad_s: Any,
    cycle_period_s: float = 0.0,
) -> JointState:
    """Build a validated JointState from array-likes (raises MessageError on NaN/shape)."""
    n = len(q_rad)
    return JointState(
        cycle,
        stamp_s,
        ControllerState(controller_state),
        flags,
        _vec(q_rad, n, "q_rad"),
        _vec(dq_rad_s, n, "dq_rad_s"),
        _vec(current_a, n, "current_a"),
        _vec(q_cmd_rad, n, "q_cmd_rad"),
        _vec(dq_cmd_rad_s, n, "dq_cmd_rad_s"),
        float(cycle_period_s),
    )


def make_joint_command(
    cycle: int,
    state_stamp_s: float,
    sent_stamp_s: float,
    q_cmd_rad: Any,
    dq_cmd_rad_s: Any,
    state_rx_stamp_s: float = 0.0,
) -> JointCommand:
    """Build a validated JointCommand (raises MessageError on NaN or mismatched sizes)."""
    n = len(q_cmd_rad)
    return JointCommand(
        cycle,
        state_stamp_s,
        sent_stamp_s,
        _vec(q_cmd_rad, n, "q_cmd_rad"),
        _vec(dq_cmd_rad_s, n, "dq_cmd_rad_s"),
        float(state_rx_stamp_s),
    )
