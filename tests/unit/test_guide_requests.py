"""Constrained guiding from the operator to the law: `leadthrough start --guide` is checked by
the gateway, passed to the control process in the lifecycle while the cell is ready or
teaching (a start while teaching changes it), and the control process sets it on its law; a
name that is not a guide is refused with the names that are, and the guide in force stays."""

from __future__ import annotations

import logging
from pathlib import Path

import pytest
from example_cell import example_cell
from recording_session import RecordingSession

from control.cell_config import load_control_config
from control.process import ControlProcess
from gateway.bus import BusConfig
from gateway.cli import guide_line
from gateway.gateway_config import GatewayConfig
from gateway.messages import Lifecycle, LifecycleMsg, encode_json
from gateway.supervisor import Gateway


def _gateway() -> Gateway:
    gw = Gateway(Path("cell.toml"), BusConfig(), GatewayConfig())
    gw.session = RecordingSession()
    return gw


def _published(gw: Gateway, now: float) -> LifecycleMsg:
    gw._publish_lifecycle(now)
    return LifecycleMsg.from_bytes(gw.session.puts[-1][1])


def test_a_start_naming_no_guide_is_refused_with_the_names_that_are():
    gw = _gateway()
    reply = gw._request(encode_json({"command": "start", "guide": "sideways"}))
    assert not reply["ok"] and "orientation-locked" in reply["message"]
    reply = gw._request(encode_json({"command": "start", "guide": 3}))
    assert not reply["ok"] and "guide 3" in reply["message"]
    assert gw.guide is None


def test_the_guide_goes_to_control_while_ready_or_teaching_and_a_start_there_changes_it():
    gw = _gateway()
    # a start the cell refuses (no links yet) takes no guide
    reply = gw._request(encode_json({"command": "start", "guide": "plane"}))
    assert not reply["ok"] and gw.guide is None
    gw.machine._go(Lifecycle.READY, "started by the test")
    assert "guide" not in _published(gw, 1.0).extra  # none asked for: control's own
    reply = gw._request(encode_json({"command": "start", "guide": "plane"}))
    assert reply["ok"] and reply["message"] == "guide now plane"
    assert _published(gw, 2.0).extra["guide"] == "plane"
    gw.machine._go(Lifecycle.TEACHING, "enabling device held")
    reply = gw._request(encode_json({"command": "start", "guide": "axis"}))
    assert reply["ok"] and _published(gw, 3.0).extra["guide"] == "axis"
    assert reply["guide"]["asked"] == "axis"
    gw.machine._go(Lifecycle.STOPPED, "stop requested by operator")
    assert "guide" not in _published(gw, 4.0).extra


def test_the_control_process_sets_the_lifecycles_guide_on_its_law_or_its_own(tmp_path, caplog):
    cfg, bus = load_control_config(example_cell(tmp_path))
    proc = ControlProcess(cfg, bus)
    assert proc.ctl is not None and proc.ctl.guide == "free"
    proc._apply_guide(LifecycleMsg(Lifecycle.READY, 1, 0.0, "", {"guide": "orientation-locked"}))
    assert proc.ctl.guide == "orientation-locked"
    assert proc._guide_report()["mode"] == "orientation-locked"
    with caplog.at_level(logging.ERROR):
        proc._apply_guide(LifecycleMsg(Lifecycle.TEACHING, 2, 0.1, "", {"guide": "sideways"}))
    assert "guide 'sideways' is not one of" in caplog.text
    assert proc.ctl.guide == "orientation-locked" and proc.stats["bad_messages"] == 1
    proc._apply_guide(LifecycleMsg(Lifecycle.STOPPED, 3, 0.2))  # none named: the config's
    assert proc.ctl.guide == "free"


@pytest.mark.parametrize(
    ("report", "line"),
    [
        (None, ""),
        ({"mode": "free", "deviation_mm": 0.0, "rotation_deg": 0.0}, ""),
        (
            {"mode": "orientation-locked", "deviation_mm": 0.0, "rotation_deg": 0.42},
            "guide: orientation-locked, the tool turned 0.42° from its hold",
        ),
        (
            {"mode": "plane", "deviation_mm": 1.5, "rotation_deg": 0.1},
            "guide: plane, the tool turned 0.1° from its hold, 1.5 mm off its plane",
        ),
    ],
)
def test_status_names_the_guide_held_and_how_far_the_tool_is_from_it(report, line):
    assert guide_line({"asked": None, "control": report}) == line
