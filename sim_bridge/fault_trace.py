"""What the arm did just before a cell faulted in a run on the virtual cell: a short table from the
simulator's truth log, printed beside the fault's reason so that a fault seen once (in CI, where
the run's folder is gone when the log is read) can be traced from the log alone.

The rows are the last :data:`TRACE_S` of the log's command cycles (teaching or replay), every
:data:`EVERY_ROWS`-th: the time since those cycles began, the tool's speed over the speed
monitor's window (drivers/can/rt/src/speed_monitor.rs: three cycles), the hand's force, and per
joint the measured speed and how far the controller's reference led the arm.
"""

from __future__ import annotations

import numpy as np

#: the trace covers this much of the log's last command cycles [s]
TRACE_S = 0.8
#: one row of the table per this many rows of the log (the log has one per controller cycle)
EVERY_ROWS = 4
#: the tool's speed is measured over this many cycles, as the CAN driver's speed monitor does
SPEED_WINDOW = 3


def fault_trace(truth: dict[str, np.ndarray]) -> str:
    """The table of the module docs for ``truth`` (the simulator's truth log as columns); a
    sentence saying so when the log holds no command cycle."""
    rows = np.flatnonzero(truth.get("teaching", np.zeros(0)) > 0.5)
    if rows.size <= SPEED_WINDOW:
        return "truth log: no command cycles to trace"
    n = sum(1 for name in truth if name.startswith("dq"))
    t = truth["t_s"][rows]
    tool = np.stack([truth[f"tool_{a}"][rows] for a in "xyz"], axis=1)
    force = np.linalg.norm(np.stack([truth[f"f_{a}"][rows] for a in "xyz"], axis=1), axis=1)
    w = SPEED_WINDOW
    speed = np.full(t.size, np.nan)
    span = t[w:] - t[:-w]
    with np.errstate(divide="ignore", invalid="ignore"):
        speed[w:] = np.linalg.norm(tool[w:] - tool[:-w], axis=1) / span
    dq = np.stack([truth[f"dq{j + 1}"][rows] for j in range(n)], axis=1)
    lead = np.stack([truth[f"q_ref{j + 1}"][rows] - truth[f"q{j + 1}"][rows] for j in range(n)], 1)
    shown = np.flatnonzero(t >= t[-1] - TRACE_S)[::-1][::EVERY_ROWS][::-1]
    peak = int(np.nanargmax(speed))
    lines = [
        f"the last {TRACE_S:.1f} s of command cycles (truth log; fastest tool "
        f"{speed[peak] * 1e3:.0f} mm/s at {t[peak] - t[0]:.2f} s):",
        "   t [s] tool [mm/s] hand [N] | joint speed [mrad/s] | reference ahead of arm [mrad]",
    ]
    for i in shown:
        lines.append(
            f"{t[i] - t[0]:8.3f} {speed[i] * 1e3:11.0f} {force[i]:8.1f} |"
            + "".join(f"{v * 1e3 + 0.0:6.0f}" for v in dq[i])
            + " |"
            + "".join(f"{v * 1e3 + 0.0:6.1f}" for v in lead[i])
        )
    return "\n".join(lines)
