"""`leadthrough bench`: the control loop's real-time behaviour on the virtual cell, per rate.

For each rate the whole product runs as separate processes (virtual controller, gateway, CAN
driver, Modbus driver, control process reached through zenoh) with the operator holding the
enabling device and teaching, for ``--cycles`` controller cycles. Reported per rate:

* ``cycles``: controller cycles in the measured window (CAN driver's count);
* ``computed``: answered with a fresh command from the control law, in time;
* ``coasted``: answered by the CAN driver moving the last command on by its velocity (the
  control law was late);
* ``held``: answered with a hold set (the command was late past ``deadline_s``, refused, or
  teaching was blocked);
* ``missed``: cycles the controller began without a complete set for the previous one (its
  own count, PROTOCOL.md §6.1: a missed cycle freezes the reference);
* wire-to-wire latency ``p50_ms``/``p99_ms``/``p999_ms``/``max_ms``, measured by the virtual
  controller: its last feedback frame of cycle k leaving → the last frame of the computed or
  coasted set answering k arriving;
* ``stages``: the CAN driver's per-stage latency (decode, zenoh out, control law, zenoh back,
  encode, and the whole answer) at p50/p99/p99.9, so the next bottleneck is visible;
* ``cpu_ms_per_cycle``: CPU time of each process per controller cycle.

A rate at which teaching cannot even start is reported with the reason and the controller's
faults, not a traceback. On a terminal a bar on stderr counts the measured cycles of all
rates (``--no-progress``: none).
"""

from __future__ import annotations

import argparse
import json
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from gateway.bus_security import write_credentials
from gateway.progress import add_progress_argument, progress_bar, progress_enabled
from sim_bridge.commission import commissioned_stack
from sim_bridge.harness import CAN_PROFILES, Stack, deep_merge

#: the counters of the CAN driver's health that classify its answers
_COUNTS = ("cycles", "forwarded", "coasted", "held", "unanswered")


def driver_health(stack: Stack, timeout_s: float = 3.0) -> dict[str, Any]:
    """The CAN driver's next health message (it publishes at 10 Hz)."""
    from gateway.bus import open_client
    from gateway.messages import decode_json

    session = open_client(stack.bus)
    try:
        sub = session.declare_subscriber(stack.bus.keys.health("can_driver"))
        try:
            deadline = time.monotonic() + timeout_s
            while time.monotonic() < deadline:
                sample = sub.try_recv()
                if sample is not None:
                    return decode_json(sample.payload.to_bytes(), "can_driver health")
                time.sleep(0.01)
        finally:
            sub.undeclare()
    finally:
        session.close()
    raise TimeoutError(f"no CAN driver health on {stack.bus.endpoint} within {timeout_s} s")


def _cpu(stack: Stack, seconds: float) -> dict[str, float] | None:
    try:
        from sim_bridge.cpu import process_cpu_per_cycle
    except ImportError:
        return None
    return process_cpu_per_cycle(stack, seconds)


def run_rate(
    rate_hz: float,
    cycles: int,
    workdir: Path,
    profile: str = "classic",
    place: bool = False,
    locked_bus: bool = False,
    on_cycles: Callable[[int], None] | None = None,
) -> dict[str, Any]:
    """One rate's measurement (module docstring). ``on_cycles(k)`` hears, about every 0.5 s,
    how many of the ``cycles`` the measured window has lasted so far (from its clock)."""
    period = 1.0 / rate_hz
    sim_profile, cell_overrides = CAN_PROFILES[profile]
    if locked_bus:  # the cell PC's bus: credentials, access list, every process a client
        workdir.mkdir(parents=True, exist_ok=True)
        creds = write_credentials(workdir / "bus.credentials")
        cell_overrides = deep_merge(cell_overrides, {"bus": {"credentials_file": str(creds)}})
    controller_period = period
    if profile == "cia402":  # the host clocks the cycle: its SYNC period is the rate
        cell_overrides = deep_merge(cell_overrides, {"can": {"cia402": {"cycle_period_s": period}}})
        controller_period = min(period, sim_profile["controller"]["cycle_period_s"])  # servo
    overrides = deep_merge(
        sim_profile,
        {
            "controller": {"cycle_period_s": controller_period},
            "operator": {"enabling_after_s": 0.0, "mode": "none"},
        },
    )
    result: dict[str, Any] = {"hz": rate_hz, "profile": profile, "cycles": 0, "error": None}
    result["locked_bus"] = locked_bus
    with commissioned_stack(workdir, sim_overrides=overrides, cell_overrides=cell_overrides,
               place=place) as stack:  # fmt: skip
        result["placement"] = None if stack.placement is None else {
            "product_cpus": list(stack.placement[0]), "sim_cpus": list(stack.placement[1])
        }  # fmt: skip
        stack.start()
        try:
            stack.start_teaching()
        except (TimeoutError, RuntimeError) as exc:  # the loop cannot even start at this rate
            result["error"] = f"teaching did not start: {exc}"
        else:
            before = driver_health(stack)
            t_start = time.monotonic()
            t_end = t_start + cycles * period
            cpu = _cpu(stack, min(10.0, cycles * period / 2))
            while time.monotonic() < t_end:
                stack.check_alive()
                if on_cycles is not None:
                    on_cycles(min(cycles, int((time.monotonic() - t_start) / period)))
                time.sleep(min(0.5, max(t_end - time.monotonic(), 0.0)))
            after = driver_health(stack)
            delta = {k: int(after[k]) - int(before[k]) for k in _COUNTS}
            result.update(
                cycles=delta["cycles"],
                computed=delta["forwarded"],
                coasted=delta["coasted"],
                held=delta["held"],
                unanswered_by_driver=delta["unanswered"],
                stages=after.get("stages", {}),
                cpu_ms_per_cycle=cpu,
                driver_state=after.get("controller_state"),
            )
        stack.request("stop")
    summary = json.loads(stack.sim_summary.read_text())
    result["missed"] = int(summary["controller_missed_cycles"])
    result["faults"] = summary["faults"]
    result["sim_overruns"] = summary.get("overruns")
    for key, name in (("p50_ms", "latency_p50_s"), ("p99_ms", "latency_p99_s"),
                      ("p999_ms", "latency_p999_s"), ("max_ms", "latency_max_s")):  # fmt: skip
        value = summary.get(name)
        result[key] = None if value is None else round(value * 1e3, 3)
    if result["cycles"]:
        bad = result["missed"] + result.get("coasted", 0) + result.get("held", 0)
        result["not_computed_pct"] = round(100.0 * bad / result["cycles"], 3)
    return result


