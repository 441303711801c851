"""Modbus driver on the zenoh bus against the virtual I/O module (in-process transports)."""

from __future__ import annotations

import argparse
import math
import os
import signal
import socket
import subprocess
import sys
import threading
import time
import tomllib
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import pytest
import zenoh

from drivers.modbus.config import ModbusDriverConfig
from drivers.modbus.driver import ModbusDriver, cli_main, configure_parser
from gateway.bus import BusConfig, open_client, open_router
from gateway.errors import EXIT_CONFIG
from gateway.messages import IoState, PressureSetpoint, decode_json
from sim_bridge.modbus_server import VirtualIoServer, sim_modbus_section_toml

REPO = Path(__file__).resolve().parents[2]
WAIT_S = 5.0


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def wait_for(cond: Callable[[], Any], timeout_s: float = WAIT_S, what: str = "condition") -> Any:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if result := cond():
            return result
        time.sleep(0.01)
    raise AssertionError(f"timed out after {timeout_s} s waiting for {what}")


@dataclass
class Bus:
    """The router session, with everything the driver publishes collected."""

    config: BusConfig
    session: zenoh.Session
    io: list[IoState] = field(default_factory=list)
    health: list[dict[str, Any]] = field(default_factory=list)
    lock: threading.Lock = field(default_factory=threading.Lock)

    def io_after(self, t_s: float) -> list[IoState]:
        with self.lock:
            return [s for s in self.io if s.stamp_s > t_s]

    def last_health(self) -> dict[str, Any] | None:
        with self.lock:
            return self.health[-1] if self.health else None

    def publish_setpoint(self, p2_bar: float, p3_bar: float) -> None:
        msg = PressureSetpoint(time.monotonic(), p2_bar, p3_bar)
        self.session.put(self.config.keys.pressure_setpoint, msg.to_bytes())


@pytest.fixture
def bus() -> Iterator[Bus]:
    config = BusConfig(endpoint=f"tcp/127.0.0.1:{free_port()}")
    session = open_router(config)
    b = Bus(config, session)

    def on_io(sample: zenoh.Sample) -> None:
        state = IoState.from_bytes(sample.payload.to_bytes())
        with b.lock:
            b.io.append(state)

    def on_health(sample: zenoh.Sample) -> None:
        msg = decode_json(sample.payload.to_bytes(), "health")
        with b.lock:
            b.health.append(msg)

    subs = [
        session.declare_subscriber(config.keys.io_state, on_io),
        session.declare_subscriber(config.keys.health("modbus_driver"), on_health),
    ]
    try:
        yield b
    finally:
        for s in subs:
            s.undeclare()
        session.close()


@pytest.fixture
def io_server() -> Iterator[VirtualIoServer]:
    srv = VirtualIoServer("127.0.0.1", 0)
    srv.start()
    try:
        yield srv
    finally:
        srv.stop()


def sim_config(port: int) -> ModbusDriverConfig:
    return ModbusDriverConfig.from_cell_config(tomllib.loads(sim_modbus_section_toml(port=port)))


@pytest.fixture
def driver(bus: Bus, io_server: VirtualIoServer) -> Iterator[ModbusDriver]:
    session = open_client(bus.config)
    drv = ModbusDriver(sim_config(io_server.port), session, bus.config.keys)
    drv.RECONNECT_MAX_S = 0.2  # reconnect quickly in tests
    try:
        drv.start()
        yield drv
    finally:
        drv.close()
        session.close()


def test_io_state_carries_the_values_set_on_the_virtual_module(bus, io_server, driver):
    io_server.set_inputs(2.5, 3.25, True, True)
    t0 = time.monotonic()
    state = wait_for(lambda: bus.io_after(t0), what="an IoState")[0]
    assert (state.p2_bar, state.p3_bar) == (2.5, pytest.approx(3.25))
    assert (state.p2_set_bar, state.p3_set_bar) == (0.0, 0.0)
    assert (state.enabling, state.estop_ok) == (True, True)
    assert 0.0 <= time.monotonic() - state.stamp_s < 1.0

    io_server.set_inputs(1.0, 0.5, False, False)
    t1 = time.monotonic()
    state = wait_for(lambda: bus.io_after(t1), what="a new IoState")[0]
    assert (state.p2_bar, state.p3_bar, state.enabling, state.estop_ok) == (1.0, 0.5, False, False)
    stamps = [s.stamp_s for s in bus.io_after(0.0)]
    assert stamps == sorted(stamps)


def test_setpoint_on_the_bus_reaches_the_module_and_is_read_back(bus, io_server, driver):
    def applied() -> bool:
        bus.publish_setpoint(4.2, 5.125)  # until the driver's subscription has propagated
        return io_server.setpoints() == (4.2, 5.125)

    wait_for(applied, what="the set-point at the module")
    t0 = time.monotonic()
    state = wait_for(lambda: bus.io_after(t0), what="an IoState")[0]
    assert (state.p2_set_bar, state.p3_set_bar) == pytest.approx((4.2, 5.125))
    wait_for(lambda: (bus.last_health() or {}).get("setpoints_written", 0) >= 1, what="health")


