"""Modbus driver process: cylinder pressures and safety inputs between the I/O module and zenoh.

Every ``poll_period_s`` the poll thread

1. writes the newest accepted :class:`~gateway.messages.PressureSetpoint`, if one arrived;
2. reads every input and publishes one :class:`~gateway.messages.IoState` on ``keys.io_state``,
   stamped with ``time.monotonic()`` taken just before the read request went out.

A poll that fails in any way (no link, timeout, exception response, a value that does not
decode or is implausible) publishes **nothing**. Consumers age IoState and treat stale I/O as
"enabling device released", so silence is the safe answer; a stale or guessed value is not.
The error is logged (rate-limited) and counted in the health message; link errors close the
connection and reconnect: at once after the first failure of a healthy link, then with
exponential backoff.

Set-points arrive in a zenoh callback, which must not block: it only decodes and checks them
(finite, ``0 <= p <= max_setpoint_bar``) and drops them into a one-slot mailbox (newest wins);
the poll thread does the Modbus write. When set-points stop arriving, the driver keeps the last
one and does not ramp the pressure down: the assist cylinders carry part of the arm's weight, so
dropping their pressure would let the arm sag onto its brakes (or onto the operator's hands).
Releasing the arm safely is the control process's decision, made with full knowledge of the
robot state, not a side-effect of a message gap. For the same reason the last written
set-point is written again after every reconnect (the module may have power-cycled).

Health (JSON, ~``HEALTH_RATE_HZ``) on ``keys.health("modbus_driver")``::

    {"process": "modbus_driver", "stamp_s": ..., "link_ok": bool, "polls": int, "errors": int,
     "last_error": str, "setpoints_written": int, "setpoints_rejected": int}

``link_ok`` is true while the last poll published an IoState; ``polls`` counts published
IoStates; ``errors`` counts failed connects, polls and writes.

Run: ``python -m drivers.modbus.driver --config CELL.toml [--bus ENDPOINT]``.
"""

from __future__ import annotations

import argparse
import logging
import math
import sys
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any, Generic, TypeVar

import zenoh

from drivers.modbus.adapter import PressureIoAdapter, create_adapter
from drivers.modbus.client import ModbusLinkError
from drivers.modbus.config import ModbusDriverConfig
from gateway import bus_security as security
from gateway.bus import bus_config_from, open_peer, undeclare_all
from gateway.config import load_toml
from gateway.errors import LeadthroughError, MessageError, ModbusReplyError
from gateway.messages import HEALTH_RATE_HZ, IoState, Keys, PressureSetpoint, encode_json
from gateway.ratelog import RateLimitedLog
from gateway.runner import run_service

log = logging.getLogger(__name__)

PROCESS_NAME = "modbus_driver"
T = TypeVar("T")


