"""`leadthrough`: the one command-line entry point; every tool is a subcommand.

Subcommand modules are imported lazily: `leadthrough status`, `--help` and `--version` do not
load MuJoCo.
"""

from __future__ import annotations

import argparse
import importlib
import json
import logging
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

from gateway.errors import EXIT_CONFIG, ConfigError, LeadthroughError
from gateway.guide_modes import GUIDES
from gateway.parent_death import die_with_parent_from_env

#: name → (module, one-line help)
SUBCOMMANDS: dict[str, tuple[str, str]] = {
    "gateway": ("gateway.supervisor", "run the gateway: router, drivers, control, lifecycle"),
    "start": (
        "gateway.cli",
        "operator: servo on and hold (teach while the enabling device is held)",
    ),
    "stop": ("gateway.cli", "operator: stop the robot (brakes on)"),
    "status": ("gateway.cli", "operator: show lifecycle state, links and why it cannot start"),
    "reset": ("gateway.cli", "operator: clear a fault once its cause is gone"),
    "mark": ("gateway.cli", "operator: mark a waypoint in the program being taught"),
    "program": ("control.program_cli", "show a taught program, export it as CSV or processed"),
    "replay": ("gateway.replay", "operator: play a taught program back on the robot"),
    "can-driver": ("drivers.can.driver", "run the CAN driver (started by the gateway)"),
    "modbus-driver": ("drivers.modbus.driver", "run the Modbus driver (started by the gateway)"),
    "control": ("control.process", "run the control process (started by the gateway)"),
    "sim": ("sim_bridge.sim_cli", "run the virtual robot cell (MuJoCo + virtual controller)"),
    "demo": ("sim_bridge.demo", "run the whole product on the virtual cell and report"),
    "teach-bench": (
        "sim_bridge.teach_bench",
        "benchmark lead-through strategies on a raster spray path (virtual cell)",
    ),
    "bench": ("sim_bridge.bench", "measure wire-to-wire loop latency on the virtual cell"),
    "identify": (
        "control.identification.on_cell",
        "run identification experiments on the cell and fit",
    ),
    "record": ("gateway.recorder", "record everything on the bus into an MCAP file"),
    "export": (
        "gateway.export_cli",
        "export a recording's joint states for analyze (CSV, Parquet)",
    ),
    "view": ("gateway.live_view", "serve the bus live to Foxglove (WebSocket)"),
    "ros2": ("gateway.ros2", "publish the joint states to a ROS 2 system (rmw_zenoh)"),
    "config": ("gateway.config_check", "check a cell config: every section, every error"),
    "bus-certs": ("gateway.bus_tls", "make the certificates for mutual TLS off the cell PC"),
    "analyze": (
        "control.identification.cli",
        "identify the dynamic model from recorded files, validate, find missing effects",
    ),
    "predict": (
        "control.identification.predict_cli",
        "an identified model's joint torque on every row of a measured file",
    ),
}
OPERATOR_COMMANDS = ("start", "stop", "status", "reset", "mark")
#: the product's processes: each places itself by the cell config's [realtime] when it starts
PRODUCT_PROCESSES = ("gateway", "can-driver", "modbus-driver", "control")


def _configure_operator(p: argparse.ArgumentParser, name: str) -> None:
    p.add_argument("--config", type=Path, default=None, help="cell config TOML (for [bus])")
    p.add_argument("--bus", default=None, help="zenoh endpoint of the gateway")
    p.add_argument("--json", action="store_true", help="print the gateway's full JSON reply")
    p.add_argument("--timeout", type=float, default=3.0, help="seconds to wait for the gateway")
    if name == "start":
        p.add_argument(
            "--program",
            default=None,
            help="name of the program this session's teaching is recorded to (default: "
            "teach-<UTC time>), in the gateway's [gateway].program_dir",
        )
        p.add_argument(
            "--guide",
            choices=GUIDES,
            default=None,
            help="constrained guiding: the tool's orientation held, and with it the tool point "
            "kept in the plane facing the tool or on a line along one of its axes (default: the "
            "cell config's [control] guide); given while teaching, it changes the guide there",
        )
    if name == "mark":
        p.add_argument("--label", default="", help="a label for the waypoint")


