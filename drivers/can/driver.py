"""The CAN driver process: the robot controller's CAN link on one side, the zenoh bus on the other.

The cycle is compiled (drivers/can/rt, issue 48): a Rust loop thread owns the CAN socket, decodes
every frame, runs the host core's decisions (which frames complete a cycle, whether and how it
is answered: forwarded command, coast, hold, ramp; servo requests and heartbeats; the monitors),
publishes the JointState and answers the control process's JointCommand from zenoh's receiving
thread, all without Python (read drivers/can/rt/src/core.rs for the rules). This module is what
is not per cycle: it reads the cell config, derives the adapter's tables from the DBC/EDS
(drivers/can/rt_tables.py, rt_cia402_tables.py) and the speed monitor's kinematics from the robot
description (rt_kinematics.py), runs the adapter's start-up (CANopen's SDO configuration) on a
python-can bus, then moves the core onto the loop; it publishes the loop's health and logs its
notes at HEALTH_RATE_HZ, and closes it (BRAKE first). Run as a process, a stop signal makes the
loop send the BRAKE itself (:class:`CanDriverProcess`): no Python on the way from SIGTERM to it.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import logging
import signal
import threading
import time
from pathlib import Path
from typing import Any

import can

from drivers.can import _rt
from drivers.can.adapter import ADAPTER_GROUP, CanAdapter
from drivers.can.config import CanDriverConfig, load_can_config
from drivers.can.rt_adapters import adapter_tables, static_tables
from drivers.can.rt_kinematics import chain_table
from drivers.registry import load_adapter
from gateway import bus_security as security
from gateway.bus import BusConfig, open_peer, peer_config_entries
from gateway.config import require
from gateway.current_zero_file import StoredZeroError, read_stored_zero
from gateway.errors import ConfigError, LinkTimeoutError
from gateway.messages import HEALTH_RATE_HZ, encode_json
from gateway.runner import run_service
from gateway.signals import STOP_SIGNALS

log = logging.getLogger(__name__)

PROCESS_NAME = "can_driver"

__all__ = ["PROCESS_NAME", "REJECT_REASONS", "STAGES", "CanDriver", "CanDriverProcess"]

#: Why a JointCommand was not forwarded (the keys of the health message's "rejected").
REJECT_REASONS = (
    "stale",  # older than deadline_s
    "blocked_lifecycle",  # lifecycle not TEACHING/IDENTIFYING, or silent
    "blocked_enabling",  # enabling device released, e-stop chain open, or I/O silent
    "blocked_controller",  # controller not servoing (BRAKED/FAULT) or its link is down
    "bad_message",  # undecodable payload, NaN, wrong joint count
    "out_of_range",  # following error, velocity, or a value the protocol cannot carry
    "late_cycle",  # not for the current cycle, or that cycle was already answered
    "blocked_speed",  # the speed monitor tripped and the lifecycle still runs
    "blocked_bus",  # a CAN bus fault is latched (a bus-off, a burst of errors)
    "blocked_lost",  # too many lost command cycles, until the cell is stopped
)

#: Stages of one loop cycle the driver times (health "stages"), all on CLOCK_MONOTONIC:
#: decode — the cycle's last frame received → its JointState handed to zenoh;
#: zenoh_out — handed to zenoh → received by the control process;
#: control — received by the control process → its JointCommand handed to zenoh;
#: zenoh_back — handed to zenoh → received here;
#: encode — received here → the answer's frames handed to the CAN bus (checks included);
#: answer — the cycle's last frame received → its computed answer handed to the CAN bus.
STAGES = ("decode", "zenoh_out", "control", "zenoh_back", "encode", "answer")

#: Python's logging levels of the loop's notes, by the number it gives them.
_LEVELS = {10: logging.DEBUG, 20: logging.INFO, 30: logging.WARNING, 40: logging.ERROR}


def _datasheet(n: int) -> Any:
    """The robot description (the datasheet's) for ``n`` joints."""
    from gateway.robot.description import load_description

    desc = load_description()
    if desc.n_dof != n:
        raise ConfigError(f"[can].joints = {n}, but the robot description has {desc.n_dof}")
    return desc


def _needs_start(adapter: CanAdapter) -> bool:
    """The adapter brings its link up before the cycle (CANopen), on a python-can bus."""
    return type(adapter).start is not CanAdapter.start


class CanDriver:
    """The CAN driver. ``start()`` opens the links and runs the compiled loop; ``close()``
    brakes.

    Counters and health come from the loop (refreshed at HEALTH_RATE_HZ, and on demand by
    :meth:`health`). Raises ConfigError for a config the compiled core refuses.
    """

    #: Period of health messages and of draining the loop's notes [s].
    HEALTH_PERIOD_S = 1.0 / HEALTH_RATE_HZ
    #: How long close() waits for the health thread [s].
    JOIN_TIMEOUT_S = 2.0

    def __init__(
        self,
        config: CanDriverConfig,
        bus_config: BusConfig,
        *,
        adapter: CanAdapter | None = None,
        brake_on_signals: bool = False,
    ) -> None:
        self.config = config
        #: the loop brakes by itself on the stop signals this process handles (:meth:`open`)
        self.brake_on_signals = brake_on_signals
        self.bus_config = bus_config
        self.keys = bus_config.keys
        if adapter is None:
            adapter_cls = load_adapter(ADAPTER_GROUP, config.adapter)
            adapter = adapter_cls.from_config(config)
        self.adapter: CanAdapter = adapter
        require(
            adapter.n_joints == config.joints,
            "[can].joints",
            f"{config.joints} but the adapter is built for {adapter.n_joints}",
        )
        require(
            config.heartbeat_period_s <= adapter.host_heartbeat_timeout_s / 2,
            "[can].heartbeat_period_s",
            f"{config.heartbeat_period_s} s; the controller faults after "
            f"{adapter.host_heartbeat_timeout_s} s without a heartbeat, so send at least twice "
            "within that",
        )
        self._stored_zero = None
        if config.current_zero_file:
            try:
                zero, samples, noise = read_stored_zero(config.current_zero_file, config.joints)
            except StoredZeroError as exc:
                raise ConfigError(f"[can].current_zero_file: {exc}") from None
            self._stored_zero = (zero.tolist(), int(samples), noise.tolist())
        desc = _datasheet(config.joints)
        self._limits = (list(desc.lower_rad), list(desc.upper_rad))
        self._chain = (
            json.dumps(chain_table(desc)) if config.hand_guiding_max_speed_m_s > 0 else None
        )
        # A core now, so a config the compiled core refuses fails here, not at start-up (an
        # adapter with a start-up gets its tables from the config until the start-up ran).
        self._core: Any = self._build_core(static=_needs_start(adapter))
        self._loop: Any = None
        self._session: Any = None
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._closed = False
        self._health: dict[str, Any] = {}
        self._health_lock = threading.Lock()

    def _build_core(self, static: bool = False) -> Any:
        """The compiled core; ``static``: from the tables the config alone gives (before an
        adapter's start-up)."""
        tables = static_tables(self.config) if static else adapter_tables(self.adapter)
        try:
            return _rt.HostCore(
                json.dumps(dataclasses.asdict(self.config)),
                self.config.adapter,
                json.dumps(tables),
                *self._limits,
                self._chain,
                self._stored_zero,
                self.HEALTH_PERIOD_S,
            )
        except ValueError as exc:
            raise ConfigError(f"[can]: {exc}") from None

    # --- counters (the loop keeps them; health reports them) --------------------------------
    def health(self) -> dict[str, Any]:
        """The loop's health entries now (the core's counters, the stages, socket errors)."""
        loop = self._loop
        if loop is None:
            return {}
        health = json.loads(loop.health())
        with self._health_lock:
            self._health = health
        return health

    def _counter(self, name: str) -> Any:
        return self.health().get(name, 0)

    @property
    def rejected(self) -> dict[str, int]:
        return self.health().get("rejected", dict.fromkeys(REJECT_REASONS, 0))

    @property
    def forwarded(self) -> int:
        return self._counter("forwarded")

    @property
    def coasted(self) -> int:
        return self._counter("coasted")

    @property
    def held(self) -> int:
        return self._counter("held")

    @property
    def cycles(self) -> int:
        return self._counter("cycles")

    @property
    def unanswered(self) -> int:
        return self._counter("unanswered")

    @property
    def bad_inputs(self) -> int:
        return self._counter("bad_inputs")

    # --- lifecycle --------------------------------------------------------------------------
    def start(self) -> None:
        """Open the links and start the compiled loop and the health thread."""
        if self._loop is not None or self._closed:
            raise RuntimeError("CanDriver.start() called twice or after close()")
        self.open()

    def open(self) -> None:
        """The adapter's start-up (if it has one), then the loop with its CAN socket and zenoh
        session, and this process's own session for health. On failure everything is closed."""
        if self._closed:
            raise RuntimeError("CanDriver.open() after close()")
        if self._loop is not None:
            return
        setup_bus = None
        try:
            if _needs_start(self.adapter):
                setup_bus = can.Bus(**self.config.transport)
                self.adapter.start(setup_bus)
                self._core = self._build_core()  # the tables the start-up read
            self._session = open_peer(self.bus_config, security.CAN_DRIVER)
            keys = self.keys
            try:
                self._loop = _rt.CanLoop.start(
                    self._core,
                    json.dumps(self.config.transport),
                    peer_config_entries(self.bus_config, security.CAN_DRIVER),
                    {
                        "joint_state": keys.joint_state,
                        "state_window": keys.state_window,
                        "joint_command": keys.joint_command,
                        "lifecycle": keys.lifecycle,
                        "io_state": keys.io_state,
                    },
                    self._brake_signals(),
                )
            except ValueError as exc:
                raise ConfigError(f"[can]: {exc}") from None
            except OSError as exc:
                raise LinkTimeoutError(str(exc)) from None
        except BaseException:
            self.close()
            raise
        finally:
            if setup_bus is not None:
                setup_bus.shutdown()  # the loop has its own socket, opened before this closed
        self._thread = threading.Thread(target=self._report, name="can-health", daemon=True)
        self._thread.start()
        log.info(
            "CAN driver up (compiled cycle): adapter %s, %d joints, CAN %s, zenoh %s",
            self.adapter.name,
            self.config.joints,
            self.config.transport.get("channel", "?"),
            self.bus_config.endpoint,
        )

    def _brake_signals(self) -> list[int]:
        """The stop signals the loop brakes on: with :attr:`brake_on_signals`, those this
        process has a Python handler for (gateway/signals.py's, installed before open). A
        signal left at its default disposition is not passed: the loop's handler chains to the
        one before it, and the default action (ending the process) would be lost."""
        if not self.brake_on_signals:
            return []
        return [int(s) for s in STOP_SIGNALS if callable(signal.getsignal(s))]

    def close(self) -> None:
        """Ask the controller to brake (and hold) at once, stop, release every link. Never
        raises. The loop sends the BRAKE before it stops (drivers/can/rt driver_loop.rs)."""
        if self._closed:
            return
        self._closed = True
        loop, self._loop = self._loop, None
        if loop is not None:
            try:
                began_s = time.monotonic()
                signal_s = loop.signal_s
                sent = loop.close()
                # the frames go out first, then the loop thread is joined and its zenoh session
                # closed: the line's own time is not the send time; the close's start is
                after = ""
                if signal_s is not None:
                    after = f", {(began_s - signal_s) * 1e3:.1f} ms after the stop signal"
                    if loop.braked_on_signal:
                        after += ", whose BRAKE the loop had sent"
                log.info(
                    "BRAKE requested on exit (%d frames sent; the close began %.1f ms before%s)",
                    sent,
                    (time.monotonic() - began_s) * 1e3,
                    after,
                )
            except OSError as exc:
                log.error("%s", exc)
            self._drain_notes(loop)
        self._stop.set()
        thread, self._thread = self._thread, None
        if thread is not None and thread is not threading.current_thread():
            thread.join(self.JOIN_TIMEOUT_S)
        if self._session is not None:
            try:
                self._session.close()
            except Exception:
                log.exception("could not close the zenoh session")
        self._session = None

    def __enter__(self) -> CanDriver:
        self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    @property
    def running(self) -> bool:
        loop = self._loop
        return loop is not None and loop.running

    @property
    def failed(self) -> str | None:
        """Why the loop thread ended, if it ended on an error."""
        loop = self._loop
        return None if loop is None else loop.failed

    def link_ok(self) -> bool:
        loop = self._loop
        return loop is not None and loop.link_ok()

    # --- off the cycle: health and notes -----------------------------------------------------
    def _report(self) -> None:
        next_s = time.monotonic()
        while not self._stop.wait(max(0.0, next_s - time.monotonic())):
            next_s += self.HEALTH_PERIOD_S
            loop, session = self._loop, self._session
            if loop is None or session is None:
                continue
            self._drain_notes(loop)
            health = {"process": PROCESS_NAME, "stamp_s": time.monotonic(), **self.health()}
            try:
                session.put(self.keys.health(PROCESS_NAME), encode_json(health))
            except Exception as exc:
                log.error("cannot publish health: %s", exc)

    @staticmethod
    def _drain_notes(loop: Any) -> None:
        for level, _key, message in loop.take_notes():
            log.log(_LEVELS.get(level, logging.WARNING), "%s", message)


# --- process entry points -------------------------------------------------------------------
class CanDriverProcess:
    """The CAN driver as a product process (:func:`gateway.runner.run_service`): its loop
    thread serves until the stop event (SIGTERM/SIGINT), then :meth:`close` brakes the arm.

    Raises ConfigError for a bad cell config; :meth:`run` re-raises the error that stopped
    the loop."""

    def __init__(
        self,
        cell_config_path: str | Path,
        bus_endpoint: str | None = None,
        *,
        stop_event: threading.Event | None = None,
    ) -> None:
        can_cfg, bus_cfg = load_can_config(cell_config_path)
        self.driver = CanDriver(
            can_cfg, bus_cfg.with_overrides(bus_endpoint), brake_on_signals=True
        )
        self.stop_event = stop_event or threading.Event()

    def open(self) -> None:
        self.driver.start()

    def run(self, notifier: Any = None) -> None:
        while not self.stop_event.wait(0.1):
            if not self.driver.running:
                break
        if self.driver.failed is not None:
            raise RuntimeError(f"CAN driver loop failed: {self.driver.failed}")

    def close(self) -> None:
        self.driver.close()


def configure_parser(p: argparse.ArgumentParser) -> argparse.ArgumentParser:
    """Add the CAN driver's options to ``p`` (used by ``leadthrough can-driver``)."""
    p.description = (
        "Bridge the robot controller's CAN link to the zenoh bus. Publishes the joint state of "
        "every controller cycle; forwards the control process's joint commands only while the "
        "cell is TEACHING (or IDENTIFYING) with the enabling device held; otherwise tells the "
        "controller to hold "
        "still, and to brake whenever the gateway is silent or stopped. Stop it with Ctrl-C or "
        "SIGTERM: it asks the controller to brake before it exits."
    )
    p.add_argument(
        "--config",
        required=True,
        metavar="CELL.toml",
        help="cell configuration file; its [can] section picks the adapter, the CAN interface "
        "(transport) and the limits, its [bus] section the zenoh router",
    )
    p.add_argument(
        "--bus",
        metavar="ENDPOINT",
        default=None,
        help="zenoh router to connect to, e.g. tcp/127.0.0.1:7460 (default: environment "
        "variable LEADTHROUGH_BUS_ENDPOINT, then [bus].endpoint of the cell config)",
    )
    return p


def cli_main(args: argparse.Namespace) -> int:
    """Run from parsed arguments (:func:`gateway.runner.run_service`): 0 on a clean stop,
    EXIT_CONFIG (78) for a bad config, 1 for other errors."""
    return run_service(
        PROCESS_NAME,
        lambda: CanDriverProcess(args.config, args.bus),
        place=getattr(args, "place", None),
    )


def main(argv: list[str] | None = None) -> int:
    parser = configure_parser(argparse.ArgumentParser(prog="python -m drivers.can.driver"))
    return cli_main(parser.parse_args(argv))


if __name__ == "__main__":
    raise SystemExit(main())
