"""The product's CiA 402 adapter (drivers/can/cia402.py) against the virtual cell's CiA 402
drives (sim_bridge/cia402_drives.py, written separately from the standard) on a real in-process
CAN segment: start-up by NMT and SDO, the state machine walked 2-3-4 by the controlword in the
RPDOs, a cycle per SYNC, commands followed, BRAKE by transition 5, the host's heartbeat lost
(the drives quick-stop through 0x6007 within the consumer heartbeat time) and a fault reset;
and a drive whose units differ from the cell config refused at start."""

from __future__ import annotations

import dataclasses
import time

import can
import numpy as np
import pytest
from cia402_rig import cia402_cell

from drivers.can.adapter import HostRequest
from drivers.can.cia402 import Cia402Adapter
from drivers.can.config import load_can_config
from gateway.errors import ConfigError
from gateway.messages import ControllerState
from sim_bridge.harness import REPO, SIM_CELL_CIA402

SYNC_PERIOD_S = 0.008


@pytest.fixture
def cell():
    with cia402_cell(SYNC_PERIOD_S) as vc:
        yield vc


@pytest.fixture
def bus(cell):
    b = can.Bus(interface="seqpacket", channel=cell.cfg.endpoints.can_channel,
                connect_timeout_s=5.0)  # fmt: skip
    try:
        yield b
    finally:
        b.shutdown()


def _config(**cia402):
    cfg, _ = load_can_config(SIM_CELL_CIA402)
    return dataclasses.replace(cfg, cia402=dataclasses.replace(cfg.cia402, **cia402))


class Host:
    """The CAN driver's cycle, reduced: SYNC, the drives' answers, then our frames."""

    def __init__(self, adapter: Cia402Adapter, bus: can.BusABC) -> None:
        self.adapter, self.bus = adapter, bus
        self.heartbeat = True
        self.fb = None
        self._next_s = time.monotonic()

    def cycle(self, frames: list[can.Message] | None = None) -> None:
        """One cycle at SYNC_PERIOD_S of wall time (the drives watch the heartbeat in it)."""
        self._next_s += SYNC_PERIOD_S
        time.sleep(max(self._next_s - time.monotonic(), 0.0))
        if self.heartbeat:
            self.bus.send(self.adapter.heartbeat_frame())
        for frame in frames or []:
            self.bus.send(frame)
        for frame in self.adapter.clock_frames():
            self.bus.send(frame)
        deadline = time.monotonic() + 1.0
        while time.monotonic() < deadline:
            msg = self.bus.recv(0.1)
            if msg is not None and (fb := self.adapter.feed(msg)) is not None:
                self.fb = fb
                return
        raise AssertionError("no complete cycle within 1 s of a SYNC")

    def until(self, done, what: str, frames=lambda: [], cycles: int = 40) -> None:
        for _ in range(cycles):
            self.cycle(frames())
            if done(self.fb):
                return
        raise AssertionError(f"no {what} in {cycles} cycles: {self.fb.status} {self.fb.fault}")