def test_invalid_setpoints_are_refused_and_the_last_one_is_kept(bus, io_server, driver, caplog):
    def applied() -> bool:
        bus.publish_setpoint(3.0, 2.0)
        return io_server.setpoints() == (3.0, 2.0)

    wait_for(applied, what="the valid set-point")
    time.sleep(0.1)  # let the repeated valid publications drain
    writes = io_server.setpoint_writes
    rejected = driver.setpoints_rejected

    key = bus.config.keys.pressure_setpoint
    bus.publish_setpoint(10.5, 1.0)  # above max_setpoint_bar = 10
    bus.publish_setpoint(1.0, -0.1)
    bus.session.put(key, PressureSetpoint(time.monotonic(), math.nan, 1.0).to_bytes())
    bus.session.put(key, PressureSetpoint(time.monotonic(), 1.0, math.inf).to_bytes())
    bus.session.put(key, b"not a set-point")
    wait_for(lambda: driver.setpoints_rejected >= rejected + 5, what="five refusals")
    time.sleep(0.1)  # several polls: nothing may be written, and nothing ramps down
    assert io_server.setpoints() == (3.0, 2.0)
    assert io_server.setpoint_writes == writes
    refusals = [r.getMessage() for r in caplog.records if "set-point refused" in r.getMessage()]
    assert refusals and "p2_set_bar=10.5 bar outside 0..10 bar" in refusals[0]
    wait_for(
        lambda: (bus.last_health() or {}).get("setpoints_rejected", 0) >= rejected + 5,
        what="health counting the refusals",
    )


def test_stopped_module_silences_io_state_and_reconnect_restores_it(bus, io_server, driver):
    def applied() -> bool:
        bus.publish_setpoint(2.0, 2.5)
        return io_server.setpoints() == (2.0, 2.5)

    wait_for(applied, what="the set-point")
    port = io_server.port
    io_server.stop()
    t_stop = time.monotonic()
    health = wait_for(
        lambda: (h := bus.last_health()) and not h["link_ok"] and h["stamp_s"] > t_stop and h,
        what="health reporting the link down",
    )
    assert health["errors"] >= 1 and health["last_error"]
    time.sleep(0.3)
    assert bus.io_after(t_stop) == [], "IoState published while the module was down"

    # The module comes back (power-cycled: its set-points are 0) on the same port.
    with VirtualIoServer("127.0.0.1", port) as again:
        again.set_inputs(1.25, 1.0, True, True)
        t_back = time.monotonic()
        state = wait_for(lambda: bus.io_after(t_back), what="IoState after reconnect")[0]
        assert state.p2_bar == 1.25
        # the last set-point is written again rather than letting the cylinders vent
        wait_for(lambda: again.setpoints() == (2.0, 2.5), what="set-point rewritten")
        wait_for(lambda: (h := bus.last_health()) and h["link_ok"], what="health link up")


def test_implausible_reply_is_reported_and_nothing_published(bus, io_server, driver, caplog):
    io_server.set_inputs(2.0, 2.0, True, True)
    wait_for(lambda: bus.io_after(time.monotonic() - 0.05), what="a first IoState")

    io_server.set_inputs(math.nan, 2.0, True, True)  # float32 NaN bits in input registers 0-1
    t_bad = time.monotonic()
    wait_for(lambda: "p2_bar" in driver.last_error, what="the NaN error")
    assert "0x7FC0" in driver.last_error and "nan" in driver.last_error
    wait_for(
        lambda: any("p2_bar" in r.getMessage() for r in caplog.records if r.levelname == "ERROR"),
        what="the error logged",
    )

    io_server.set_inputs(2.0, 70.0, True, True)  # 70 bar saturates the uint16 mbar register
    wait_for(lambda: "p3_bar" in driver.last_error, what="the range error")
    assert "outside the plausible range" in driver.last_error
    health = wait_for(
        lambda: (h := bus.last_health()) and "p3_bar" in h["last_error"] and h, what="health"
    )
    assert health["link_ok"] is False
    t_good = time.monotonic()
    assert bus.io_after(t_bad) == [], "IoState published from an implausible reply"

    io_server.set_inputs(2.0, 2.0, True, True)
    state = wait_for(lambda: bus.io_after(t_good), what="IoState once the reply is sane")[0]
    assert state.p3_bar == pytest.approx(2.0)


# Command line ------------------------------------------------------------------------------


def test_help_is_readable():
    text = configure_parser(argparse.ArgumentParser(prog="modbus-driver")).format_help()
    assert "--config CELL.toml" in text and "--bus ENDPOINT" in text and "SIGTERM" in text


def test_bad_config_exits_with_ex_config(tmp_path, caplog):
    cfg = tmp_path / "cell.toml"
    cfg.write_text(sim_modbus_section_toml(port=70000))
    args = configure_parser(argparse.ArgumentParser()).parse_args(["--config", str(cfg)])
    assert cli_main(args) == EXIT_CONFIG
    assert "[modbus].port: 70000" in caplog.text


def test_process_publishes_and_exits_cleanly_on_sigterm(bus, io_server, tmp_path):
    cfg = tmp_path / "cell.toml"
    cfg.write_text(
        f'[bus]\nendpoint = "{bus.config.endpoint}"\n\n'
        + sim_modbus_section_toml(port=io_server.port)
    )
    io_server.set_inputs(3.5, 1.0, True, True)
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    env.pop("LEADTHROUGH_BUS_ENDPOINT", None)
    proc = subprocess.Popen(
        [sys.executable, "-m", "drivers.modbus.driver", "--config", str(cfg)],
        cwd=REPO,
        env=env,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
    )
    try:
        t0 = time.monotonic()
        state = wait_for(lambda: bus.io_after(t0), timeout_s=10.0, what="IoState from the process")[
            0
        ]
        assert state.p2_bar == 3.5
        proc.send_signal(signal.SIGTERM)
        out, _ = proc.communicate(timeout=5.0)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
    assert proc.returncode == 0, out.decode(errors="replace")
    assert b"modbus_driver stopped" in out
