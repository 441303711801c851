"""`leadthrough view`: the bus live in Foxglove (or any Foxglove WebSocket client).

A Foxglove WebSocket server (foxglove-sdk) on ``--host``/``--port`` (default 127.0.0.1:8765)
advertises one channel per bus key and message kind, with the recordings' JSON Schemas
(gateway/mcap_json.py): joint states and their commands, the state windows, cylinder pressures
and the safety inputs, the lifecycle, every process's health. In Foxglove: *Open connection* →
*Foxglove WebSocket* → ``ws://HOST:PORT``, then plot ``lt/state/joints.q_rad[0]`` and so on.

It joins the bus as the ``observer`` identity (subscribe only): it can see everything and
command nothing. The zenoh callback only transcodes and hands the message to the SDK, which
queues it per client (a slow browser drops its own oldest messages, never the bus's).
"""

from __future__ import annotations

import argparse
import logging
import threading
import time
from pathlib import Path
from typing import Any

from gateway import mcap_json
from gateway.bus import BusConfig, bus_config_from, open_client, undeclare_all
from gateway.bus_security import OBSERVER
from gateway.config import load_toml
from gateway.signals import StopSignals

log = logging.getLogger("leadthrough.view")


class LiveView:
    """Serve ``<prefix>/**`` of ``bus`` to Foxglove WebSocket clients on ``host:port`` (port 0:
    any free port; :attr:`port` tells which)."""

    def __init__(self, bus: BusConfig, host: str = "127.0.0.1", port: int = 8765) -> None:
        self.bus, self.host, self.requested_port = bus, host, port
        self._lock = threading.Lock()
        self._channels: dict[tuple[str, str], Any] = {}
        self._context: Any = None
        self._server: Any = None
        self._session: Any = None
        self._sub: Any = None
        self.count = 0

    @property
    def port(self) -> int:
        return int(self._server.port) if self._server is not None else 0

    def start(self) -> None:
        import foxglove

        self._context = foxglove.Context()
        self._server = foxglove.start_server(
            name="leadthrough", host=self.host, port=self.requested_port, context=self._context
        )
        try:
            self._session = open_client(self.bus, identity=OBSERVER)
            self._sub = self._session.declare_subscriber(
                f"{self.bus.key_prefix}/**", self._on_sample
            )
        except BaseException:
            self.stop()
            raise
        log.info("live view on ws://%s:%d (bus %s)", self.host, self.port, self.bus.endpoint)

    def _on_sample(self, sample: Any) -> None:
        key = str(sample.key_expr)
        kind, data = mcap_json.to_record(sample.payload.to_bytes(), time.monotonic_ns())
        with self._lock:
            channel = self._channels.get((key, kind))
            if channel is None:
                channel = self._channel(key, kind)
                self._channels[(key, kind)] = channel
            self.count += 1
        channel.log(data, log_time=time.time_ns())

    def _channel(self, key: str, kind: str) -> Any:
        import foxglove

        # One topic per channel: a key's undecodable payloads get a topic of their own.
        topic = key if kind != "Undecodable" else f"{key}/undecodable"
        schema = foxglove.Schema(
            name=mcap_json.PREFIX + kind,
            encoding=mcap_json.SCHEMA_ENCODING,
            data=mcap_json.schema_bytes(kind),
        )
        return foxglove.Channel(
            topic,
            schema=schema,
            message_encoding=mcap_json.MESSAGE_ENCODING,
            context=self._context,
        )

    def stop(self) -> None:
        """Undeclare, close the session, stop the server (idempotent)."""
        undeclare_all([self._sub])
        self._sub = None
        if self._session is not None:
            self._session.close()
            self._session = None
        with self._lock:
            for channel in self._channels.values():
                channel.close()
            self._channels.clear()
        if self._server is not None:
            self._server.stop()
            self._server = None


def configure_parser(p: argparse.ArgumentParser) -> None:
    p.description = (
        "Serve the bus live to Foxglove (WebSocket): joint states, commands, pressures, "
        "lifecycle, health. Connect Foxglove to ws://HOST:PORT. Until Ctrl-C."
    )
    p.add_argument("--config", type=Path, default=None, help="cell config TOML (for [bus])")
    p.add_argument("--bus", default=None, help="zenoh endpoint of the gateway")
    p.add_argument("--host", default="127.0.0.1", help="address to serve on")
    p.add_argument("--port", type=int, default=8765, help="port to serve on (0: any free one)")
    p.add_argument("--duration", type=float, default=None, help="stop after this many seconds")


def cli_main(args: argparse.Namespace) -> int:
    bus = BusConfig()
    if args.config:
        bus = bus_config_from(load_toml(args.config), str(args.config))
    view = LiveView(bus.with_overrides(args.bus), args.host, args.port)
    stop = threading.Event()
    with StopSignals(stop):
        view.start()
        print(f"live view: connect Foxglove to ws://{args.host}:{view.port}", flush=True)
        try:
            stop.wait(args.duration)
        finally:
            view.stop()
    log.info("%d messages served", view.count)
    return 0
