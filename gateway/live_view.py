"""`leadthrough view`: the bus live in Foxglove (or any Foxglove WebSocket client).

A Foxglove WebSocket server (foxglove-sdk) on ``--host``/``--port`` (default 127.0.0.1:8765)
advertises one channel per bus key and message kind, with the recordings' JSON Schemas
(gateway/mcap_json.py): joint states and their commands, the state windows, cylinder pressures
and the safety inputs, the lifecycle, every process's health. In Foxglove: *Open connection* →
*Foxglove WebSocket* → ``ws://HOST:PORT``, then plot ``lt/state/joints.q_rad[0]`` and so on.

With ``--config`` the view also knows the cell's robot (gateway/view_page/arm.py): at most
:data:`ARM_RATE_HZ` times a second it runs forward kinematics on the newest joint state and
publishes ``/tf`` (``foxglove.FrameTransforms``, frames named after the URDF links under
``world``), ``/arm`` (``foxglove.SceneUpdate``: the arm drawn as cylinders and spheres, so the
3D panel shows it moving without meshes), ``/arm/points`` (the link origins as plain JSON) and,
to every client that subscribes, ``/robot_description`` (the URDF, for the 3D panel's URDF
layer). With ``--http-port`` it also serves a page any browser on the cell PC opens, offline
(gateway/view_page/page_server.py): joint position plots, the arm, the lifecycle state.

It joins the bus as the ``observer`` identity (subscribe only): it can see everything and
command nothing. The zenoh callback only transcodes and hands the message to the SDK, which
queues it per client (a slow browser drops its own oldest messages, never the bus's); the
kinematics run on a thread of their own, which takes the newest joint state when it is free.
"""

from __future__ import annotations

import argparse
import json
import logging
import threading
import time
from pathlib import Path
from typing import TYPE_CHECKING, Any

from gateway import mcap_json
from gateway.bus import BusConfig, bus_config_from, open_client, undeclare_all
from gateway.bus_security import OBSERVER
from gateway.config import load_toml
from gateway.signals import StopSignals

if TYPE_CHECKING:
    from gateway.robot.description import RobotDescription

log = logging.getLogger("leadthrough.view")

#: forward kinematics and the arm's 3D messages at most this often [Hz] (the bus: 125 Hz)
ARM_RATE_HZ = 30.0


