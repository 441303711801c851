"""The let-go campaign: a hand pushes the tool for 2 s once the admittance's engagement probe is
over, then lets go; how far the arm moves 2-4 s after the push ended, over many runs and pushes
up to the hand-guiding speed limit. One run is the stack test
``tests/stack/test_admittance_stack.py::test_a_push_moves_the_tool_along_it_and_the_arm_stops_when_the_hand_lets_go``;
a run-on that happens once in ten or twenty let-gos (docs/results/teaching.md) needs this
many-run count to be seen at all. Judged from the simulator's truth log, every run counted:

    python -m sim_bridge.letgo --forces 20 40 60 --runs 10 [--plant-seed 0] [--control JSON]
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

from sim_bridge.commission import commissioned_stack
from sim_bridge.faults import tool_xyz

#: the engagement probe's length ([control] admittance_probe_s) and the time its joints take
#: to stick after it [s]: the hand pushes after it, as a painter waits for it
PROBE_S = 0.8 + 0.3
#: the push's length [s]; the arm's motion is measured from AFTER_S to AFTER_S + 2 s after its end
PUSH_S, AFTER_S = 2.0, 2.0
#: the arm "ran on" when the tool moved this far in those 2 s [m] (the stack test's bound)
RAN_ON_M = 1e-3


def judge(truth: dict[str, np.ndarray], force_n: float) -> dict[str, Any]:
    """One run's figures from its truth log: the tool's travel along the push in the push
    [m], its peak speed [m/s] and its motion 2-4 s after the push ended [m]."""
    rows = np.flatnonzero(truth["teaching"] > 0.5)
    if not rows.size:
        raise ValueError("the robot never followed the control process's commands")
    t = truth["t_s"][rows] - truth["t_s"][rows[0]] - PROBE_S
    end = PUSH_S + AFTER_S + 2.0
    if t[-1] < end:
        raise ValueError(f"the truth log holds {t[-1]:.1f} s after the probe, not {end:.1f} s")
    at = {s: rows[t <= s][-1] for s in (0.0, PUSH_S + 0.1, PUSH_S + AFTER_S, end)}
    every = tool_xyz(truth)
    push = every[at[PUSH_S + 0.1]] - every[at[0.0]]
    after = every[at[end]] - every[at[PUSH_S + AFTER_S]]
    xyz, ts = every[rows], truth["t_s"][rows]
    speed = np.linalg.norm(xyz[5:] - xyz[:-5], axis=1) / (ts[5:] - ts[:-5])
    return {
        "force_n": force_n,
        "push_m": push.tolist(),
        "travel_m": float(push[1]),
        "peak_m_s": float(speed.max()),
        "after_m": float(np.linalg.norm(after)),
        "ran_on": bool(np.linalg.norm(after) >= RAN_ON_M),
    }


def run(force_n: float, workdir: Path, plant_seed: int, control: dict[str, Any]) -> dict[str, Any]:
    """One let-go on a fresh stack of ``plant_seed`` with the admittance (and ``control``);
    :func:`judge`'s figures and ``phases``, the engagement phases the operator's status
    showed until the probe was over."""
    operator = {"mode": "force", "force_n": [0.0, force_n, 0.0], "start_s": PROBE_S,
                "duration_s": PUSH_S}  # fmt: skip
    cell = {"control": {"strategy": "admittance", **control}}
    with commissioned_stack(
        workdir, plant_seed=plant_seed, sim_overrides={"operator": operator}, cell_overrides=cell
    ) as stack:
        stack.start()
        stack.start_teaching()
        phases: list[str | None] = []
        while len(phases) < 40 and (not phases or phases[-1] != "following"):
            engagement = stack.request("status").get("engagement") or {}
            phases.append(engagement.get("phase"))
            time.sleep(0.05)
        truth = stack.wait_teaching(PROBE_S + PUSH_S + AFTER_S + 2.1, 40.0)
        stack.request("stop")
    return {**judge(truth, force_n), "phases": phases}


def table(records: list[dict[str, Any]]) -> list[str]:
    """Per push: runs, runs that ran on, the largest motion after the let-go, the travel."""
    lines = ["  push N   runs   ran on   after max mm   travel mm   peak mm/s"]
    for f in sorted({r["force_n"] for r in records}):
        rs = [r for r in records if r["force_n"] == f]
        travel = [r["travel_m"] * 1e3 for r in rs]
        lines.append(
            f"{f:8.0f} {len(rs):6d} {sum(r['ran_on'] for r in rs):8d} "
            f"{max(r['after_m'] for r in rs) * 1e3:14.2f} "
            f"{min(travel):5.0f}-{max(travel):<5.0f} {max(r['peak_m_s'] for r in rs) * 1e3:11.0f}"
        )
    return lines


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m sim_bridge.letgo", description=__doc__)
    ap.add_argument("--forces", type=float, nargs="+", default=[20.0, 40.0, 60.0])
    ap.add_argument("--runs", type=int, default=10)
    ap.add_argument("--plant-seed", type=int, default=0)
    ap.add_argument("--control", default="{}", help="[control] overrides, JSON")
    ap.add_argument("--json", type=Path, help="write every run's record here")
    args = ap.parse_args(argv)
    if args.runs < 1 or any(not 0 < f <= 200 for f in args.forces):
        ap.error("--runs must be >= 1 and each force in (0, 200] N")
    try:
        control = json.loads(args.control)
    except json.JSONDecodeError as e:
        ap.error(f"--control is not JSON: {e}")
    if not isinstance(control, dict):
        ap.error("--control must be a JSON object of [control] keys")
    records = []
    for force in args.forces:
        for k in range(args.runs):
            with tempfile.TemporaryDirectory(prefix="letgo-") as d:
                rec = run(force, Path(d), args.plant_seed, control)
            print(f"{force:.0f} N run {k + 1}: travel {rec['travel_m'] * 1e3:.0f} mm, peak "
                  f"{rec['peak_m_s'] * 1e3:.0f} mm/s, after the let-go "
                  f"{rec['after_m'] * 1e3:.2f} mm", flush=True)  # fmt: skip
            records.append(rec)
    print("\n".join(table(records)))
    if args.json:
        args.json.write_text(json.dumps(records, indent=1))
    return 1 if any(r["ran_on"] for r in records) else 0


if __name__ == "__main__":
    sys.exit(main())
