"""The CiA 402 adapter's cycle (drivers/can/cia402.py) on hand-made frames, without a bus: a
cycle is complete only with every drive's two TPDOs after a SYNC; units; a corrupt or missing
PDO drops its cycle; a drive's late heartbeat and a drive that leaves operation enabled on its
own fault the controller, latched until a fault reset; RPDOs carry the controlword of the step
towards the request and refuse what int32 cannot carry."""

from __future__ import annotations

import math
import struct

import can
import numpy as np
import pytest

from drivers.can.adapter import HostRequest
from drivers.can.cia402 import HOST_DISABLE_CYCLES, Cia402Adapter, _Joint, _Pdo
from drivers.can.config import Cia402Config
from gateway.errors import FrameError
from gateway.messages import ControllerState

N = 2
GEAR = (100.0, 50.0)
RATED_A = (10.0, 2.0)
INC = 1 << 20
SW_OPERATION_ENABLED, SW_SWITCH_ON_DISABLED, SW_FAULT = 0x0237, 0x0250, 0x0218
SW_SWITCHED_ON = 0x0233


class Clock:
    t = 0.0

    def __call__(self) -> float:
        return self.t


@pytest.fixture
def rig():
    cfg = Cia402Config(eds="drive.eds", gear_ratio=GEAR, rated_current_a=RATED_A,
                       encoder_increments=INC, producer_heartbeat_s=0.05)  # fmt: skip
    clock = Clock()
    adapter = Cia402Adapter(N, cfg, clock=clock)
    joints = []
    for k in range(N):
        nid = k + 1
        joints.append(_Joint(
            node_id=nid,
            inc_per_rad=INC * GEAR[k] / (2 * math.pi),
            amps_per_mille=RATED_A[k] / 1000.0,
            rpdo1=_Pdo(0x200 + nid, struct.Struct("<Hi"), (0x6040, 0x607A)),
            rpdo2=_Pdo(0x300 + nid, struct.Struct("<i"), (0x60B1,)),
            tpdo1=_Pdo(0x180 + nid, struct.Struct("<Hi"), (0x6041, 0x6064)),
            tpdo2=_Pdo(0x280 + nid, struct.Struct("<ihh"), (0x606C, 0x6078, 0x6077)),
        ))  # fmt: skip
    adapter._attach(joints)
    return adapter, clock


def _frame(cob: int, data: bytes) -> can.Message:
    return can.Message(arbitration_id=cob, data=data, is_extended_id=False)


def _cycle(adapter, statuswords=(SW_OPERATION_ENABLED,) * N, q=(0.1, -0.2), current=(500, -250)):
    """SYNC, then each drive's TPDO1 and TPDO2; the feedback the last one completes."""
    assert [f.arbitration_id for f in adapter.clock_frames()] == [0x080]
    out = []
    for k in range(N):
        inc = round(q[k] * INC * GEAR[k] / (2 * math.pi))
        out.append(adapter.feed(_frame(0x181 + k, struct.pack("<Hi", statuswords[k], inc))))
        out.append(adapter.feed(_frame(0x281 + k, struct.pack("<ihh", 0, current[k], 0))))
    assert all(o is None for o in out[:-1])
    return out[-1]


def test_a_cycle_needs_every_drive_and_converts_the_units(rig):
    adapter, _ = rig
    fb = _cycle(adapter)
    assert fb is not None and fb.counter == 1
    np.testing.assert_allclose(fb.q_rad, [0.1, -0.2], atol=1e-7)
    np.testing.assert_allclose(fb.current_a, [5.0, -0.5])  # per mille of the rated current
    assert fb.controller_state == ControllerState.EXTERNAL and fb.servo_power
    assert _cycle(adapter).counter == 2


def test_a_short_pdo_drops_its_cycle_and_a_sync_before_all_answers_counts_incomplete(rig):
    adapter, _ = rig
    adapter.clock_frames()
    adapter.feed(_frame(0x181, b"\x37\x02\x00"))  # 3 bytes of a 6-byte TPDO1
    for k in range(N):
        adapter.feed(_frame(0x181 + k, struct.pack("<Hi", SW_OPERATION_ENABLED, 0)))
    fb = None
    for k in range(N):
        fb = adapter.feed(_frame(0x281 + k, struct.pack("<ihh", 0, 0, 0)))
    assert fb is None and adapter.stats.corrupt_cycles == 1 and adapter.stats.bad_frames == 1
    adapter.clock_frames()
    adapter.feed(_frame(0x181, struct.pack("<Hi", SW_OPERATION_ENABLED, 0)))
    adapter.clock_frames()  # drive 2 never answered the last SYNC
    assert adapter.stats.incomplete_cycles == 1
    assert adapter.feed(_frame(0x7FF, b"")) is None and adapter.stats.unknown_frames == 1