def _operator_main(args: argparse.Namespace) -> int:
    from gateway.bus import BusConfig, bus_config_from
    from gateway.config import load_toml
    from gateway.operator_request import operator_request

    bus = BusConfig()
    if args.config:
        bus = bus_config_from(load_toml(args.config), str(args.config))
    fields = {}
    if getattr(args, "program", None) is not None:
        fields["program"] = args.program
    if getattr(args, "label", ""):
        fields["label"] = args.label
    if getattr(args, "guide", None) is not None:
        fields["guide"] = args.guide
    reply = operator_request(bus.with_overrides(args.bus), args.command, args.timeout, **fields)
    if args.json:
        print(json.dumps(reply, indent=2))
    else:
        state = reply.get("state", "?")
        print(f"{'OK' if reply.get('ok') else 'REFUSED'}: {reply.get('message')} [state: {state}]")
        for problem in reply.get("problems", []) if args.command == "status" else []:
            print(f"  - {problem}")
        engagement = reply.get("engagement") if args.command == "status" else None
        if isinstance(engagement, dict) and engagement.get("phase") == "probing":
            print(f"  - the arm is measuring its model's error ({engagement.get('left_s')} s "
                  "left): hold the tool lightly, do not push yet")  # fmt: skip
        refused = reply.get("bus_refused") if args.command == "status" else None
        if isinstance(refused, dict) and refused.get("total"):
            print(f"  - {refusal_line(refused)}")
        guide = reply.get("guide") if args.command == "status" else None
        if isinstance(guide, dict) and (line := guide_line(guide)):
            print(f"  - {line}")
        adapted = reply.get("model_adaptation") if args.command == "status" else None
        if isinstance(adapted, dict):
            for line in adaptation_lines(adapted):
                print(f"  - {line}")
    return 0 if reply.get("ok") else 1


def guide_line(guide: dict) -> str:
    """What `leadthrough status` says of constrained guiding: the guide the control law holds
    and how far the tool is from it ("" for a free guide or none reported)."""
    held = guide.get("control")
    if not isinstance(held, dict) or held.get("mode") in (None, "free"):
        return ""
    line = f"guide: {held.get('mode')}, the tool turned {held.get('rotation_deg')}° from its hold"
    if held.get("mode") in ("plane", "axis"):
        line += f", {held.get('deviation_mm')} mm off its {held.get('mode')}"
    return line


#: how many (identity, action, key) entries `leadthrough status` names, the most refused first
REFUSALS_SHOWN = 6


def refusal_line(refused: dict) -> str:
    """What `leadthrough status` says of the locked bus's refusals: the total and the most
    refused (identity, action, key); every entry is in ``--json``."""
    entries = sorted(
        (e for e in refused.get("by", []) if isinstance(e, dict)),
        key=lambda e: -int(e.get("count") or 0),
    )
    parts = [
        f"{e.get('identity')} {e.get('action')} on {e.get('key')} x{e.get('count')}"
        for e in entries[:REFUSALS_SHOWN]
    ]
    more = f" and {len(entries) - REFUSALS_SHOWN} more" if len(entries) > REFUSALS_SHOWN else ""
    return f"the bus refused {refused.get('total')}: " + ", ".join(parts) + more


def adaptation_lines(adapted: dict) -> list[str]:
    """What `leadthrough status` says of the mass eq. (29) added to the model in replay."""
    out = []
    mass = adapted.get("mass_kg")
    if isinstance(mass, int | float) and abs(mass) >= 0.05:
        where = adapted.get("com_m")
        at = f" at {where} m from the flange" if isinstance(where, list) else ""
        if adapted.get("applied"):
            state = "compensated"
        elif adapted.get("not_taken"):
            state = f"not compensated: {adapted['not_taken']}"
        else:
            state = "compensated after this run if it explains the run better"
        out.append(f"model: {mass:+.2f} kg{at} learned in replay, {state}")
    if adapted.get("problem"):
        out.append(f"model adaptation: {adapted['problem']}")
    return out


