"""ModbusDriver poll logic with an injected clock and a scripted adapter (no bus, no sockets)."""

from __future__ import annotations

import itertools
import logging
import math
import tomllib
from types import SimpleNamespace

import pytest

from drivers.modbus.adapter import IoReading, PressureIoAdapter
from drivers.modbus.client import ModbusLinkError, ModbusTimeoutError
from drivers.modbus.config import ModbusDriverConfig
from drivers.modbus.driver import ModbusDriver
from gateway.errors import ModbusReplyError
from gateway.messages import Keys, PressureSetpoint
from sim_bridge.modbus_server import sim_modbus_section_toml

GOOD = IoReading(2.0, 3.0, 1.0, 1.5, True, True)


class FakeClock:
    def __init__(self) -> None:
        self.t = 100.0

    def __call__(self) -> float:
        return self.t


class ScriptedAdapter(PressureIoAdapter):
    """Connects and reads according to flags the test flips; records every call."""

    def __init__(self) -> None:
        self.up = True
        self.read_error: Exception | None = None
        self.calls: list[tuple] = []

    def connect(self) -> None:
        self.calls.append(("connect",))
        if not self.up:
            raise ModbusLinkError("connect failed (refused)")

    def read(self) -> IoReading:
        self.calls.append(("read",))
        if not self.up:
            raise ModbusTimeoutError("no reply")
        if self.read_error is not None:
            raise self.read_error
        return GOOD

    def write_setpoints(self, p2_bar: float, p3_bar: float) -> None:
        self.calls.append(("write", p2_bar, p3_bar))
        if not self.up:
            raise ModbusLinkError("connection lost")

    def close(self) -> None:
        self.calls.append(("close",))

    def count(self, name: str) -> int:
        return sum(1 for c in self.calls if c[0] == name)

    def writes(self) -> list[tuple]:
        return [c[1:] for c in self.calls if c[0] == "write"]


@pytest.fixture
def clock() -> FakeClock:
    return FakeClock()


@pytest.fixture
def adapter() -> ScriptedAdapter:
    return ScriptedAdapter()


@pytest.fixture
def driver(clock: FakeClock, adapter: ScriptedAdapter) -> ModbusDriver:
    cell = tomllib.loads(sim_modbus_section_toml(port=5020))
    config = ModbusDriverConfig.from_cell_config(cell)
    # No session: step() runs without zenoh publishers (nothing declared).
    return ModbusDriver(config, session=None, keys=Keys(), adapter=adapter, clock=clock)  # type: ignore[arg-type]


def setpoint_sample(p2: float, p3: float) -> SimpleNamespace:
    payload = PressureSetpoint(0.0, p2, p3).to_bytes()
    return SimpleNamespace(payload=SimpleNamespace(to_bytes=lambda: payload))


def test_a_good_poll_is_stamped_with_the_clock_before_the_read(driver, clock):
    state = driver.step()
    assert state is not None
    assert state.stamp_s == clock.t
    assert (state.p2_bar, state.enabling) == (2.0, True)
    assert driver.link_ok and driver.polls == 1 and driver.errors == 0


def test_reconnect_backs_off_exponentially_and_resets_after_a_good_poll(driver, clock, adapter):
    adapter.up = False
    attempts_at = []
    for _ in range(800):  # 8 s of 10 ms steps
        before = adapter.count("connect")
        assert driver.step() is None
        if adapter.count("connect") > before:
            attempts_at.append(round(clock.t - 100.0, 2))
        clock.t += 0.01
    gaps = [round(b - a, 2) for a, b in itertools.pairwise(attempts_at)]
    assert gaps[:6] == [0.1, 0.2, 0.4, 0.8, 1.6, 2.0]
    assert max(gaps) == pytest.approx(driver.RECONNECT_MAX_S, abs=0.011)
    assert not driver.link_ok and "cannot connect" in driver.last_error

    adapter.up = True
    while driver.step() is None:
        clock.t += 0.01
    assert driver.link_ok
    adapter.up = False
    connects = adapter.count("connect")
    driver.step()  # the link of a healthy module drops: the next poll reconnects at once
    clock.t += 0.01
    driver.step()
    assert adapter.count("connect") == connects + 1
    t_fail = clock.t  # ... and, failing, backs off from the minimum again
    while adapter.count("connect") == connects + 1:
        clock.t += 0.01
        driver.step()
    assert clock.t - t_fail == pytest.approx(driver.RECONNECT_MIN_S, abs=0.011)