def test_a_drive_whose_heartbeat_stops_faults_the_controller(rig):
    adapter, clock = rig
    for k in range(N):
        adapter.feed(_frame(0x701 + k, bytes([0x05])))
    clock.t = 0.14  # under 3 periods of 50 ms
    assert _cycle(adapter).controller_state == ControllerState.EXTERNAL
    adapter.feed(_frame(0x701, bytes([0x05])))
    clock.t = 0.16  # drive 2's last heartbeat 0.16 s ago
    fb = _cycle(adapter)
    assert fb.controller_state == ControllerState.FAULT and "J2 heartbeat lost" in fb.fault
    adapter.feed(_frame(0x701, bytes([0x7F])))  # drive 1 in pre-operational
    assert "J1 NMT state 0x7F" in _cycle(adapter).fault


def test_a_drive_that_stops_on_its_own_is_latched_until_a_fault_reset(rig):
    adapter, _ = rig
    adapter.request_frames(HostRequest.SERVO_ON)
    assert _cycle(adapter).controller_state == ControllerState.EXTERNAL
    fb = _cycle(adapter, statuswords=(SW_OPERATION_ENABLED, SW_SWITCH_ON_DISABLED))
    assert fb.controller_state == ControllerState.FAULT
    assert "J2 left operation enabled on its own (switch on disabled)" in fb.fault

    def controlwords(frames):
        return [struct.unpack("<Hi", f.data)[0] for f in frames if f.arbitration_id < 0x300]

    # SERVO_ON again: drive 2 gets no shutdown→switch on walk, drive 1 is switched off (5)
    assert controlwords(adapter.request_frames(HostRequest.SERVO_ON)) == [0x07, 0x06]
    fb = _cycle(adapter, statuswords=(SW_OPERATION_ENABLED, SW_SWITCH_ON_DISABLED))
    assert fb.controller_state == ControllerState.FAULT
    adapter.request_frames(HostRequest.RESET_FAULT)  # the operator's reset clears the latch
    fb = _cycle(adapter, statuswords=(SW_SWITCH_ON_DISABLED, SW_SWITCH_ON_DISABLED))
    assert fb.controller_state == ControllerState.BRAKED and fb.fault == "NONE"
    assert controlwords(adapter.request_frames(HostRequest.SERVO_ON)) == [0x06, 0x06]  # 2


def test_a_stop_and_a_start_within_a_cycle_are_no_drop_out(rig):
    """The drives' answer to a BRAKE that arrives after the next SERVO_ON (an operator's stop
    and start within a cycle) is obeying the host, not dropping out (HOST_DISABLE_CYCLES); a
    drop-out once those cycles have passed still latches."""
    adapter, _ = rig
    adapter.request_frames(HostRequest.SERVO_ON)
    assert _cycle(adapter).controller_state == ControllerState.EXTERNAL
    adapter.request_frames(HostRequest.BRAKE)
    adapter.request_frames(HostRequest.SERVO_ON)
    assert _cycle(adapter).controller_state == ControllerState.EXTERNAL  # BRAKE not acted on yet
    fb = _cycle(adapter, statuswords=(SW_SWITCHED_ON,) * N)  # ... now
    assert (fb.controller_state, fb.fault) == (ControllerState.BRAKED, "NONE")
    for _ in range(HOST_DISABLE_CYCLES):
        assert _cycle(adapter).controller_state == ControllerState.EXTERNAL
    fb = _cycle(adapter, statuswords=(SW_OPERATION_ENABLED, SW_SWITCH_ON_DISABLED))
    assert fb.controller_state == ControllerState.FAULT
    assert "J2 left operation enabled on its own (switch on disabled)" in fb.fault


def test_a_drive_fault_is_reported_and_reset_by_a_rising_fault_reset(rig):
    adapter, _ = rig
    adapter.feed(_frame(0x082, bytes([0x11, 0x86, 0, 0, 0, 0, 0, 0])))  # EMCY 0x8611
    fb = _cycle(adapter, statuswords=(SW_OPERATION_ENABLED, SW_FAULT))
    assert fb.controller_state == ControllerState.FAULT and "J2 fault EMCY 0x8611" in fb.fault
    frames = adapter.request_frames(HostRequest.RESET_FAULT)
    assert struct.unpack("<Hi", frames[1].data)[0] == 0x80


def test_commands_carry_the_targets_in_increments_and_refuse_what_int32_cannot(rig):
    adapter, _ = rig
    _cycle(adapter)
    adapter.request_frames(HostRequest.SERVO_ON)
    frames = adapter.command_frames(1, np.array([0.1, -0.2]), np.array([0.5, 0.5]), hold=True)
    assert [f.arbitration_id for f in frames] == [0x201, 0x301, 0x202, 0x302]
    cw, target = struct.unpack("<Hi", frames[0].data)
    assert cw == 0x0F and target == round(0.1 * INC * GEAR[0] / (2 * math.pi))
    assert struct.unpack("<i", frames[1].data)[0] == 0  # hold: no velocity
    with pytest.raises(FrameError, match=r"J1: command 1000 rad, 0 rad/s does not fit int32"):
        adapter.command_frames(1, np.array([1e3, 0.0]), np.zeros(2), hold=False)
    with pytest.raises(FrameError, match=r"J1: command nan rad"):
        adapter.command_frames(1, np.array([math.nan, 0.0]), np.zeros(2), hold=False)
