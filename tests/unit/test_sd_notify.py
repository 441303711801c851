"""systemd notifications (gateway/sd_notify.py) on a datagram socket standing in for systemd's."""

from __future__ import annotations

import os
import socket

import pytest

from gateway.sd_notify import Notifier


@pytest.fixture
def systemd_socket(tmp_path):
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    path = str(tmp_path / "notify")
    sock.bind(path)
    sock.settimeout(2.0)
    yield path, sock
    sock.close()


def test_ready_status_watchdog_and_stopping_reach_systemd(systemd_socket):
    path, sock = systemd_socket
    n = Notifier({"NOTIFY_SOCKET": path, "WATCHDOG_USEC": "2000000"})
    assert n.watchdog_period_s == pytest.approx(1.0)
    assert n.ready("serving")
    assert sock.recv(256) == b"READY=1\nSTATUS=serving"
    assert n.watchdog(10.0)
    assert sock.recv(256) == b"WATCHDOG=1"
    assert not n.watchdog(10.5), "pinged again before half the interval"
    assert n.watchdog(11.0)
    assert sock.recv(256) == b"WATCHDOG=1"
    assert n.stopping()
    assert sock.recv(256) == b"STOPPING=1"


def test_outside_systemd_nothing_is_sent():
    n = Notifier({})
    assert n.address is None and n.watchdog_period_s is None
    assert not n.ready() and not n.watchdog(0.0) and not n.stopping()


def test_a_watchdog_meant_for_another_process_is_not_pinged(systemd_socket):
    path, _ = systemd_socket
    n = Notifier({"NOTIFY_SOCKET": path, "WATCHDOG_USEC": "1000000", "WATCHDOG_PID": "1"})
    assert n.watchdog_period_s is None or os.getpid() == 1


def test_a_socket_that_is_gone_is_a_warning_not_a_crash(tmp_path, caplog):
    n = Notifier({"NOTIFY_SOCKET": str(tmp_path / "nobody")})
    assert not n.ready()
    assert "sd_notify READY=1 failed" in caplog.text
