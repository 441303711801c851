"""Read-only checks against the real cell; they run only with LEADTHROUGH_HARDWARE=1.

The cell config comes from LEADTHROUGH_CELL (default deploy/config/cell.toml). Nothing here
commands motion: the tests listen to the controller's cycle and read the I/O module once.
"""

from __future__ import annotations

import os
import time
from pathlib import Path

import can
import pytest

from drivers.can.config import load_can_config
from drivers.modbus.adapter import create_adapter
from drivers.modbus.config import ModbusDriverConfig
from drivers.registry import load_adapter
from gateway.config import load_toml

pytestmark = pytest.mark.hardware

CELL = Path(
    os.environ.get("LEADTHROUGH_CELL", Path(__file__).parents[2] / "deploy/config/cell.toml")
)


def test_the_controller_sends_complete_cycles():
    cfg, _ = load_can_config(CELL)
    adapter = load_adapter("leadthrough.can_adapters", cfg.adapter)(n_joints=cfg.joints)
    bus = can.Bus(**cfg.transport)
    try:
        deadline = time.monotonic() + 2.0
        cycles = []
        while time.monotonic() < deadline and len(cycles) < 3:
            msg = bus.recv(0.1)
            if msg is not None and (fb := adapter.feed(msg)) is not None:
                cycles.append(fb)
        assert len(cycles) == 3, f"no complete controller cycle on {cfg.transport} within 2 s"
        assert all(abs(q) < 8.0 for fb in cycles for q in fb.q_rad)
    finally:
        bus.shutdown()


def test_the_io_module_answers_with_plausible_values():
    adapter = create_adapter(ModbusDriverConfig.from_cell_config(load_toml(CELL), str(CELL)))
    adapter.connect()
    try:
        reading = adapter.read()
    finally:
        adapter.close()
    assert 0.0 <= reading.p2_bar <= 12.0 and 0.0 <= reading.p3_bar <= 12.0
