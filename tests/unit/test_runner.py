"""The one process runner (gateway/runner.py): exit statuses, close on every path, signals,
systemd's notifications, and the four product processes going through it."""

from __future__ import annotations

import argparse
import logging
import os
import signal
import socket
import threading
from pathlib import Path

import pytest

from gateway.errors import EXIT_CONFIG, ConfigError, LinkTimeoutError
from gateway.runner import EXIT_FAILED, run_service


class Process:
    """A service that records what the runner did to it; ``fail`` names the step that raises
    and ``error`` what it raises."""

    def __init__(self, fail: str = "", error: BaseException | None = None) -> None:
        self.stop_event = threading.Event()
        self.fail, self.error = fail, error or RuntimeError("boom")
        self.calls: list[str] = []

    def _step(self, name: str) -> None:
        self.calls.append(name)
        if self.fail == name:
            raise self.error

    def open(self) -> None:
        self._step("open")

    def run(self, notifier) -> None:
        self._step("run")
        self.stop_event.wait(10.0)

    def close(self) -> None:
        self._step("close")


def test_a_refused_config_exits_78_before_anything_opens(caplog):
    def build():
        raise ConfigError("cell.toml [can] deadline_s: expected a number, got 'soon'")

    assert run_service("can_driver", build) == EXIT_CONFIG
    assert "can_driver: configuration refused: cell.toml [can] deadline_s" in caplog.text


@pytest.mark.parametrize(
    ("fail", "error", "status"),
    [
        ("open", ConfigError("drive 2: 0x6091 gear ratio 147/1, config 153/1"), EXIT_CONFIG),
        ("open", LinkTimeoutError("no zenoh router at tcp/127.0.0.1:7460"), EXIT_FAILED),
        ("run", RuntimeError("loop thread died"), EXIT_FAILED),
    ],
)
def test_every_failure_closes_the_service_and_names_the_process(caplog, fail, error, status):
    process = Process(fail, error)
    assert run_service("control", lambda: process) == status
    assert process.calls[-1] == "close"  # the CAN driver's close is what brakes the arm
    assert f"control: configuration refused: {error}" in caplog.text or (
        "control failed: " in caplog.text and str(error) in caplog.text
    )
    # a bug gets its traceback, an expected failure one line
    tracebacks = [r for r in caplog.records if r.exc_info]
    assert bool(tracebacks) == (type(error) is RuntimeError)


def test_a_failing_close_is_logged_and_keeps_the_status(caplog):
    process = Process("close", OSError("bus already gone"))
    process.stop_event.set()
    assert run_service("modbus_driver", lambda: process) == 0
    assert "modbus_driver: closing failed: OSError: bus already gone" in caplog.text


def test_sigterm_stops_the_service_cleanly():
    process = Process()
    before = signal.getsignal(signal.SIGTERM)
    timer = threading.Timer(0.2, os.kill, (os.getpid(), signal.SIGTERM))
    timer.start()
    try:
        assert run_service("gateway", lambda: process) == 0
    finally:
        timer.cancel()
    assert process.calls == ["open", "run", "close"]
    assert signal.getsignal(signal.SIGTERM) is before  # the handler is put back


def test_the_gateway_tells_systemd_ready_and_stopping(tmp_path, monkeypatch):
    address = str(tmp_path / "notify")
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    sock.bind(address)
    sock.settimeout(2.0)
    monkeypatch.setenv("NOTIFY_SOCKET", address)
    monkeypatch.delenv("WATCHDOG_USEC", raising=False)
    try:
        process = Process()
        process.stop_event.set()
        status = run_service("gateway", lambda: process, notify=True, status=lambda p: "serving")
        assert status == 0
        assert sock.recv(256) == b"READY=1\nSTATUS=serving"
        assert sock.recv(256) == b"STOPPING=1"
        # a child (notify=False) leaves systemd alone
        child = Process()
        child.stop_event.set()
        assert run_service("control", lambda: child) == 0
        sock.settimeout(0.1)
        with pytest.raises(TimeoutError):
            sock.recv(256)
    finally:
        sock.close()


PROCESSES = {
    "gateway": "gateway.supervisor",
    "can-driver": "drivers.can.driver",
    "modbus-driver": "drivers.modbus.driver",
    "control": "control.process",
}


@pytest.mark.parametrize("name", sorted(PROCESSES))
def test_each_product_process_refuses_a_bad_config_with_78(name, tmp_path, caplog):
    import importlib

    module = importlib.import_module(PROCESSES[name])
    parser = argparse.ArgumentParser(prog=f"leadthrough {name}")
    module.configure_parser(parser)
    bad = tmp_path / "cell.toml"
    bad.write_text('[bus]\nendpoint = "tcp/127.0.0.1:7460"\n[bsu]\nkey_prefix = "lt"\n')
    with caplog.at_level(logging.ERROR):
        assert module.cli_main(parser.parse_args(["--config", str(bad)])) == EXIT_CONFIG
    assert "bsu" in caplog.text, caplog.text
    assert Path(bad).name in caplog.text


def test_the_process_is_placed_once_built_and_before_it_opens_a_link():
    """[realtime] is applied between build and open: the threads open starts inherit the
    cycle's priority, and the building (models, laws) does not run at it."""
    process = Process("none", RuntimeError("unused"))
    calls = process.calls

    def build():
        calls.append("build")
        return process

    process.stop_event.set()
    assert run_service("control", build, place=lambda: calls.append("place")) == 0
    assert calls[:3] == ["build", "place", "open"]
