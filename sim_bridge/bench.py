"""`leadthrough bench`: wire-to-wire latency of the control loop on the virtual cell.

Latency is measured by the virtual controller itself: from the moment it starts sending the
feedback frames of cycle k to the moment the complete command set answering cycle k (computed by
the control process, not a driver hold) has arrived back on its CAN endpoint. The path covers
CAN transport → CAN driver → zenoh → control → zenoh → CAN driver → CAN transport.
A cycle is missed when no computed command set for it arrived before the next cycle began.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from sim_bridge.harness import Stack


def run_rate(rate_hz: float, cycles: int, workdir: Path) -> dict:
    period = 1.0 / rate_hz
    overrides = {
        "controller": {"cycle_period_s": period},
        "operator": {"enabling_after_s": 0.0, "mode": "none"},
    }
    error = None
    with Stack(workdir, sim_overrides=overrides) as stack:
        stack.start()
        try:
            stack.start_teaching()
        except (TimeoutError, RuntimeError) as exc:  # the loop cannot even start at this rate
            error = f"teaching did not start: {exc}"
        else:
            t_end = time.monotonic() + cycles * period * 1.05 + 1.0
            while time.monotonic() < t_end:
                stack.check_alive()
                time.sleep(0.5)
        stack.request("stop")
    truth = stack.truth()
    summary = json.loads(stack.sim_summary.read_text())
    lat = truth["latency_s"]
    lat = lat[np.isfinite(lat)][:cycles] * 1e3

    def pct(p: float) -> float | None:
        return float(np.percentile(lat, p)) if lat.size else None

    return {
        "rate_hz": rate_hz,
        "cycles_measured": int(lat.size),
        "p50_ms": pct(50),
        "p99_ms": pct(99),
        "max_ms": pct(100),
        "missed_cycles": int(summary["teaching_missed_cycles"]),
        "teaching_cycles": int(summary["teaching_cycles"]),
        "faults": summary["faults"],
        "error": error,
    }


def configure_parser(p: argparse.ArgumentParser) -> None:
    p.description = (
        "Benchmark the loop's wire-to-wire latency (feedback frame leaving the virtual "
        "controller → command frame computed from it arriving back) at each rate."
    )
    p.add_argument("--rates", type=float, nargs="+", default=[250.0, 500.0], help="[Hz]")
    p.add_argument("--cycles", type=int, default=10000, help="cycles per rate (≥ 10000)")
    p.add_argument("--out", type=Path, default=Path("bench_out"), help="output folder")


def cli_main(args: argparse.Namespace) -> int:
    results = []
    for rate in args.rates:
        print(f"running {args.cycles} cycles at {rate:.0f} Hz ...", flush=True)
        results.append(run_rate(rate, args.cycles, args.out / f"{rate:.0f}hz"))
    print(f"\n{'rate':>8} {'cycles':>8} {'p50 ms':>8} {'p99 ms':>8} {'max ms':>8} {'missed':>8}")
    for r in results:
        ms = [f"{r[k]:>8.3f}" if r[k] is not None else f"{'-':>8}" for k in ("p50_ms", "p99_ms",
                                                                            "max_ms")]  # fmt: skip
        print(f"{r['rate_hz']:>6.0f}Hz {r['cycles_measured']:>8d} {' '.join(ms)} "
              f"{r['missed_cycles']:>8d}")  # fmt: skip
    for r in results:
        for problem in ([r["error"]] if r["error"] else []) + r["faults"]:
            print(f"{r['rate_hz']:>6.0f}Hz: {problem}")
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "bench.json").write_text(json.dumps(results, indent=2))
    return 0
