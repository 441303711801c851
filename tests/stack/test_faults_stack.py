"""The fault campaign (sim_bridge/faults.py, `make faults`) on the whole stack: one of its
faults, as `make faults` runs it, so the campaign's own code is exercised by `make test`.

A control process that hangs (SIGSTOP) sends no more commands while its zenoh session and
process stay up: the CAN driver coasts, then holds, and after [can]
lost_cycles_max_consecutive lost cycles trips (drivers/can/lost_cycles.py): the cell faults
naming the command link. The default, 50 cycles (0.4 s), races the gateway's 0.5 s health
watchdog; the test sets 13 (0.1 s) so that the driver's rule is what faults the cell."""

from __future__ import annotations

from sim_bridge.faults import BY_NAME, format_record, run_fault


def test_a_hung_control_process_trips_the_lost_cycle_rule_and_the_arm_stops(tmp_path):
    rec = run_fault(
        BY_NAME["hang_control"],
        tmp_path,
        cell_overrides={"can": {"lost_cycles_max_consecutive": 13}},
    )
    print(format_record(rec))
    assert rec["speed_m_s"] > 0.08, "the arm was not moving at the fault: nothing was tested"
    assert rec["pass"], rec["checks"]
    assert "command link" in rec["reason"], rec["reason"]
