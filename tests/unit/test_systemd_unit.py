"""The systemd unit (deploy/systemd/leadthrough-gateway.service) matches what the gateway does:
it notifies readiness and pings the watchdog, a refused configuration's exit status stops the
restarts, and the CAN bitrate is set with the link down (a restart finds can0 up)."""

from __future__ import annotations

import shutil
import subprocess
from pathlib import Path

import pytest

from gateway.config import load_toml
from gateway.errors import EXIT_CONFIG
from gateway.realtime import realtime_config_from

UNIT = Path(__file__).resolve().parents[2] / "deploy" / "systemd" / "leadthrough-gateway.service"


def _service_settings() -> list[tuple[str, str]]:
    section, out = None, []
    for raw in UNIT.read_text().splitlines():
        line = raw.strip()
        if not line or line.startswith("#"):
            continue
        if line.startswith("["):
            section = line
            continue
        if section == "[Service]":
            key, _, value = line.partition("=")
            out.append((key, value))
    return out


def test_the_unit_notifies_watches_and_does_not_restart_a_refused_config():
    settings = _service_settings()
    one = dict(settings)
    assert one["Type"] == "notify" and float(one["WatchdogSec"]) > 0
    assert one["RestartPreventExitStatus"] == str(EXIT_CONFIG)
    assert one["Restart"] == "on-failure"


def test_the_unit_grants_what_the_cell_configs_realtime_section_asks_for():
    one = dict(_service_settings())
    cell = load_toml(UNIT.parents[1] / "config" / "cell.toml")
    rt = realtime_config_from(cell, "cell.toml")
    assert rt.sched_fifo_priority <= int(one.get("LimitRTPRIO", "0"))
    assert not rt.mlockall or one.get("LimitMEMLOCK") == "infinity"


def test_the_can_bitrate_is_set_with_the_link_down():
    pre = [v for k, v in _service_settings() if k == "ExecStartPre"]
    down = next(i for i, v in enumerate(pre) if v.endswith("link set can0 down"))
    rate = next(i for i, v in enumerate(pre) if "bitrate" in v)
    up = next(i for i, v in enumerate(pre) if v.endswith("link set can0 up"))
    assert down < rate < up
    assert "restart-ms" in pre[rate], "no bus-off recovery"


@pytest.mark.skipif(shutil.which("systemd-analyze") is None, reason="no systemd-analyze here")
def test_systemd_accepts_the_unit():
    run = subprocess.run(
        ["systemd-analyze", "verify", str(UNIT)], capture_output=True, text=True, timeout=60
    )
    # only the installation paths of this machine may be missing
    problems = [
        line
        for line in (run.stdout + run.stderr).splitlines()
        if line.strip() and "is not executable" not in line and "No such file" not in line
    ]
    assert not problems, problems
