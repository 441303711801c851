"""The virtual controller's servo follows a command set ``command_delay_cycles`` after it is
accepted, as a real controller that reads the joints at one cycle boundary and applies the
host's answer at a later one (issue 22)."""

from __future__ import annotations

import numpy as np
import pytest

from drivers.can.adapter import HostRequest
from gateway.errors import ConfigError
from gateway.messages import ControllerState
from sim_bridge.config import ControllerSpec
from sim_bridge.controller import VirtualController, controller_protocol

N = 2
LOWER, UPPER = np.full(N, -3.0), np.full(N, 3.0)
PERIOD = 0.004


def _controller(delay: int) -> VirtualController:
    spec = ControllerSpec(cycle_period_s=PERIOD, command_delay_cycles=delay)
    ctrl = VirtualController(spec, controller_protocol(spec, N), LOWER, UPPER)
    ctrl.on_frame(ctrl.proto.encode_heartbeat("HOST"), wall_s=0.0)
    ctrl.on_frame(ctrl.proto.encode_request(HostRequest.SERVO_ON, 0), wall_s=0.0)
    ctrl.begin_cycle(0.0, np.zeros(N), wall_s=0.0)
    assert ctrl.state == ControllerState.HOLD
    return ctrl


def _send(ctrl: VirtualController, q: float, dq: float) -> None:
    for joint in range(1, N + 1):
        msg = ctrl.proto.encode_command(joint, q, dq, False, ctrl.cycle & 0xFF)
        ctrl.on_frame(msg, wall_s=0.0)


@pytest.mark.parametrize("delay", [0, 1, 3])
def test_a_set_reaches_the_servo_after_the_configured_cycles(delay):
    ctrl = _controller(delay)
    refs = []
    for k in range(1, 8):
        t = k * PERIOD
        _send(ctrl, 0.001 * k, 0.25)  # a ramp: 1 mrad per cycle at 0.25 rad/s
        ctrl.on_frame(ctrl.proto.encode_heartbeat("HOST"), wall_s=0.0)
        ctrl.begin_cycle(t, np.full(N, 0.001 * (k - 1)), wall_s=0.0)
        assert ctrl.state == ControllerState.EXTERNAL, ctrl.stats.faults
        refs.append(float(ctrl.reference(t)[0][0]))
    # the set sent in cycle k is followed from cycle k + delay on
    for k in range(1 + delay, 8):
        assert refs[k - 1] == pytest.approx(0.001 * (k - delay))
    for k in range(1, 1 + delay):
        assert refs[k - 1] == 0.0  # still holding where servo-on found the arm


def test_a_missed_cycle_freezes_in_its_turn():
    ctrl = _controller(1)
    _send(ctrl, 0.01, 0.5)
    ctrl.begin_cycle(PERIOD, np.zeros(N), wall_s=0.0)  # accepted; the servo still holds
    assert ctrl.reference(PERIOD)[1][0] == 0.0
    ctrl.begin_cycle(2 * PERIOD, np.zeros(N), wall_s=0.0)  # missed; the set reaches the servo
    assert ctrl.stats.missed_cycles == 1
    q, dq = ctrl.reference(2 * PERIOD + 0.002)
    assert dq[0] == 0.5 and q[0] == pytest.approx(0.011)
    ctrl.begin_cycle(3 * PERIOD, np.zeros(N), wall_s=0.0)  # the miss reaches it: frozen
    q, dq = ctrl.reference(3 * PERIOD + 0.002)
    assert dq[0] == 0.0 and q[0] == pytest.approx(0.01 + 0.5 * PERIOD)


def test_the_delay_is_checked():
    with pytest.raises(ConfigError, match="command_delay_cycles"):
        ControllerSpec(command_delay_cycles=-1)