class _Mailbox(Generic[T]):
    """One-slot hand-over between threads; a new item replaces an untaken one."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._item: T | None = None

    def put(self, item: T) -> None:
        with self._lock:
            self._item = item

    def put_if_empty(self, item: T) -> None:
        with self._lock:
            if self._item is None:
                self._item = item

    def take(self) -> T | None:
        with self._lock:
            item, self._item = self._item, None
        return item


class ModbusDriver:
    """Polls the I/O module, publishes IoState and health, writes pressure set-points.

    :param config: the ``[modbus]`` section.
    :param session: an open zenoh session (owned by the caller, who closes it).
    :param keys: key expressions of the cell.
    :param adapter: the I/O port; by default built from ``config.adapter``.
    :param clock: monotonic clock [s] used for stamps and scheduling (tests inject one and call
        :meth:`step` directly instead of :meth:`start`).
    """

    #: Reconnect backoff: first retry after MIN, doubling up to MAX [s].
    RECONNECT_MIN_S = 0.1
    RECONNECT_MAX_S = 2.0
    #: At most one log line per error kind per period [s].
    ERROR_LOG_PERIOD_S = 5.0
    HEALTH_PERIOD_S = 1.0 / HEALTH_RATE_HZ
    #: How long :meth:`stop` waits for the poll thread [s] (a blocked request takes timeout_s).
    JOIN_TIMEOUT_S = 5.0

    def __init__(
        self,
        config: ModbusDriverConfig,
        session: zenoh.Session,
        keys: Keys,
        *,
        adapter: PressureIoAdapter | None = None,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.config = config
        self.adapter = adapter if adapter is not None else create_adapter(config)
        self._session = session
        self._keys = keys
        self._clock = clock
        self._log = RateLimitedLog(log, self.ERROR_LOG_PERIOD_S, clock)
        self._setpoints: _Mailbox[tuple[float, float]] = _Mailbox()
        self._rejects: _Mailbox[str] = _Mailbox()
        self._reject_lock = threading.Lock()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._pub_io: zenoh.Publisher | None = None
        self._pub_health: zenoh.Publisher | None = None
        self._sub: zenoh.Subscriber | None = None
        self._connected = False
        self._backoff_s = self.RECONNECT_MIN_S
        #: the last poll succeeded (its link's next failure reconnects at once)
        self._healthy = False
        self._next_connect_s = -math.inf
        self._next_health_s = -math.inf
        self._last_written: tuple[float, float] | None = None
        self.link_ok = False
        self.polls = 0
        self.errors = 0
        self.last_error = ""
        self.setpoints_written = 0
        self.setpoints_rejected = 0

    # Lifecycle ---------------------------------------------------------------------------

    def declare(self) -> None:
        """Declare the publishers and the set-point subscriber (done by :meth:`start`)."""
        if self._pub_io is None:
            self._pub_io = self._session.declare_publisher(self._keys.io_state)
            self._pub_health = self._session.declare_publisher(self._keys.health(PROCESS_NAME))
            self._sub = self._session.declare_subscriber(
                self._keys.pressure_setpoint, self._on_setpoint
            )

    def start(self) -> None:
        """Declare on zenoh and start the poll thread."""
        if self._thread is not None:
            raise RuntimeError("ModbusDriver already started")
        self.declare()
        self._stop.clear()
        self._thread = threading.Thread(target=self._run, name="modbus-poll", daemon=True)
        self._thread.start()

    @property
    def running(self) -> bool:
        return self._thread is not None and self._thread.is_alive()

    def stop(self) -> None:
        """Stop and join the poll thread (idempotent). The set-point in the valves stays."""
        self._stop.set()
        thread, self._thread = self._thread, None
        if thread is not None:
            thread.join(self.JOIN_TIMEOUT_S + self.config.timeout_s)
            if thread.is_alive():
                log.error("modbus poll thread did not stop within %.1f s", self.JOIN_TIMEOUT_S)

    def close(self) -> None:
        """Stop, undeclare from zenoh and close the link. Never raises."""
        try:
            self.stop()
        finally:
            undeclare_all((self._sub, self._pub_io, self._pub_health))
            self._sub = self._pub_io = self._pub_health = None
            try:
                self.adapter.close()
            except Exception as exc:
                log.debug("adapter close failed: %r", exc)
            self._connected = False

    def __enter__(self) -> ModbusDriver:
        self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # Set-point callback (zenoh thread: no I/O, no blocking) -------------------------------

    def check_setpoint(self, p2_bar: float, p3_bar: float) -> str | None:
        """Why a set-point pair must be refused, or None if it may be written."""
        limit = self.config.max_setpoint_bar
        for name, p in (("p2_set_bar", p2_bar), ("p3_set_bar", p3_bar)):
            if not math.isfinite(p):
                return f"{name}={p!r} is not finite"
            if not 0.0 <= p <= limit:
                return f"{name}={p:g} bar outside 0..{limit:g} bar ([modbus].max_setpoint_bar)"
        return None

    def _on_setpoint(self, sample: zenoh.Sample) -> None:
        try:
            msg = PressureSetpoint.from_bytes(sample.payload.to_bytes())
            reason = self.check_setpoint(msg.p2_set_bar, msg.p3_set_bar)
            if reason is None:
                self._setpoints.put((msg.p2_set_bar, msg.p3_set_bar))
                return
        except MessageError as exc:
            reason = str(exc)
        except Exception as exc:  # a callback must never raise into zenoh
            reason = f"unexpected {exc!r}"
        with self._reject_lock:
            self.setpoints_rejected += 1
        self._rejects.put_if_empty(reason)  # the first reason since the last poll is logged

    # Poll thread -------------------------------------------------------------------------

    def _run(self) -> None:
        period = self.config.poll_period_s
        next_poll = self._clock()
        while not self._stop.is_set():
            try:
                self.step()
            except Exception as exc:  # keep polling; the failure is counted and logged
                self._fail("internal", f"unexpected error in poll: {exc!r}", reconnect=True)
                log.debug("poll traceback", exc_info=True)
            next_poll += period
            now = self._clock()
            if next_poll < now:  # overran (slow reply): skip missed polls instead of bursting
                next_poll = now
            self._stop.wait(next_poll - now)

    def step(self) -> IoState | None:
        """One cycle: connect if needed, write a pending set-point, read, publish.

        Returns the published IoState, or None when nothing was published.
        """
        self._log_rejects()
        try:
            return self._poll()
        finally:
            self._publish_health()

    def _poll(self) -> IoState | None:
        if not self._connected and not self._connect():
            return None
        pending = self._setpoints.take()
        if pending is not None:
            try:
                self.adapter.write_setpoints(*pending)
            except ModbusLinkError as exc:
                self._setpoints.put_if_empty(pending)  # retry after the reconnect
                self._fail("write", f"set-point write failed: {exc}", reconnect=True)
                return None
            except ModbusReplyError as exc:
                self._fail("write", f"set-point write {pending} refused by the module: {exc}")
            except ValueError as exc:
                self._fail("write", f"set-point {pending} cannot be encoded: {exc}")
            else:
                self._last_written = pending
                self.setpoints_written += 1
        stamp_s = self._clock()
        try:
            reading = self.adapter.read()
        except ModbusLinkError as exc:
            self._fail("read", f"I/O read failed, no IoState published: {exc}", reconnect=True)
            return None
        except ModbusReplyError as exc:
            self._fail("read", f"I/O reply rejected, no IoState published: {exc}")
            return None
        pressures = reading[:4]
        if not all(math.isfinite(p) for p in pressures):  # a plug-in adapter's slip
            self._fail("read", f"adapter returned non-finite pressures {pressures}")
            return None
        state = IoState(stamp_s, *reading)
        if self._pub_io is not None:
            self._pub_io.put(state.to_bytes())
        self.polls += 1
        if not self.link_ok:
            self._log(logging.INFO, "recovered", "I/O polling healthy (%s)", self.config.host)
            self._log.reset("read")
        self.link_ok = True
        self._healthy = True
        self._backoff_s = self.RECONNECT_MIN_S
        return state

    def _connect(self) -> bool:
        now = self._clock()
        if now < self._next_connect_s:
            return False
        try:
            self.adapter.connect()
        except ModbusReplyError as exc:
            self._fail("connect", f"cannot connect to the I/O module: {exc}", reconnect=True)
            return False
        self._connected = True
        self._log.reset("connect")
        log.info("connected to I/O module %s:%d", self.config.host, self.config.port)
        if self._last_written is not None:
            self._setpoints.put_if_empty(self._last_written)
        return True

    def _fail(self, kind: str, message: str, *, reconnect: bool = False) -> None:
        self.errors += 1
        self.last_error = message
        self.link_ok = False
        if reconnect:
            try:
                self.adapter.close()
            except Exception as exc:
                log.debug("adapter close failed: %r", exc)
            self._connected = False
            if self._healthy:
                # The first failure of a healthy link (one lost or late reply) reconnects at
                # the next poll: waiting the backoff on top of the reply timeout would outlast
                # the readers' I/O timeout and fault the cell for a single reply.
                self._healthy = False
                self._next_connect_s = self._clock()
                message += "; reconnecting now"
            else:
                self._next_connect_s = self._clock() + self._backoff_s
                message += f"; reconnecting in {self._backoff_s:.2f} s"
                # Reset only by a successful poll: a module that accepts connections but
                # never answers must not be hammered at the minimum period.
                self._backoff_s = min(2.0 * self._backoff_s, self.RECONNECT_MAX_S)
        self._log(logging.ERROR, kind, "%s", message)

    def _log_rejects(self) -> None:
        reason = self._rejects.take()
        if reason is not None:
            self._log(
                logging.WARNING,
                "setpoint",
                "pressure set-point refused (%d so far): %s",
                self.setpoints_rejected,
                reason,
            )

    def health(self) -> dict[str, Any]:
        """The health message as a dict."""
        return {
            "process": PROCESS_NAME,
            "stamp_s": self._clock(),
            "link_ok": self.link_ok,
            "polls": self.polls,
            "errors": self.errors,
            "last_error": self.last_error,
            "setpoints_written": self.setpoints_written,
            "setpoints_rejected": self.setpoints_rejected,
        }

    def _publish_health(self) -> None:
        now = self._clock()
        if now < self._next_health_s or self._pub_health is None:
            return
        self._next_health_s = now + self.HEALTH_PERIOD_S
        self._pub_health.put(encode_json(self.health()))


# Command line ------------------------------------------------------------------------------


def configure_parser(p: argparse.ArgumentParser) -> argparse.ArgumentParser:
    """Add the driver's options to ``p`` (shared by ``leadthrough`` and ``python -m``)."""
    p.description = (
        "Modbus driver: polls the cell's I/O module (cylinder pressures, enabling device, "
        "e-stop chain), publishes them on the zenoh bus and writes the pressure set-points it "
        "receives. Stops cleanly on Ctrl-C or SIGTERM; the valves keep their last set-point."
    )
    p.add_argument(
        "--config",
        required=True,
        type=Path,
        metavar="CELL.toml",
        help="cell config file; reads its [modbus] and [bus] sections",
    )
    p.add_argument(
        "--bus",
        metavar="ENDPOINT",
        default=None,
        help="zenoh router to connect to, e.g. tcp/127.0.0.1:7460 "
        "(default: $LEADTHROUGH_BUS_ENDPOINT, else [bus].endpoint of the config)",
    )
    p.add_argument(
        "--log-level",
        default="INFO",
        choices=["DEBUG", "INFO", "WARNING", "ERROR"],
        help="log verbosity (default: INFO)",
    )
    return p