#: the drives' heartbeats come from the cell's thread in this process on wall time, as a real
#: drive's do, and the adapter calls a drive lost 0.15 s after its last (3 × 0x1017): niced
#: beside the stack tier and a referee, this process once went 0.16-0.18 s without the CPU
#: (tests/run_suite.py)
@pytest.mark.deadline
def test_the_adapter_starts_enables_commands_brakes_and_loses_the_drives(cell, bus):
    adapter = Cia402Adapter.from_config(_config(cycle_period_s=SYNC_PERIOD_S))
    adapter.start(bus)
    host = Host(adapter, bus)
    host.cycle()
    assert host.fb.controller_state == ControllerState.BRAKED and not host.fb.servo_power
    q0 = host.fb.q_rad.copy()
    # units: the drives' increments back in joint radians (the plant's truth, to encoder noise)
    np.testing.assert_allclose(q0, cell.plant.q_rad, atol=2e-4)
    # SERVO_ON: the controlword walks 2, 3, 4; requests never move the setpoint
    host.until(
        lambda fb: fb.controller_state == ControllerState.EXTERNAL,
        "operation enabled",
        frames=lambda: adapter.request_frames(HostRequest.SERVO_ON),
        cycles=10,
    )
    assert host.fb.servo_power and set(host.fb.status.values()) == {"operation enabled"}
    # commands: J1 and J6 move 0.05 rad at 0.1 rad/s and stop there
    target = q0.copy()
    for k in range(80):
        step = min((k + 1) * 0.1 * SYNC_PERIOD_S, 0.05)
        q = q0 + np.array([step, 0, 0, 0, 0, step])
        dq = np.where(np.array([1, 0, 0, 0, 0, 1]) & (step < 0.05), 0.1, 0.0)
        host.cycle(adapter.command_frames(host.fb.counter, q, dq, False))
        target = q
    # the drives' loops leave a static error under load (J4 about 2.5 mrad here)
    host.until(lambda fb: np.abs(fb.q_rad - target).max() < 5e-3, "the arm at its command",
               frames=lambda: adapter.command_frames(0, target, np.zeros(6), True))  # fmt: skip
    assert abs(host.fb.q_rad[0] - q0[0] - 0.05) < 2e-3 and abs(host.fb.q_rad[1] - q0[1]) < 2e-3
    # BRAKE: transition 5, the drives switched on with the brakes, not a fault
    host.until(
        lambda fb: fb.controller_state == ControllerState.BRAKED,
        "the drives out of operation",
        frames=lambda: adapter.request_frames(HostRequest.BRAKE),
        cycles=10,
    )
    assert not host.fb.servo_power and host.fb.fault == "NONE"
    # enabled again, then the host's heartbeat stops: 0x6007 = 3, a quick stop
    host.until(lambda fb: fb.controller_state == ControllerState.EXTERNAL, "operation enabled",
               frames=lambda: adapter.request_frames(HostRequest.SERVO_ON), cycles=10)  # fmt: skip
    host.heartbeat = False
    cycles_to_stop = 0
    while host.fb.controller_state != ControllerState.FAULT:
        host.cycle(adapter.command_frames(host.fb.counter, target, np.zeros(6), True))
        cycles_to_stop += 1
        assert cycles_to_stop < 40, "no quick stop within 0.3 s of the host's last heartbeat"
    # consumer heartbeat time 0.1 s = 12.5 cycles of 8 ms (+ the heartbeat's own period)
    assert cycles_to_stop * SYNC_PERIOD_S <= adapter.config.consumer_heartbeat_s + 0.03
    assert "left operation enabled on its own" in host.fb.fault, host.fb.fault
    # the drives stopped on their own: SERVO_ON does not enable them again (latched) ...
    host.heartbeat = True
    for _ in range(20):
        host.cycle(adapter.request_frames(HostRequest.SERVO_ON))
        assert host.fb.controller_state == ControllerState.FAULT and not host.fb.servo_power
    assert "operation enabled" not in host.fb.status.values()
    # ... until the operator's reset
    host.cycle(adapter.request_frames(HostRequest.RESET_FAULT))
    host.cycle(adapter.request_frames(HostRequest.BRAKE))
    assert host.fb.controller_state == ControllerState.BRAKED, host.fb.fault
    host.until(lambda fb: fb.controller_state == ControllerState.EXTERNAL,
               "operation enabled after the quick stop",
               frames=lambda: adapter.request_frames(HostRequest.SERVO_ON), cycles=10)  # fmt: skip
    host.until(lambda fb: fb.controller_state == ControllerState.BRAKED, "brake on exit",
               frames=lambda: adapter.request_frames(HostRequest.BRAKE), cycles=10)  # fmt: skip
    assert adapter.stats.cycles > 100 and adapter.stats.bad_frames == 0


def test_a_drive_whose_gear_ratio_differs_from_the_config_is_refused_at_start(cell, bus):
    wrong = list(_config().cia402.gear_ratio)
    wrong[2] = 150.0
    adapter = Cia402Adapter.from_config(_config(gear_ratio=tuple(wrong)))
    with pytest.raises(ConfigError, match=r"node 3 \(J3\): 0x6091 gear ratio is 153 .* 150"):
        adapter.start(bus)


def test_the_startup_sdo_writes_reach_every_drive_and_one_it_cannot_take_fails_the_start(cell, bus):
    def averaging() -> list[int]:
        return [d.read(0x2010) for d in cell.ctrl.drives]

    Cia402Adapter.from_config(_config(startup_sdo=())).start(bus)
    assert averaging() == [0] * 6, "nothing written without the list"
    for entry, refusal in (
        (
            (0x2011, 0, 1),
            r"node 1 \(J1\): \[can.cia402\].startup_sdo 0x2011 sub 0 = 1: the "
            r"drive's EDS has no such object",
        ),
        ((0x2010, 3, 1), r"0x2010 sub 3 = 1: the drive's EDS has no such object"),
        ((0x2010, 0, 2), r"0x2010 sub 0 = 2: the drive refused it: .*0x06090030"),
        ((0x2010, 0, 300), r"0x2010 sub 0 = 300: not a value of the object's type"),
    ):
        with pytest.raises(ConfigError, match=refusal):
            Cia402Adapter.from_config(_config(startup_sdo=(entry,))).start(bus)
    assert averaging() == [0] * 6
    Cia402Adapter.from_config(_config(startup_sdo=((0x2010, 0, 1),))).start(bus)
    assert averaging() == [1] * 6


def test_the_cia402_cell_config_names_a_shipped_eds():
    cfg, _ = load_can_config(SIM_CELL_CIA402)
    assert cfg.adapter == "cia402"
    assert (REPO / "deploy" / "cia402" / "leadthrough_drive.eds").samefile(cfg.cia402.eds)
