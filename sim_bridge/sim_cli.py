"""`leadthrough sim`: the virtual robot cell as a process, the LTC-1 vendor controller
(sim_bridge/sim.py) or one CiA 402 drive per joint (sim_bridge/cia402_cell.py) as the truth
file's ``[controller].can_profile`` asks."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from gateway.signals import StopSignals
from sim_bridge.cia402_cell import Cia402Cell
from sim_bridge.config import SimConfig, load_sim_config
from sim_bridge.sim import VirtualCell


def make_virtual_cell(
    cfg: SimConfig, truth_log: Path | None = None, summary_path: Path | None = None
) -> VirtualCell:
    """The virtual cell ``[controller].can_profile`` asks for: the LTC-1 vendor controller
    ("classic", "fd"), or one CiA 402 drive per joint ("cia402")."""
    if cfg.controller.can_profile == "cia402":
        return Cia402Cell(cfg, truth_log, summary_path)
    return VirtualCell(cfg, truth_log, summary_path)


def configure_parser(p: argparse.ArgumentParser) -> None:
    p.description = (
        "Run the virtual robot cell: a simulated GR630ST with its closed controller, exposing "
        "the same CAN (LTC-1; on a Unix seqpacket socket or a socketcand TCP server, see "
        "[endpoints] of the truth file) and Modbus TCP endpoints as the real cell; with "
        '[controller] can_profile = "cia402" (sim_bridge/gr630st_truth_cia402.toml) one '
        "CANopen CiA 402 drive per joint instead of the LTC-1 controller. Stop it with Ctrl-C."
    )
    p.add_argument("--truth", type=Path, default=None, help="simulator config (private truth) TOML")
    p.add_argument(
        "--plant-seed",
        type=int,
        default=None,
        help="draw the plant from this seed (0: the truth file as written; default: its "
        "plant_seed)",
    )
    p.add_argument(
        "--duration", type=float, default=None, help="stop after this simulated time [s]"
    )
    p.add_argument("--lockstep", action="store_true", help="run lock-step, faster than real time")
    p.add_argument("--log", type=Path, default=None, help="write the per-cycle truth log (CSV)")
    p.add_argument("--summary", type=Path, default=None, help="write counters and latency (JSON)")


def cli_main(args: argparse.Namespace) -> int:
    overrides: dict[str, Any] = {}
    if args.lockstep:
        overrides["realtime"] = False
    if args.plant_seed is not None:
        overrides["plant_seed"] = args.plant_seed
    cfg = load_sim_config(args.truth, overrides)
    cell = make_virtual_cell(cfg, args.log, args.summary)

    with StopSignals(cell.stop_event):
        cell.open()
        try:
            cell.run(args.duration)
        finally:
            cell.close()
    return 0