class LiveView:
    """Serve ``<prefix>/**`` of ``bus`` to Foxglove WebSocket clients on ``host:port`` (port 0:
    any free port; :attr:`port` tells which). With ``robot``, also the arm in 3D; with
    ``http_port``, also the browser page on ``host:http_port`` (:attr:`http_port` tells which)."""

    def __init__(
        self,
        bus: BusConfig,
        host: str = "127.0.0.1",
        port: int = 8765,
        robot: RobotDescription | None = None,
        http_port: int | None = None,
    ) -> None:
        self.bus, self.host, self.requested_port = bus, host, port
        self.robot, self.requested_http_port = robot, http_port
        self._joint_state_key = bus.keys.joint_state
        self._lock = threading.Lock()
        self._channels: dict[tuple[str, str], Any] = {}
        self._context: Any = None
        self._server: Any = None
        self._session: Any = None
        self._sub: Any = None
        self._page: Any = None
        self.count = 0
        # The arm: the newest joint state (payload, wall-clock receive time [ns]) waits in a
        # one-message slot for the kinematics thread.
        self._kin: Any = None
        self._arm_channels: dict[str, Any] = {}
        self._arm_thread: threading.Thread | None = None
        self._arm_wake = threading.Event()
        self._arm_stop = threading.Event()
        self._send_description = threading.Event()
        self._newest_state: tuple[bytes, int] | None = None
        self._arm_refused = False
        self.arm_count = 0

    @property
    def port(self) -> int:
        return int(self._server.port) if self._server is not None else 0

    @property
    def http_port(self) -> int:
        return self._page.port if self._page is not None else 0

    def start(self) -> None:
        import foxglove

        listener = None
        if self.robot is not None:
            from gateway.view_page.arm import ArmKinematics, DescriptionSubscribed

            self._kin = ArmKinematics.from_description(self.robot)
            listener = DescriptionSubscribed(self._send_description_again)
        self._context = foxglove.Context()
        self._server = foxglove.start_server(
            name="leadthrough",
            host=self.host,
            port=self.requested_port,
            context=self._context,
            server_listener=listener,
        )
        try:
            if self._kin is not None:
                self._start_arm()
            if self.requested_http_port is not None:
                from gateway.view_page.page_server import PageServer

                self._page = PageServer(self.host, self.requested_http_port, self.port)
                self._page.start()
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
        payload = sample.payload.to_bytes()
        kind, data = mcap_json.to_record(payload, time.monotonic_ns())
        log_ns = time.time_ns()
        with self._lock:
            channel = self._channels.get((key, kind))
            if channel is None:
                channel = self._channel(key, kind)
                self._channels[(key, kind)] = channel
            self.count += 1
            if self._kin is not None and kind == "JointState" and key == self._joint_state_key:
                self._newest_state = (payload, log_ns)
                self._arm_wake.set()
        channel.log(data, log_time=log_ns)

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

    def _start_arm(self) -> None:
        import foxglove
        from foxglove.channels import FrameTransformsChannel, SceneUpdateChannel

        from gateway.view_page import arm

        def json_channel(topic: str, name: str, schema: dict[str, Any]) -> Any:
            return foxglove.Channel(
                topic,
                schema=foxglove.Schema(
                    name=name, encoding=mcap_json.SCHEMA_ENCODING, data=json.dumps(schema).encode()
                ),
                message_encoding=mcap_json.MESSAGE_ENCODING,
                context=self._context,
            )

        ctx = self._context
        self._arm_channels = {
            "tf": FrameTransformsChannel(arm.TF_TOPIC, context=ctx),
            "scene": SceneUpdateChannel(arm.ARM_TOPIC, context=ctx),
            "points": json_channel(
                arm.ARM_POINTS_TOPIC, arm.ARM_POINTS_SCHEMA_NAME, arm.ARM_POINTS_SCHEMA
            ),
            "description": json_channel(
                arm.DESCRIPTION_TOPIC, arm.DESCRIPTION_SCHEMA_NAME, arm.DESCRIPTION_SCHEMA
            ),
        }
        self._arm_stop.clear()
        self._send_description.set()  # once now, then again for each new subscriber
        self._arm_wake.set()
        self._arm_thread = threading.Thread(
            target=self._arm_loop, name="live-view-arm", daemon=True
        )
        self._arm_thread.start()

    def _send_description_again(self) -> None:
        """A client subscribed to ``/robot_description`` (called on the server's thread)."""
        self._send_description.set()
        self._arm_wake.set()

    def _arm_loop(self) -> None:
        """Until stopped: the URDF when asked, the arm at the newest joint state, then a pause
        of 1/:data:`ARM_RATE_HZ` (the states that came meanwhile are skipped but the newest)."""
        period_s = 1.0 / ARM_RATE_HZ
        while True:
            self._arm_wake.wait()
            self._arm_wake.clear()
            if self._arm_stop.is_set():
                return
            if self._send_description.is_set():
                self._send_description.clear()
                urdf = json.dumps({"data": self._kin.urdf_xml}).encode()
                self._arm_channels["description"].log(urdf, log_time=time.time_ns())
            with self._lock:
                newest, self._newest_state = self._newest_state, None
            if newest is not None and self._publish_arm(*newest):
                self._arm_stop.wait(period_s)

    def _publish_arm(self, payload: bytes, log_ns: int) -> bool:
        """The arm at one joint state on ``/tf``, ``/arm`` and ``/arm/points``; False when no
        client watches or the state cannot be drawn (said once)."""
        import numpy as np

        from gateway.errors import MessageError
        from gateway.messages import JointState
        from gateway.view_page import arm

        channels = self._arm_channels
        if not any(channels[name].has_sinks() for name in ("tf", "scene", "points")):
            return False
        try:
            state = JointState.from_bytes(payload)
            if not np.all(np.isfinite(state.q_rad)):
                raise ValueError("joint positions not finite")
            pose = self._kin.forward(state.q_rad)
        except (MessageError, ValueError) as exc:
            if not self._arm_refused:
                log.warning("the arm is not drawn: %s", exc)
                self._arm_refused = True
            return False
        channels["tf"].log(arm.frame_transforms(self._kin, pose, log_ns), log_time=log_ns)
        channels["scene"].log(arm.scene_update(self._kin, pose, log_ns), log_time=log_ns)
        points = json.dumps(arm.arm_points(self._kin, pose, state.cycle)).encode()
        channels["points"].log(points, log_time=log_ns)
        self.arm_count += 1
        return True

    def stop(self) -> None:
        """Undeclare, close the session, stop the arm, the page and the server (idempotent)."""
        undeclare_all([self._sub])
        self._sub = None
        if self._session is not None:
            self._session.close()
            self._session = None
        if self._arm_thread is not None:
            self._arm_stop.set()
            self._arm_wake.set()
            self._arm_thread.join()
            self._arm_thread = None
        if self._page is not None:
            self._page.stop()
            self._page = None
        with self._lock:
            for channel in [*self._channels.values(), *self._arm_channels.values()]:
                channel.close()
            self._channels.clear()
            self._arm_channels.clear()
        if self._server is not None:
            self._server.stop()
            self._server = None


def configure_parser(p: argparse.ArgumentParser) -> None:
    p.description = (
        "Serve the bus live to Foxglove (WebSocket): joint states, commands, pressures, "
        "lifecycle, health; with --config also the arm in 3D (/tf, /arm, /robot_description). "
        "Connect Foxglove to ws://HOST:PORT, or open http://HOST:HTTP_PORT/ in a browser "
        "(--http-port). Until Ctrl-C."
    )
    p.add_argument(
        "--config",
        type=Path,
        default=None,
        help="cell config TOML ([bus], and the robot of [control] model for the 3D arm)",
    )
    p.add_argument("--bus", default=None, help="zenoh endpoint of the gateway")
    p.add_argument("--host", default="127.0.0.1", help="address to serve on")
    p.add_argument("--port", type=int, default=8765, help="port to serve on (0: any free one)")
    p.add_argument(
        "--http-port",
        type=int,
        default=None,
        help="also serve a live page for a plain browser on this port (default: off)",
    )
    p.add_argument("--duration", type=float, default=None, help="stop after this many seconds")


def cli_main(args: argparse.Namespace) -> int:
    bus = BusConfig()
    robot = None
    if args.config:
        from gateway.view_page.arm import cell_description

        bus = bus_config_from(load_toml(args.config), str(args.config))
        robot = cell_description(args.config)
    view = LiveView(bus.with_overrides(args.bus), args.host, args.port, robot, args.http_port)
    stop = threading.Event()
    with StopSignals(stop):
        view.start()
        print(f"live view: connect Foxglove to ws://{args.host}:{view.port}", flush=True)
        if view.http_port:
            print(f"live view: open http://{args.host}:{view.http_port}/ in a browser", flush=True)
        try:
            stop.wait(args.duration)
        finally:
            view.stop()
    log.info("%d messages served, the arm drawn %d times", view.count, view.arm_count)
    return 0