class ModbusDriverProcess:
    """The Modbus driver as a product process (:func:`gateway.runner.run_service`): polls the
    I/O module and publishes until the stop event. Raises ConfigError for a bad cell config;
    :meth:`run` raises when the poll thread died."""

    def __init__(self, cell_config_path: Path, bus_endpoint: str | None = None) -> None:
        cell = load_toml(cell_config_path)
        self.bus = bus_config_from(cell, str(cell_config_path)).with_overrides(bus_endpoint)
        self.config = ModbusDriverConfig.from_cell_config(cell, str(cell_config_path))
        self.adapter: PressureIoAdapter = create_adapter(self.config)
        self.stop_event = threading.Event()
        self.session: zenoh.Session | None = None
        self.driver: ModbusDriver | None = None

    def open(self) -> None:
        self.session = open_peer(self.bus, security.MODBUS_DRIVER)
        self.driver = ModbusDriver(self.config, self.session, self.bus.keys, adapter=self.adapter)
        self.driver.start()
        log.info(
            "modbus driver running: I/O %s:%d every %.0f ms, bus %s",
            self.config.host,
            self.config.port,
            self.config.poll_period_s * 1000.0,
            self.bus.endpoint,
        )

    def run(self, notifier: Any = None) -> None:
        assert self.driver is not None
        while not self.stop_event.wait(0.2):
            if not self.driver.running:
                raise LeadthroughError("the Modbus poll thread died")

    def close(self) -> None:
        try:
            if self.driver is not None:
                self.driver.close()
            else:
                self.adapter.close()
        finally:
            if self.session is not None:
                self.session.close()
                self.session = None


def cli_main(args: argparse.Namespace) -> int:
    """Run the driver until SIGTERM/SIGINT (:func:`gateway.runner.run_service`): 0 on a clean
    stop, EXIT_CONFIG (78) on a bad config, 1 on any other failure."""
    level = getattr(args, "log_level", "INFO")
    if level != "DEBUG":
        # pymodbus logs every failed connect itself; the driver reports those rate-limited.
        logging.getLogger("pymodbus").setLevel(logging.CRITICAL)
    return run_service(
        PROCESS_NAME,
        lambda: ModbusDriverProcess(args.config, args.bus),
        log_level=getattr(logging, level, logging.INFO),
        place=getattr(args, "place", None),
    )


def main(argv: list[str] | None = None) -> int:
    parser = configure_parser(argparse.ArgumentParser(prog="python -m drivers.modbus.driver"))
    return cli_main(parser.parse_args(argv))


if __name__ == "__main__":
    sys.exit(main())