def _version() -> str:
    """The installed package's version (the source tree's pyproject.toml when not installed)."""
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("leadthrough")
    except PackageNotFoundError:
        import tomllib
        from pathlib import Path

        pyproject = Path(__file__).resolve().parents[1] / "pyproject.toml"
        return str(tomllib.loads(pyproject.read_text())["project"]["version"])


def build_parser() -> argparse.ArgumentParser:
    """The top-level parser: the subcommands by name and help only. ``leadthrough COMMAND ...``
    is parsed by :func:`_single`, which imports that one subcommand's module for its options;
    so ``--help`` and ``--version`` import none (MuJoCo, SciPy: 2 s)."""
    parser = argparse.ArgumentParser(
        prog="leadthrough",
        description=(
            "Hand-guiding (lead-through teaching) for a closed-controller painting robot. "
            "Typical use on the cell PC: `leadthrough gateway --config cell.toml`, then "
            "`leadthrough start`, hold the enabling device and guide the tool; "
            "`leadthrough stop` when done."
        ),
    )
    parser.add_argument("-v", "--verbose", action="store_true", help="debug logging")
    parser.add_argument("--version", action="version", version=f"leadthrough {_version()}")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for name, (_module, help_text) in SUBCOMMANDS.items():
        sub.add_parser(name, help=help_text, description=help_text)
    return parser


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    try:
        die_with_parent_from_env()  # started by the virtual cell's harness: stop with it
    except ConfigError as exc:
        print(f"leadthrough: {exc}", file=sys.stderr)
        return EXIT_CONFIG
    # Build only the parser needed: importing every subcommand would load MuJoCo for `status`.
    parser = build_parser() if not argv or argv[0] not in SUBCOMMANDS else _single(argv[0])
    args = parser.parse_args(argv)
    from gateway.runner import setup_logging

    setup_logging(args.command, logging.DEBUG if getattr(args, "verbose", False) else logging.INFO)
    try:
        if args.command in OPERATOR_COMMANDS:
            return _operator_main(args)
        if args.command in PRODUCT_PROCESSES:
            args.place = _placement(args.command, args.config)
        return int(importlib.import_module(SUBCOMMANDS[args.command][0]).cli_main(args) or 0)
    except ConfigError as exc:
        print(f"leadthrough {args.command}: configuration refused: {exc}", file=sys.stderr)
        return EXIT_CONFIG
    except LeadthroughError as exc:
        print(f"leadthrough {args.command}: error: {exc}", file=sys.stderr)
        return 2


def _placement(process: str, cell_path: Path) -> Callable[[], Any]:
    """The cell config's ``[realtime]`` for this process, read now (a bad section is a
    ConfigError like any other) and applied by :func:`gateway.runner.run_service` once the
    process is built, before it opens any link (gateway/realtime.py)."""
    from gateway.config import load_toml
    from gateway.realtime import apply_realtime, realtime_config_from

    cfg = realtime_config_from(load_toml(cell_path), str(cell_path))
    return lambda: apply_realtime(cfg, process)


def _single(name: str) -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="leadthrough")
    parser.add_argument("-v", "--verbose", action="store_true", help="debug logging")
    parser.add_argument("--version", action="version", version=f"leadthrough {_version()}")
    sub = parser.add_subparsers(dest="command", required=True)
    module, help_text = SUBCOMMANDS[name]
    p = sub.add_parser(name, help=help_text, description=help_text)
    if name in OPERATOR_COMMANDS:
        _configure_operator(p, name)
    else:
        importlib.import_module(module).configure_parser(p)
    return parser


if __name__ == "__main__":
    sys.exit(main())