def _table(results: list[dict[str, Any]]) -> str:
    cols = ("hz", "cycles", "computed", "coasted", "held", "missed", "p50_ms", "p99_ms",
            "p999_ms", "max_ms")  # fmt: skip
    lines = [" ".join(f"{c:>9}" for c in cols)]
    for r in results:
        cells = []
        for c in cols:
            v = r.get(c)
            cells.append(f"{'-':>9}" if v is None else f"{v:>9.3f}" if isinstance(v, float)
                         else f"{v:>9}")  # fmt: skip
        lines.append(" ".join(cells))
    for r in results:
        stages = r.get("stages") or {}
        if stages:
            parts = [f"{name} {s.get('p50_us')}/{s.get('p99_us')}" for name, s in stages.items()]
            lines.append(f"{r['hz']:>7.0f}Hz stages p50/p99 [µs]: " + ", ".join(parts))
        cpu = r.get("cpu_ms_per_cycle")
        if cpu:
            parts = [f"{name} {v:.3f}" for name, v in cpu.items()]
            lines.append(f"{r['hz']:>7.0f}Hz CPU per cycle [ms]: " + ", ".join(parts))
        for problem in ([r["error"]] if r.get("error") else []) + list(r.get("faults") or []):
            lines.append(f"{r['hz']:>7.0f}Hz: {problem}")
    return "\n".join(lines)


def configure_parser(p: argparse.ArgumentParser) -> None:
    p.description = (
        "Benchmark the control loop on the virtual cell at each rate: how many cycles were "
        "answered by the control law in time (computed), by the CAN driver coasting or "
        "holding, or missed; the wire-to-wire latency (last feedback frame leaving the "
        "virtual controller → last command frame arriving back); the latency of each stage; "
        "the CPU per cycle of every process."
    )
    p.add_argument("--rates", type=float, nargs="+", default=[250.0, 500.0], help="[Hz]")
    p.add_argument("--cycles", type=int, default=10000, help="cycles per rate")
    p.add_argument("--out", type=Path, default=Path("bench_out"), help="working folder (logs)")
    p.add_argument(
        "--profile",
        choices=sorted(CAN_PROFILES),
        default="classic",
        help="CAN profile: classic (LTC-1, 13 frames per cycle), fd (LTC-1F, 2 frames) or "
        "cia402 (CiA 402 drives over CANopen: SYNC + 24 PDOs, the host clocking the cycle)",
    )
    p.add_argument("--json", type=Path, default=None, help="write the results here as JSON")
    p.add_argument(
        "--place",
        action="store_true",
        help="on two CPUs or more, run the virtual cell on the last CPU and the product on the "
        "others (default: the OS places them)",
    )
    p.add_argument(
        "--locked-bus",
        action="store_true",
        help="run the product on a locked bus, as the cell PC does (credentials, the router's "
        "access list, every process a client of the router: gateway/bus_security.py)",
    )
    add_progress_argument(p)


def cli_main(args: argparse.Namespace) -> int:
    if args.cycles < 100:
        print("--cycles must be at least 100")
        return 2
    results = []
    total = args.cycles * len(args.rates)
    with progress_bar(total, "bench", "cycle", enabled=progress_enabled(args)) as bar:
        for k, rate in enumerate(args.rates):
            bar.write(f"running {args.cycles} cycles at {rate:.0f} Hz ({args.profile}) ...")
            bar.set_label(f"{rate:.0f} Hz")
            workdir = args.out / f"{rate:.0f}hz_{args.profile}"
            done = k * args.cycles

            def measured(cycles: int, done: int = done) -> None:
                bar.update_to(done + cycles)

            result = run_rate(
                rate, args.cycles, workdir, args.profile, args.place, args.locked_bus, measured
            )
            results.append(result)
            bar.update_to(done + args.cycles)  # also a rate that could not start: it is over
    print()
    print(_table(results))
    doc = {"rates": results}
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "bench.json").write_text(json.dumps(doc, indent=2))
    if args.json is not None:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(doc, indent=2))
    return 0 if all(r.get("cycles") for r in results) else 1
