"""`python -m sim_bridge.bench_loop_cli`: the command line of :mod:`control.bench_loop`, which by
default times the control process on the virtual cell (plant seed 0's commissioned model)."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from control.bench_loop import run


def _virtual_cell() -> Path:
    """The virtual cell's config with plant seed 0's commissioned model, in a temp folder."""
    import tempfile

    import tomli_w

    from gateway.config import load_toml
    from sim_bridge.commission import commissioned
    from sim_bridge.harness import SIM_CELL

    done = commissioned(0)
    raw = load_toml(SIM_CELL)
    raw["control"].update(model=str(done.model), inner_loop=str(done.inner_loop))
    path = Path(tempfile.mkdtemp(prefix="bench_loop-")) / "cell.toml"
    path.write_text(tomli_w.dumps(raw))
    return path


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(
        prog="python -m sim_bridge.bench_loop_cli",
        description="Time the control process's per-cycle work (decode, zero-moment torque, "
        "eq. (21), encode) on realistic joint states; prints µs per cycle.",
    )
    p.add_argument("--calls", type=int, default=20000, help="timed cycles (default 20000)")
    p.add_argument("--warmup", type=int, default=2000, help="untimed cycles first")
    p.add_argument("--profile", action="store_true", help="also print a cProfile of the path")
    p.add_argument(
        "--period-ms",
        type=float,
        default=0.0,
        help="sleep this long before each call and time it by CPU clock (cold caches, as in "
        "the process at that cycle); default 0: back to back, wall clock",
    )
    p.add_argument("--json", action="store_true", help="print the result as JSON")
    p.add_argument(
        "--config",
        type=Path,
        default=None,
        help="a commissioned cell config (default: the virtual cell with plant seed 0's "
        "commissioned model, identified first if not cached)",
    )
    args = p.parse_args(argv)
    cell = args.config or _virtual_cell()
    result = run(cell, args.calls, args.warmup, args.profile, args.period_ms / 1e3)
    if args.json:
        print(json.dumps(result, indent=2))
        return 0
    print(f"{'µs per call':<30} {'median':>8} {'p99':>8} {'mean':>8} {'max':>8}", end="")
    print(f"  ({args.calls} calls, {args.period_ms:g} ms apart, {result['clock']} clock)")
    for name in ("on_state", "JointState.from_bytes", "make_joint_command.to_bytes"):
        s = result[name]
        print(f"{name:<30} {s['median_us']:>8.1f} {s['p99_us']:>8.1f} {s['mean_us']:>8.1f} "
              f"{s['max_us']:>8.0f}")  # fmt: skip
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
