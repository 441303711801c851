"""CPU cost of every process of a running :class:`~sim_bridge.harness.Stack`, per controller cycle.

The budget is stated per cycle (all the product's processes together ≤ 1.0 ms of CPU per 4 ms
cycle on the slowest supported PC), so that is the unit: CPU time (user + system, all threads,
from ``/proc/<pid>/stat``) spent over a window, divided by the controller cycles in it [ms].

Processes: ``gateway`` (which hosts the zenoh router), the children it supervises
(``can-driver``, ``modbus-driver``, ``control``, found as its child processes), and ``sim``,
the virtual controller with its I/O module's threads (not part of the product, reported so the
machine's whole load is visible).

Run ``python -m sim_bridge.cpu --rate 250`` for the whole measurement on a fresh stack.
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time
from pathlib import Path

from control.config import STRATEGIES
from sim_bridge import proc_stat
from sim_bridge.commission import commissioned_stack
from sim_bridge.harness import Stack

#: the processes of the product (everything but the virtual cell)
PRODUCT = ("gateway", "can-driver", "modbus-driver", "control")


def _children(pid: int) -> dict[str, int]:
    """Child processes of ``pid`` by their `leadthrough` subcommand name (``gateway.cli NAME``)."""
    out = {}
    for child in proc_stat.children(pid):
        try:
            argv = Path(f"/proc/{child}/cmdline").read_bytes().split(b"\0")
        except OSError:
            continue  # gone since
        args = [a.decode(errors="replace") for a in argv]
        name = args[args.index("gateway.cli") + 1] if "gateway.cli" in args[:-1] else str(child)
        out[name] = child
    return out


def stack_pids(stack: Stack) -> dict[str, int]:
    """PIDs of every process of ``stack``: sim, gateway and the gateway's children."""
    if stack.gateway is None or stack.sim is None:
        raise RuntimeError("the stack is not started")
    return {"sim": stack.sim.pid, "gateway": stack.gateway.pid, **_children(stack.gateway.pid)}


def controller_cycle(stack: Stack) -> int | None:
    """The virtual controller's cycle counter, from the last complete line of its truth log
    (flushed every few cycles), or None if there is none yet."""
    try:
        with stack.truth_log.open("rb") as fh:
            header = fh.readline().decode().strip().split(",")
            fh.seek(0, os.SEEK_END)
            fh.seek(max(0, fh.tell() - 8192))
            lines = fh.read().split(b"\n")
    except (OSError, UnicodeDecodeError):
        return None
    if "cycle" not in header:
        return None
    for line in reversed(lines[1:-1]):  # the first may be cut by the seek, the last unfinished
        fields = line.split(b",")
        if len(fields) == len(header):
            return int(float(fields[header.index("cycle")]))
    return None


def process_cpu_per_cycle(stack: Stack, seconds: float) -> dict[str, float]:
    """CPU of each process of the running ``stack`` per controller cycle [ms], over ``seconds``.

    Keys are ``sim`` (the virtual controller and I/O module), ``gateway``, and the gateway's
    children (``can-driver``, ``modbus-driver``, ``control``). The cycles are those the virtual
    controller ran in the window, counted from its truth log (an overloaded machine runs fewer
    than the nominal rate); without a log, the window over ``cycle_period_s``. A process that
    exits during the window raises RuntimeError (its figure would be meaningless).
    """
    period_s = float(stack.truth_cfg["controller"]["cycle_period_s"])
    pids = stack_pids(stack)
    start = {name: proc_stat.process_cpu_s(pid) for name, pid in pids.items()}
    cycle0, t0 = controller_cycle(stack), time.monotonic()
    time.sleep(seconds)
    end = {name: proc_stat.process_cpu_s(pid) for name, pid in pids.items()}
    cycle1, elapsed = controller_cycle(stack), time.monotonic() - t0
    if cycle0 is not None and cycle1 is not None and cycle1 > cycle0:
        cycles = float(cycle1 - cycle0)
    else:
        cycles = elapsed / period_s
    out = {}
    for name in pids:
        a, b = start[name], end[name]
        if a is None or b is None:
            raise RuntimeError(f"process {name} ({pids[name]}) exited during the measurement")
        out[name] = 1e3 * (b - a) / cycles
    return out


def measure(
    rate_hz: float, seconds: float, workdir: Path, strategy: str | None = None
) -> tuple[dict[str, float], str]:
    """Start a stack at ``rate_hz``, teach (no operator force) with the lead-through law
    ``strategy`` (None: the cell's), measure, stop. Returns the figures and the lifecycle
    state at the end of the window (``teaching`` unless it faulted, in which case the control
    process stopped commanding part way)."""
    overrides = {
        "controller": {"cycle_period_s": 1.0 / rate_hz},
        "operator": {"enabling_after_s": 0.0, "mode": "none"},
    }
    cell = {"control": {"strategy": strategy}} if strategy else None
    with commissioned_stack(workdir, sim_overrides=overrides, cell_overrides=cell) as stack:
        stack.start()
        stack.start_teaching()
        try:
            result = process_cpu_per_cycle(stack, seconds)
            status = stack.request("status")
            return result, f"{status.get('state')} ({status.get('reason')})"
        finally:
            stack.request("stop")


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(
        prog="python -m sim_bridge.cpu",
        description="Start the whole stack on the virtual cell, start teaching, and print the "
        "CPU time each process spends per controller cycle [ms].",
    )
    p.add_argument("--rate", type=float, default=250.0, help="controller rate [Hz]")
    p.add_argument("--seconds", type=float, default=10.0, help="measurement window [s]")
    p.add_argument("--out", type=Path, default=None, help="work folder (default: a temp dir)")
    p.add_argument("--strategy", choices=STRATEGIES, default=None,
                   help="the lead-through law that teaches (default: the cell's)")  # fmt: skip
    args = p.parse_args(argv)
    with tempfile.TemporaryDirectory() as tmp:
        res, state = measure(args.rate, args.seconds, args.out or Path(tmp), args.strategy)
    law = f", {args.strategy}" if args.strategy else ""
    print(f"CPU per {1e3 / args.rate:g} ms cycle at {args.rate:g} Hz{law}, {args.seconds:g} s "
          "window:")  # fmt: skip
    for name, ms in sorted(res.items(), key=lambda kv: -kv[1]):
        print(f"  {name:<15} {ms:7.3f} ms")
    product = sum(v for k, v in res.items() if k in PRODUCT)
    print(f"  {'product total':<15} {product:7.3f} ms")
    print(f"lifecycle at the end of the window: {state}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
