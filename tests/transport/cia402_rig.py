"""The CiA 402 virtual cell for transport tests: on a CAN segment of its own, its loop in a
thread, lock-step (one servo cycle of the host's SYNC period per SYNC, so the plant's time is
exact however late this loaded process runs the host or the cell)."""

from __future__ import annotations

import contextlib
import threading
from collections.abc import Iterator

from sim_bridge.config import load_sim_config
from sim_bridge.harness import TRUTH_CIA402, free_port, unique_can_address
from sim_bridge.sim import VirtualCell
from sim_bridge.sim_cli import make_virtual_cell


@contextlib.contextmanager
def cia402_cell(sync_period_s: float) -> Iterator[VirtualCell]:
    """The running cell; stopped, joined and closed on exit, failing with its loop's error."""
    controller = load_sim_config(TRUTH_CIA402).controller
    cfg = load_sim_config(
        TRUTH_CIA402,
        {
            "endpoints": {"can_channel": unique_can_address(), "modbus_port": free_port()},
            "realtime": False,
            "controller": {**vars(controller), "cycle_period_s": sync_period_s},
        },
    )
    vc = make_virtual_cell(cfg)
    vc.open()
    errors: list[BaseException] = []

    def run() -> None:
        try:
            vc.run()
        except BaseException as exc:  # the test fails with it
            errors.append(exc)

    loop = threading.Thread(target=run, name="cia402-cell")
    loop.start()
    try:
        yield vc
    finally:
        vc.stop()
        loop.join()
        vc.close()
    assert not errors, errors
