"""The CiA 402 adapter's hand-over to the compiled cycle (drivers/can/rt_cia402_tables.py,
rt_cia402.py): the golden vectors the Rust test replays
(drivers/can/rt/tests/data/cia402_golden.json) are what the Python adapter answers today; the
tables are JSON and carry the floats exactly; the layouts configured without a bus are the ones
a real start-up against the virtual cell's drives maps."""

from __future__ import annotations

import json
import math
import threading
import time

import can
import pytest

from drivers.can.cia402 import Cia402Adapter
from drivers.can.config import Cia402Config, load_can_config
from drivers.can.rt_cia402 import EDS_PATH, GOLDEN_PATH, dumps, golden_vectors
from drivers.can.rt_cia402_tables import (
    TABLES_FORMAT,
    cia402_tables,
    configure_statically,
    tables_from_config,
)
from sim_bridge.cia402_drive_set import Cia402DriveSet
from sim_bridge.cia402_parameters import AxisParameters, DriveLimits
from sim_bridge.harness import SIM_CELL_CIA402


def test_the_committed_golden_vectors_are_what_the_python_adapter_answers_today():
    fresh = dumps(golden_vectors())
    assert fresh == GOLDEN_PATH.read_text(), (
        "drivers/can/cia402.py answers otherwise than the Rust cycle was tested against: "
        "regenerate (python -m drivers.can.rt_cia402 --golden "
        "drivers/can/rt/tests/data/cia402_golden.json), review the diff, and run "
        "`cargo test -p leadthrough-can-rt cia402`"
    )
    golden = json.loads(fresh)
    ops = {step["op"] for s in golden["scenarios"] for step in s["steps"]}
    assert ops == {"clock", "feed", "command", "request", "heartbeat", "is_cycle_frame"}
    faults = {
        step["feedback"]["fault"].split(" ", 1)[1]
        for s in golden["scenarios"]
        for step in s["steps"]
        if step["op"] == "feed" and step["feedback"] and step["feedback"]["fault"] != "NONE"
    }
    for reason in ("left operation", "fault", "quick stop", "NMT state", "heartbeat lost"):
        assert any(f.startswith(reason) for f in faults), reason


def test_a_cells_tables_are_json_and_carry_every_float_exactly():
    can_cfg, _ = load_can_config(SIM_CELL_CIA402)
    tables = tables_from_config(can_cfg)
    assert json.loads(json.dumps(tables, allow_nan=False)) == tables
    assert tables["format"] == TABLES_FORMAT and tables["n_joints"] == can_cfg.joints == 6
    cfg = can_cfg.cia402
    assert float(tables["clock_period_s"]) == cfg.cycle_period_s
    for k, j in enumerate(tables["joints"]):
        want = cfg.encoder_increments * cfg.gear_ratio[k] / (2.0 * math.pi)
        assert float(j["inc_per_rad"]) == want  # repr() round-trips exactly
        assert j["node_id"] == cfg.node_ids[k]
        assert (j["rpdo1"]["cob_id"], j["tpdo2"]["cob_id"]) == (0x200 + k + 1, 0x280 + k + 1)
        assert (j["rpdo1"]["format"], j["rpdo2"]["format"]) == ("<Hl", "<l")
        assert (j["tpdo1"]["format"], j["tpdo2"]["format"]) == ("<Hl", "<lhh")
        assert j["rpdo2"]["objects"] == [0x60B1]  # csp: the velocity offset


def test_an_adapter_without_drives_has_no_tables():
    cfg = Cia402Config(eds=str(EDS_PATH), gear_ratio=(100.0,), rated_current_a=(2.0,))
    with pytest.raises(ValueError, match="knows 0 of 1 drives"):
        cia402_tables(Cia402Adapter(1, cfg))


def test_the_layouts_configured_without_a_bus_are_those_of_a_real_start_up():
    """Cia402Adapter.start against the virtual cell's drives (sim_bridge/cia402_drives.py) on
    an in-process python-can bus: NMT, SDO, PDO maps, then the same tables."""
    gear, amps = (100.0, 50.5, 147.0), (10.0, 2.0, 21.0)
    cfg = Cia402Config(eds=str(EDS_PATH), gear_ratio=gear, rated_current_a=amps,
                       node_ids=(3, 4, 5), mode="csv")  # fmt: skip
    axes = [AxisParameters.for_joint(g, a, 1.0, 20) for g, a in zip(gear, amps, strict=True)]
    channel = f"rt-cia402-{id(cfg)}"
    host = can.Bus(interface="virtual", channel=channel)
    cell = can.Bus(interface="virtual", channel=channel)
    drives = Cia402DriveSet(axes, DriveLimits(), cell.send, lambda: 0.0, first_node_id=3)
    stop = threading.Event()

    def serve() -> None:
        while not stop.is_set():
            if (msg := cell.recv(0.01)) is not None:
                drives.on_frame(msg, time.monotonic())

    thread = threading.Thread(target=serve, name="cia402-drives")
    thread.start()
    started = Cia402Adapter(3, cfg)
    try:
        drives.power_on()
        started.start(host)
    finally:
        stop.set()
        thread.join()
        host.shutdown()
        cell.shutdown()
    assert cia402_tables(started) == cia402_tables(configure_statically(Cia402Adapter(3, cfg)))
    assert cia402_tables(started)["joints"][0]["rpdo2"]["objects"] == [0x60FF]  # csv
