"""The CAN driver process: the robot controller's CAN link on one side, the zenoh bus on the other.

The decisions of every control cycle — which frames complete a cycle, whether and how it is
answered (forwarded command, coast, hold), servo requests and heartbeats — live in the pure
:class:`drivers.can.core.HostCore` (read its docstring for the rules). This module is the shell
around it: it owns the CAN bus and the zenoh session, feeds the core what arrives, sends and
publishes what the core returns, and times the loop's stages.

Threads: the loop thread blocks in ``bus.recv`` until a frame arrives or the core's next
deadline (an answer, a heartbeat) is due — no polling; zenoh callbacks decode, decide and send
under one lock and never wait for anything but that lock. A zenoh callback that answers a cycle
sends its frames itself, so the answer leaves as soon as the command arrives.
"""

from __future__ import annotations

import argparse
import logging
import socket
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import can

from drivers.can.adapter import ADAPTER_GROUP, CanAdapter
from drivers.can.config import CanDriverConfig, load_can_config
from drivers.can.core import COMMAND, REJECT_REASONS, HostCore
from drivers.can.current_zero import StoredZeroError, read_stored_zero
from drivers.registry import load_adapter
from gateway import bus_security as security
from gateway.bus import (
    BusConfig,
    declare_loop_publisher,
    on_receiving_thread,
    open_peer,
    undeclare_all,
)
from gateway.config import require
from gateway.errors import ConfigError, LinkTimeoutError
from gateway.latency import Histogram
from gateway.messages import HEALTH_RATE_HZ, encode_json
from gateway.ratelog import RateLimitedLog
from gateway.runner import run_service

log = logging.getLogger(__name__)

PROCESS_NAME = "can_driver"

__all__ = ["PROCESS_NAME", "REJECT_REASONS", "STAGES", "CanDriver", "CanDriverProcess"]

#: Stages of one loop cycle the driver times (health "stages"), all on CLOCK_MONOTONIC:
#: decode — the cycle's last frame received → its JointState handed to zenoh;
#: zenoh_out — handed to zenoh → received by the control process;
#: control — received by the control process → its JointCommand handed to zenoh;
#: zenoh_back — handed to zenoh → received here;
#: encode — received here → the answer's frames handed to the CAN bus (checks included);
#: answer — the cycle's last frame received → its computed answer handed to the CAN bus.
STAGES = ("decode", "zenoh_out", "control", "zenoh_back", "encode", "answer")


class _DropPartialReadNotes(logging.Filter):
    """python-can's socketcand client warns "Got incomplete message" whenever one TCP read ends
    mid-frame (it then waits for the rest: nothing is lost). Under load that is every few
    cycles; keep its other warnings (bad data, invalid frames)."""

    def filter(self, record: logging.LogRecord) -> bool:
        return not str(record.msg).startswith("Got incomplete message")


_SOCKETCAND_LOG = logging.getLogger("can.interfaces.socketcand.socketcand")


def _quiet_socketcand_partial_reads() -> None:
    if not any(isinstance(f, _DropPartialReadNotes) for f in _SOCKETCAND_LOG.filters):
        _SOCKETCAND_LOG.addFilter(_DropPartialReadNotes())


def _await_socketcand_server(transport: dict[str, Any], timeout_s: float) -> None:
    """Wait until the socketcand server accepts TCP connections, or raise LinkTimeoutError.

    python-can's client retries a refused connection in a tight loop for 10 s, logging each
    attempt; checking first turns "the virtual controller is not up" into one clear error.
    """
    host, port = transport["host"], transport["port"]
    deadline = time.monotonic() + timeout_s
    while True:
        try:
            with socket.create_connection((host, port), timeout=0.5):
                return
        except OSError as exc:
            if time.monotonic() >= deadline:
                raise LinkTimeoutError(
                    f"no socketcand server at {host}:{port} after {timeout_s:g} s ({exc}); "
                    "is the virtual controller (leadthrough sim) running?"
                ) from None
            time.sleep(0.1)


