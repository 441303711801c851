"""`leadthrough replay PROGRAM`: play a taught program back on the robot, in position mode.

The program (:mod:`gateway.program`) is checked here first, then the gateway is asked to
``replay`` it: with the enabling device held it enters REPLAYING and the control process plays
the path (:mod:`control.taught_path`: an approach from where the arm stands to the program's
first pose, then each taught segment with the hand tremor filtered out, at constant tool
speed). The control process reads the file itself, so the path must be readable on the cell PC
where the gateway runs. Releasing the enabling device stops the replay (READY, the arm held).
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path
from typing import Any

from gateway.bus import BusConfig, bus_config_from
from gateway.config import load_toml
from gateway.errors import LeadthroughError
from gateway.program import DEFAULT_SPEED_MM_S, MAX_SPEED_MM_S


def replay_plan(program: Path, speed_mm_s: float, plan_id: str | None = None) -> dict:
    """The plan the gateway passes to the control process for ``program``."""
    from gateway.program import read_program

    if not 0 < speed_mm_s <= MAX_SPEED_MM_S:
        raise LeadthroughError(f"--speed-mm-s {speed_mm_s}: must be in (0, {MAX_SPEED_MM_S:g}]")
    prog = read_program(program)  # refuse a bad file here, with its line
    if not prog.t_s.size:
        raise LeadthroughError(f"{program}: the program has no taught path (no trace samples)")
    return {
        "plan_id": plan_id or f"replay-{program.stem}-{int(time.time())}",
        "replay": {"program": str(program.resolve()), "speed_m_s": speed_mm_s / 1000.0},
    }


def configure_parser(p: argparse.ArgumentParser) -> None:
    p.description = __doc__.split("\n\n")[1].replace("\n", " ") if __doc__ else None
    p.add_argument("program", type=Path, help="the taught program (.jsonl)")
    p.add_argument(
        "--speed-mm-s",
        type=float,
        default=DEFAULT_SPEED_MM_S,
        help=f"tool speed along the path [mm/s] (default {DEFAULT_SPEED_MM_S:g}, at most "
        f"{MAX_SPEED_MM_S:g}; the tool slows down where a joint would pass its speed limit)",
    )
    p.add_argument("--config", type=Path, default=None, help="cell config TOML (for [bus])")
    p.add_argument("--bus", default=None, help="zenoh endpoint of the gateway")
    p.add_argument("--timeout", type=float, default=3.0, help="seconds to wait for the gateway")
    p.add_argument(
        "--no-wait", action="store_true", help="return once the replay started (default: wait)"
    )


def cli_main(args: argparse.Namespace) -> int:
    from gateway.operator_request import OperatorClient

    bus = BusConfig()
    if args.config:
        bus = bus_config_from(load_toml(args.config), str(args.config))
    bus = bus.with_overrides(args.bus)
    plan = replay_plan(args.program, args.speed_mm_s)
    with OperatorClient(bus) as client:
        return _replay(client, plan, args)


def _replay(client: Any, plan: dict, args: argparse.Namespace) -> int:
    """Send the replay and, unless ``--no-wait``, follow it on the status until it ends."""
    reply = client.request("replay", args.timeout, plan=plan)
    if not reply.get("ok"):
        print(f"REFUSED: {reply.get('message')} [state: {reply.get('state', '?')}]")
        return 1
    print(f"OK: {reply.get('message')}; keep the enabling device held")
    if args.no_wait:
        return 0
    while True:
        time.sleep(0.5)
        status = client.request("status", args.timeout)
        result = status.get("plan") or {}
        if result.get("plan_id") != plan["plan_id"]:
            print(f"ENDED: the gateway no longer knows the replay [state: {status.get('state')}]")
            return 1
        if result.get("state") != "running":
            done = result.get("state") == "done"
            print(f"{'OK' if done else 'ENDED'}: {result.get('reason')} "
                  f"[state: {status.get('state', '?')}]")  # fmt: skip
            return 0 if done else 1