def test_one_late_reply_of_a_healthy_module_costs_one_poll(driver, clock, adapter):
    """A single timed-out read reconnects at the next poll, so the readers' I/O timeout
    (0.25 s) outlasts it; a module that stays silent still backs off."""
    assert driver.step() is not None
    adapter.read_error = ModbusTimeoutError("no reply within 0.1 s")
    assert driver.step() is None
    adapter.read_error = None
    clock.t += 0.02
    assert driver.step() is not None, "the poll after one late reply did not reconnect"
    assert adapter.count("connect") == 2


def test_decode_error_publishes_nothing_but_keeps_the_connection(driver, adapter):
    adapter.read_error = ModbusReplyError("point 'p2_bar': raw registers [0x7FC0, 0x0000] nan")
    assert driver.step() is None
    assert driver.step() is None
    assert adapter.count("connect") == 1 and adapter.count("close") == 0
    assert driver.errors == 2 and "p2_bar" in driver.last_error and not driver.link_ok
    adapter.read_error = None
    assert driver.step() is not None and driver.link_ok


def test_errors_are_logged_rate_limited(driver, clock, adapter, caplog):
    adapter.read_error = ModbusReplyError("point 'p3_bar' implausible")
    with caplog.at_level(logging.ERROR, logger="drivers.modbus.driver"):
        for _ in range(100):  # 2 s of failing polls
            driver.step()
            clock.t += 0.02
        assert len(caplog.records) == 1
        clock.t += driver.ERROR_LOG_PERIOD_S
        driver.step()
    assert len(caplog.records) == 2
    assert "similar in the last" in caplog.records[1].getMessage()
    assert driver.errors == 101


def test_setpoints_go_through_the_mailbox_newest_wins_and_the_last_is_kept(driver, adapter):
    driver._on_setpoint(setpoint_sample(1.0, 1.0))
    driver._on_setpoint(setpoint_sample(2.0, 2.5))  # replaces the untaken one
    driver.step()
    driver.step()
    driver.step()
    assert adapter.writes() == [(2.0, 2.5)]  # written once, then kept: no ramp-down
    assert driver.setpoints_written == 1


def test_invalid_setpoints_never_reach_the_mailbox(driver, adapter):
    limit = driver.config.max_setpoint_bar
    assert driver.check_setpoint(0.0, limit) is None
    assert "p3_set_bar" in driver.check_setpoint(1.0, limit + 0.01)
    assert "not finite" in driver.check_setpoint(math.inf, 1.0)
    driver._on_setpoint(setpoint_sample(1.0, 1.0))
    driver._on_setpoint(setpoint_sample(-0.5, 1.0))  # refused: keeps the valid one queued
    driver._on_setpoint(setpoint_sample(math.nan, 1.0))
    driver._on_setpoint(SimpleNamespace(payload=SimpleNamespace(to_bytes=lambda: b"junk")))
    driver.step()
    assert adapter.writes() == [(1.0, 1.0)]
    assert driver.setpoints_rejected == 3


def test_setpoint_survives_a_link_loss_and_is_rewritten_after_reconnect(driver, clock, adapter):
    driver._on_setpoint(setpoint_sample(3.0, 4.0))
    driver.step()
    adapter.up = False
    driver.step()
    driver._on_setpoint(setpoint_sample(5.0, 6.0))  # arrives while the link is down
    adapter.up = True
    clock.t += 1.0
    driver.step()  # reconnect, write the pending one
    clock.t += 1.0
    adapter.up = False
    driver.step()  # link drops again; the module power-cycles
    adapter.up = True
    clock.t += 1.0
    driver.step()  # reconnect: the last written set-point is written again
    assert adapter.writes() == [(3.0, 4.0), (5.0, 6.0), (5.0, 6.0)]


def test_health_has_the_documented_fields(driver, clock):
    driver.step()
    health = driver.health()
    assert health == {
        "process": "modbus_driver",
        "stamp_s": clock.t,
        "link_ok": True,
        "polls": 1,
        "errors": 0,
        "last_error": "",
        "setpoints_written": 0,
        "setpoints_rejected": 0,
    }