class CanDriver:
    """The CAN driver. ``start()`` opens the links and runs the loop thread; ``close()`` brakes.

    ``clock`` returns monotonic seconds; every stamp and deadline uses it. ``can_bus`` and
    ``session`` may be injected (then the caller closes them); otherwise they are opened from
    ``config.transport`` and ``bus_config``.
    """

    #: Longest the loop sleeps in bus.recv with nothing due: a lifecycle change or an operator
    #: reset (which arrive through callbacks) turns into a request frame within this [s].
    MAX_WAIT_S = 0.005
    #: Most frames taken in one wake-up before the deadlines are checked again.
    MAX_BURST = 64
    #: Longest a CAN send may block (socketcan tx queue full) [s].
    SEND_TIMEOUT_S = 0.005
    #: Period of health messages [s].
    HEALTH_PERIOD_S = 1.0 / HEALTH_RATE_HZ
    #: Rate limit of repeated log records, per reason [s].
    LOG_PERIOD_S = 1.0
    #: How long stop() waits for the loop thread [s].
    JOIN_TIMEOUT_S = 2.0
    #: How long open() waits for a socketcand server to accept connections [s].
    CONNECT_TIMEOUT_S = 5.0

    def __init__(
        self,
        config: CanDriverConfig,
        bus_config: BusConfig,
        *,
        clock: Callable[[], float] = time.monotonic,
        adapter: CanAdapter | None = None,
        can_bus: can.BusABC | None = None,
        session: Any = None,
    ) -> None:
        self.config = config
        self.bus_config = bus_config
        self.keys = bus_config.keys
        self._clock = clock
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
        self._rlog = RateLimitedLog(log, self.LOG_PERIOD_S, clock)
        stored_zero = None
        if config.current_zero_file:
            try:
                stored_zero = read_stored_zero(config.current_zero_file, config.joints)
            except StoredZeroError as exc:
                raise ConfigError(f"[can].current_zero_file: {exc}") from None
        self.core = HostCore(
            config,
            adapter,
            note=lambda level, key, msg: self._rlog(level, key, "%s", msg),
            health_period_s=self.HEALTH_PERIOD_S,
            stored_zero=stored_zero,
        )

        self._bus = can_bus
        self._owns_bus = can_bus is None
        self._session = session
        self._owns_session = session is None
        self._subscribers: list[Any] = []
        self._publisher: Any = None
        self._window_publisher: Any = None

        self._lock = threading.Lock()  # guards the core, the stage timers and every CAN send
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._closing = False
        self._closed = False
        self.failed: BaseException | None = None  #: the error that ended the loop, if any
        self.stages = {name: Histogram() for name in STAGES}
        #: (cycle, its stamp, when its JointState was handed to zenoh) of the newest cycle
        self._published: tuple[int, float, float] = (-1, 0.0, 0.0)
        self.send_errors = 0
        self.recv_errors = 0

    # --- counters (the core keeps them; health reports them) --------------------------------
    @property
    def rejected(self) -> dict[str, int]:
        return self.core.rejected

    @property
    def forwarded(self) -> int:
        return self.core.forwarded

    @property
    def coasted(self) -> int:
        return self.core.coasted

    @property
    def held(self) -> int:
        return self.core.held

    @property
    def cycles(self) -> int:
        return self.core.cycles

    @property
    def unanswered(self) -> int:
        return self.core.unanswered

    @property
    def bad_inputs(self) -> int:
        return self.core.bad_inputs

    # --- lifecycle --------------------------------------------------------------------------
    def start(self) -> None:
        """:meth:`open` the links, then run :meth:`spin_once` in the loop thread."""
        if self._thread is not None or self._closed:
            raise RuntimeError("CanDriver.start() called twice or after close()")
        self.open()
        self._thread = threading.Thread(target=self._loop, name="can-driver", daemon=True)
        self._thread.start()

    def open(self) -> None:
        """Open the CAN bus and the zenoh session and subscribe; no thread (tests may then
        drive :meth:`spin_once` themselves). Idempotent; on failure everything is closed."""
        if self._closed:
            raise RuntimeError("CanDriver.open() after close()")
        if self._publisher is not None:
            return
        try:
            if self._bus is None:
                if self.config.transport.get("interface") == "socketcand":
                    _await_socketcand_server(self.config.transport, self.CONNECT_TIMEOUT_S)
                    _quiet_socketcand_partial_reads()
                self._bus = can.Bus(**self.config.transport)
            # The link's start-up (CANopen: NMT and the drives' SDO configuration).
            self.adapter.start(self._bus)
            if self._session is None:
                self._session = open_peer(self.bus_config, security.CAN_DRIVER)
            session, keys = self._session, self.keys
            self._publisher = declare_loop_publisher(session, keys.joint_state)
            self._window_publisher = session.declare_publisher(keys.state_window)  # drops
            self._subscribers = [
                session.declare_subscriber(keys.lifecycle, self._on_lifecycle),
                session.declare_subscriber(keys.io_state, self._on_io_state),
                session.declare_subscriber(
                    keys.joint_command, on_receiving_thread(self._on_joint_command)
                ),
            ]
        except BaseException:
            self.close()
            raise
        log.info(
            "CAN driver up: adapter %s, %d joints, CAN %s, zenoh %s",
            self.adapter.name,
            self.config.joints,
            getattr(self._bus, "channel_info", "?"),
            self.bus_config.endpoint,
        )

    def stop(self) -> None:
        """Stop the loop thread. Idempotent; never raises."""
        self._stop.set()
        thread, self._thread = self._thread, None
        if thread is not None and thread is not threading.current_thread():
            thread.join(self.JOIN_TIMEOUT_S)
            if thread.is_alive():
                log.error("CAN driver loop did not stop within %.1f s", self.JOIN_TIMEOUT_S)

    def close(self) -> None:
        """Ask the controller to brake (and hold) at once, stop, release every link. Never
        raises.

        The BRAKE goes out before the loop thread is joined (every send checks ``_closing``
        under the lock, so nothing follows it): a controller reads it at its next cycle
        boundary, and a cycle it misses is one more cycle of the arm at speed (8 ms, 1.7 mm
        at 215 mm/s on the virtual cell)."""
        with self._lock:
            if self._closed:
                self._closing = True
                frames_due = False
            else:
                self._closing = True  # the loop and the callbacks stop sending from here on
                self._closed = frames_due = True
            if frames_due and self._bus is not None:
                try:
                    frames = self.core.closing_frames()
                except Exception:
                    log.exception("could not build the BRAKE request and hold set on exit")
                    frames = []
                if frames and not self._send_locked(frames):
                    log.error("could not send the BRAKE request and hold set on exit")
                elif frames:
                    log.info("BRAKE requested on exit (%d frames sent)", len(frames))
        self.stop()
        if not frames_due:
            return
        undeclare_all([*self._subscribers, self._publisher, self._window_publisher])
        self._subscribers, self._publisher, self._window_publisher = [], None, None
        if self._owns_session and self._session is not None:
            try:
                self._session.close()
            except Exception:
                log.exception("could not close the zenoh session")
        self._session = None
        if self._owns_bus and self._bus is not None:
            try:
                self._bus.shutdown()
            except Exception:
                log.exception("could not shut the CAN bus down")
        self._bus = None

    def __enter__(self) -> CanDriver:
        self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    @property
    def running(self) -> bool:
        thread = self._thread
        return thread is not None and thread.is_alive()

    def link_ok(self) -> bool:
        with self._lock:
            return self.core.link_ok(self._clock())

    # --- main loop --------------------------------------------------------------------------
    def _loop(self) -> None:
        try:
            while not self._stop.is_set():
                self.spin_once()
        except Exception as exc:  # a bug: stop answering; close() brakes
            self.failed = exc
            log.exception("CAN driver loop failed; stopping (the controller will brake)")
            self._stop.set()

    def spin_once(self, recv_timeout_s: float | None = None) -> None:
        """Receive a frame (waiting until the core's next deadline at most) and every frame
        queued behind it, then run the deadline, request, heartbeat and health checks. The
        loop thread calls this; tests without the thread call it directly with a timeout (0:
        do not wait)."""
        bus = self._bus
        if bus is None:
            raise RuntimeError("CanDriver is not open")
        if recv_timeout_s is None:
            with self._lock:
                due = self.core.next_tick_s()
            recv_timeout_s = min(max(due - self._clock(), 0.0), self.MAX_WAIT_S)
        try:
            msg = bus.recv(timeout=recv_timeout_s)
        except can.CanError as exc:
            self.recv_errors += 1
            self._rlog(logging.ERROR, "recv", "CAN receive failed: %s", exc)
            self._stop.wait(0.01)
            msg = None
        now = self._clock()
        if msg is None:
            self._periodic(now)
            return
        # A cycle's frames arrive back to back: take every one already queued (one wake-up,
        # one deadline check per burst rather than per frame), at most MAX_BURST of them.
        for taken in range(1, self.MAX_BURST + 1):
            self._on_frame(msg, now)
            if taken == self.MAX_BURST:
                break  # the rest wait in the socket for the next spin, none received and lost
            try:
                msg = bus.recv(timeout=0.0)
            except can.CanError:
                break  # the next spin reports it
            if msg is None:
                break
            now = self._clock()
        self._periodic(self._clock())

    def _on_frame(self, msg: can.Message, now: float) -> None:
        with self._lock:
            if self._closing:
                return
            result = self.core.on_frame(msg, now)
            if result.frames:
                self._send_locked(result.frames)
            if result.state is None:
                return
            pending = self.core.pending
            assert pending is not None
            publisher, window_publisher = self._publisher, self._window_publisher
            handed_s = self._clock()
            self._published = (pending.cycle, now, handed_s)
            self.stages["decode"].add(handed_s - now)
        if publisher is not None:
            try:
                publisher.put(result.state)
                if result.window is not None and window_publisher is not None:
                    window_publisher.put(result.window)
            except Exception as exc:  # zenoh; the controller is still answered (hold)
                self._rlog(logging.ERROR, "put", "cannot publish the joint state: %s", exc)

    def _periodic(self, now: float) -> None:
        health: dict[str, Any] | None = None
        with self._lock:
            if self._closing:
                return
            frames = self.core.on_tick(now)
            if frames:
                self._send_locked(frames)
            if self.core.health_due(now):
                health = self._health_locked(now)
        session = self._session
        if health is not None and session is not None:
            try:
                session.put(self.keys.health(PROCESS_NAME), encode_json(health))
            except Exception as exc:
                self._rlog(logging.ERROR, "health", "cannot publish health: %s", exc)

    def _send_locked(self, frames: list[can.Message]) -> bool:
        bus = self._bus
        if bus is None:
            return False
        try:
            for frame in frames:
                bus.send(frame, timeout=self.SEND_TIMEOUT_S)
        except (can.CanError, OSError) as exc:
            self.send_errors += 1
            self._rlog(logging.ERROR, "send", "CAN send failed: %s", exc)
            return False
        return True

    def _health_locked(self, now: float) -> dict[str, Any]:
        return {
            "process": PROCESS_NAME,
            "stamp_s": now,
            **self.core.health(now),
            "send_errors": self.send_errors,
            "recv_errors": self.recv_errors,
            "stages": {name: h.summary() for name, h in self.stages.items()},
        }

    # --- zenoh callbacks (never block, never sleep) ------------------------------------------
    def _on_lifecycle(self, sample: Any) -> None:
        now = self._clock()
        payload = sample.payload.to_bytes()
        with self._lock:
            self.core.on_lifecycle(payload, now)

    def _on_io_state(self, sample: Any) -> None:
        now = self._clock()
        payload = sample.payload.to_bytes()
        with self._lock:
            self.core.on_io(payload, now)

    def _on_joint_command(self, sample: Any) -> None:
        now = self._clock()
        payload = sample.payload.to_bytes()
        with self._lock:
            if self._closing:
                return
            result = self.core.on_command(payload, now)
            if not result.frames:
                return
            sent = self._send_locked(result.frames)
            if sent and result.answer == COMMAND and result.command is not None:
                self._time_stages(result.command, now, self._clock())

    def _time_stages(self, cmd: Any, rx_s: float, sent_s: float) -> None:
        cycle, _stamp_s, handed_s = self._published
        st = self.stages
        st["encode"].add(sent_s - rx_s)
        st["zenoh_back"].add(rx_s - cmd.sent_stamp_s)
        st["answer"].add(sent_s - cmd.state_stamp_s)
        if cmd.state_rx_stamp_s > 0.0:
            st["control"].add(cmd.sent_stamp_s - cmd.state_rx_stamp_s)
            if cycle == cmd.cycle:
                st["zenoh_out"].add(cmd.state_rx_stamp_s - handed_s)


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
        self.driver = CanDriver(can_cfg, bus_cfg.with_overrides(bus_endpoint))
        self.stop_event = stop_event or threading.Event()

    def open(self) -> None:
        self.driver.start()

    def run(self, notifier: Any = None) -> None:
        while not self.stop_event.wait(0.1):
            if not self.driver.running:
                break
        if self.driver.failed is not None:
            raise self.driver.failed

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
    return run_service(PROCESS_NAME, lambda: CanDriverProcess(args.config, args.bus))


def main(argv: list[str] | None = None) -> int:
    parser = configure_parser(argparse.ArgumentParser(prog="python -m drivers.can.driver"))
    return cli_main(parser.parse_args(argv))


if __name__ == "__main__":
    raise SystemExit(main())
