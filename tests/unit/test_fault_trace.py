"""sim_bridge/fault_trace.py: the table a demo prints when the cell faults, from a truth log."""

from __future__ import annotations

import numpy as np

from sim_bridge.fault_trace import EVERY_ROWS, TRACE_S, fault_trace


def _truth(rows: int, period_s: float = 0.008) -> dict[str, np.ndarray]:
    t = np.arange(rows) * period_s
    truth = {"t_s": t, "teaching": np.ones(rows)}
    # the tool along x at 0.1 m/s, then at 0.3 m/s over the last 10 rows
    v = np.where(np.arange(rows) >= rows - 10, 0.3, 0.1)
    x = np.concatenate([[0.0], np.cumsum(v[1:] * period_s)])
    truth.update(tool_x=x, tool_y=np.zeros(rows), tool_z=np.zeros(rows))
    truth.update(f_x=np.full(rows, 3.0), f_y=np.full(rows, 4.0), f_z=np.zeros(rows))
    for j in range(1, 3):
        truth[f"q{j}"] = np.zeros(rows)
        truth[f"dq{j}"] = np.full(rows, 0.01 * j)
        truth[f"q_ref{j}"] = np.full(rows, 0.002 * j)
    return truth


def test_the_trace_shows_the_last_cycles_the_tools_speed_the_hand_and_each_joints_lead():
    truth = _truth(400)
    text = fault_trace(truth).splitlines()
    assert "fastest tool 300 mm/s" in text[0]
    rows = [line.split() for line in text[2:]]
    times = np.array([float(r[0]) for r in rows])
    # the last TRACE_S of the log, one row per EVERY_ROWS cycles
    assert TRACE_S - EVERY_ROWS * 0.008 < times[-1] - times[0] <= TRACE_S
    assert np.allclose(np.diff(times), EVERY_ROWS * 0.008, atol=1e-3)
    last = rows[-1]
    assert float(last[0]) == np.float64(399 * 0.008).round(3)  # the log's last row is shown
    assert last[1] == "300" and last[2] == "5.0"  # mm/s over the monitor's window, |f| N
    assert last[3:] == ["|", "10", "20", "|", "2.0", "4.0"]  # mrad/s, reference - arm [mrad]
    assert rows[0][1] == "100"


def test_a_log_without_command_cycles_says_so():
    truth = _truth(50)
    truth["teaching"][:] = 0.0
    assert fault_trace(truth) == "truth log: no command cycles to trace"
    assert fault_trace({"t_s": np.zeros(0)}) == "truth log: no command cycles to trace"
