"""`leadthrough ros2`: the arm's joint states for a ROS 2 system next door, over rmw_zenoh.

A ROS 2 system whose middleware is rmw_zenoh (ROS 2 Jazzy and later) talks through a zenoh
router of its own (``rmw_zenohd``, ``tcp/…:7447`` by default). This bridge joins the cell's bus
as the read-only ``observer`` identity and the ROS 2 router as a client, and publishes there,
one way, what a ROS 2 tool expects to find:

- ``/joint_states`` (``sensor_msgs/msg/JointState``): the measured joint positions [rad] and
  velocities [rad/s], names from ``[ros2] joint_names``, stamped with the wall-clock time the
  CAN driver had the controller cycle. ``effort`` is left empty: the drives report motor
  current [A], not torque [N·m];
- ``/joint_commands`` (same type, ``[ros2] commands``): the position/velocity commands the
  control process sends, for plotting against the states.

Both are CDR (rosbags' serializer) on rmw_zenoh's key expressions
``<domain>/<topic>/<DDS type>/<type hash>`` with its attachment (sequence number, source
timestamp, publisher GID), and the node and its publishers announce themselves with rmw_zenoh's
liveliness tokens, so ``ros2 topic list``/``echo``, ``rviz2`` and ``ros2 bag record`` see them.

Nothing comes back: the bridge subscribes to nothing on the ROS 2 side, its cell session can
put nothing, and the two networks stay separate (a ROS 2 node cannot reach ``lt/cmd/*``).
"""

from __future__ import annotations

import argparse
import dataclasses
import hashlib
import logging
import re
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import zenoh
import zenoh.ext as zx

from gateway.bus import (
    CONNECT_TIMEOUT_S,
    BusConfig,
    bus_config_from,
    open_client,
    undeclare_all,
)
from gateway.bus_security import OBSERVER
from gateway.cell_section import CellSection
from gateway.config import from_mapping, load_toml, require
from gateway.errors import ConfigError, LinkTimeoutError, MessageError
from gateway.messages import JointCommand, JointState
from gateway.ratelog import RateLimitedLog
from gateway.signals import StopSignals

log = logging.getLogger("leadthrough.ros2")

JOINT_STATE_TYPE = "sensor_msgs/msg/JointState"
#: rmw_zenoh's liveliness entity kinds
NODE, PUBLISHER = "NN", "MP"
#: rmw_zenoh's liveliness admin space
ADMIN_SPACE = "@ros2_lv"
#: QoS in rmw_zenoh's token notation, each field empty where it is rmw_zenoh's default
#: (reliable, volatile, keep-last): history depth 10, as ``joint_state_publisher`` publishes.
QOS_KEEP_LAST_10 = "::,10:,:,:,,"
_NAME_RE = re.compile(r"^[A-Za-z][A-Za-z0-9_]*$")
_NAMESPACE_RE = re.compile(r"^(/[A-Za-z][A-Za-z0-9_]*)*$")


@dataclass(frozen=True)
class Ros2Config:
    """``[ros2]`` section of the cell config (read by ``leadthrough ros2`` only)."""

    #: zenoh endpoint of the ROS 2 system's router (``rmw_zenohd`` listens on 7447).
    endpoint: str = "tcp/127.0.0.1:7447"
    #: ROS_DOMAIN_ID of the ROS 2 system.
    domain_id: int = 0
    #: ROS namespace of the node and its topics ("" or like "/cell1").
    namespace: str = ""
    node_name: str = "leadthrough"
    #: the joints' names in controller order (empty: joint_1 … joint_n, ROS-Industrial's).
    joint_names: tuple[str, ...] = ()
    #: highest rate of each topic [Hz] (0: every controller cycle).
    rate_hz: float = 50.0
    #: also publish the control process's joint commands on ``joint_commands``.
    commands: bool = True

    def __post_init__(self) -> None:
        require(0 <= self.domain_id <= 232, "[ros2].domain_id", "must be in 0..232")
        require(
            bool(_NAMESPACE_RE.match(self.namespace)),
            "[ros2].namespace",
            f"{self.namespace!r} is not a ROS namespace like '' or '/cell1'",
        )
        require(
            bool(_NAME_RE.match(self.node_name)),
            "[ros2].node_name",
            f"{self.node_name!r} is not a ROS node name",
        )
        bad = [n for n in self.joint_names if not _NAME_RE.match(n)]
        require(not bad, "[ros2].joint_names", f"{bad} are not ROS names")
        dup = sorted({n for n in self.joint_names if self.joint_names.count(n) > 1})
        require(not dup, "[ros2].joint_names", f"{dup} given twice")
        require(
            np.isfinite(self.rate_hz) and self.rate_hz >= 0,
            "[ros2].rate_hz",
            f"{self.rate_hz!r} must be 0 (every cycle) or a positive rate",
        )

    def names(self, n: int) -> list[str]:
        """The names of ``n`` joints (ConfigError when ``joint_names`` lists another count)."""
        if not self.joint_names:
            return [f"joint_{i + 1}" for i in range(n)]
        require(
            len(self.joint_names) == n,
            "[ros2].joint_names",
            f"{len(self.joint_names)} names for an arm of {n} joints",
        )
        return list(self.joint_names)

    def topic(self, name: str) -> str:
        """Fully qualified topic name: ``/<namespace>/<name>``."""
        return f"{self.namespace}/{name}"


def ros2_config_from(cell: dict[str, Any], where: str) -> Ros2Config:
    """The ``[ros2]`` section of a parsed cell config (defaults when absent)."""
    return from_mapping(Ros2Config, cell.get("ros2", {}), f"{where} [ros2]")


#: the ``[ros2]`` section of the cell config, registered in pyproject.toml
CELL_SECTION = CellSection(
    "ros2", lambda path, raw: ros2_config_from(raw, str(path)), Ros2Config, order=7
)


# --- rmw_zenoh's names -------------------------------------------------------------------------


def mangle(name: str) -> str:
    """A ROS name inside one chunk of a liveliness key: ``/`` → ``%`` (rmw_zenoh's mangling)."""
    return name.replace("/", "%")


def dds_type_name(ros_type: str) -> str:
    """``pkg/msg/Type`` → ``pkg::msg::dds_::Type_`` (the type name in rmw_zenoh's keys)."""
    pkg, kind, name = ros_type.split("/")
    return f"{pkg}::{kind}::dds_::{name}_"


def topic_key(domain_id: int, topic: str, ros_type: str, type_hash: str) -> str:
    """The key a message of ``topic`` travels on: ``<domain>/<topic>/<DDS type>/<hash>``."""
    return f"{domain_id}/{topic.strip('/')}/{dds_type_name(ros_type)}/{type_hash}"


def node_token(domain_id: int, zid: str, node_id: int, namespace: str, node: str) -> str:
    """The liveliness key announcing a node (enclave ``/``)."""
    ns = mangle(namespace or "/")
    return f"{ADMIN_SPACE}/{domain_id}/{zid}/{node_id}/{node_id}/{NODE}/%/{ns}/{node}"


def publisher_token(
    domain_id: int,
    zid: str,
    node_id: int,
    entity_id: int,
    namespace: str,
    node: str,
    topic: str,
    ros_type: str,
    type_hash: str,
    qos: str = QOS_KEEP_LAST_10,
) -> str:
    """The liveliness key announcing a publisher of ``topic`` (a fully qualified name)."""
    ns = mangle(namespace or "/")
    return (
        f"{ADMIN_SPACE}/{domain_id}/{zid}/{node_id}/{entity_id}/{PUBLISHER}/%/{ns}/{node}/"
        f"{mangle(topic)}/{dds_type_name(ros_type)}/{type_hash}/{qos}"
    )


def attachment(sequence_number: int, source_timestamp_ns: int, gid: bytes) -> bytes:
    """rmw_zenoh's per-message attachment: int64 sequence number, int64 source timestamp [ns]
    and the 16-byte publisher GID as a sequence, in zenoh's serialization format."""
    if len(gid) != 16:
        raise ValueError(f"a publisher GID has 16 bytes, got {len(gid)}")
    payload = zx.z_serialize((zx.Int64(sequence_number), zx.Int64(source_timestamp_ns), gid))
    return payload.to_bytes()


def gid_of(token: str) -> bytes:
    """A publisher's 16-byte GID, from its liveliness key (rmw_zenoh hashes the same key)."""
    return hashlib.blake2b(token.encode(), digest_size=16).digest()


class JointStateCdr:
    """``sensor_msgs/msg/JointState`` to CDR bytes (rosbags' serializer, ROS 2 Jazzy types)."""

    def __init__(self) -> None:
        from rosbags.typesys import Stores, get_typestore

        self._store = get_typestore(Stores.ROS2_JAZZY)
        types = self._store.types
        self._msg = types[JOINT_STATE_TYPE]
        self._header = types["std_msgs/msg/Header"]
        self._time = types["builtin_interfaces/msg/Time"]
        #: the type's RIHS01 hash, as ``ros2 topic info --verbose`` prints it
        self.type_hash: str = self._store.hash_rihs01(JOINT_STATE_TYPE)
        self._empty = np.zeros(0)

    def encode(
        self,
        stamp_ns: int,
        names: list[str],
        position: np.ndarray,
        velocity: np.ndarray,
        frame_id: str = "",
    ) -> bytes:
        sec, nanosec = divmod(int(stamp_ns), 1_000_000_000)
        msg = self._msg(
            header=self._header(stamp=self._time(sec=sec, nanosec=nanosec), frame_id=frame_id),
            name=names,
            position=np.asarray(position, dtype=np.float64),
            velocity=np.asarray(velocity, dtype=np.float64),
            effort=self._empty,
        )
        return bytes(self._store.serialize_cdr(msg, JOINT_STATE_TYPE))


@dataclass
class _Topic:
    """One ROS 2 publisher of the bridge: its key, token, GID, rate gate and counters."""

    name: str
    key: str
    token: str
    gid: bytes
    min_period_s: float
    publisher: Any = None
    liveliness: Any = None
    sequence: int = 0
    last_s: float = -1e18
    published: int = 0

    def due(self, now_s: float) -> bool:
        if now_s - self.last_s < self.min_period_s:
            return False
        self.last_s = now_s
        return True


@dataclass
class BridgeCounts:
    published: dict[str, int] = field(default_factory=dict)
    #: bus messages refused (undecodable, NaN, wrong joint count)
    refused: int = 0


class Ros2Bridge:
    """Publish the cell's joint states (and commands) to a ROS 2 system over rmw_zenoh."""

    def __init__(
        self, bus: BusConfig, cfg: Ros2Config, connect_timeout_s: float = CONNECT_TIMEOUT_S
    ) -> None:
        self.bus, self.cfg, self.connect_timeout_s = bus, cfg, connect_timeout_s
        self._cdr = JointStateCdr()
        self._lock = threading.Lock()
        self._cell: zenoh.Session | None = None
        self._ros: zenoh.Session | None = None
        self._node_token: Any = None
        self._subs: list[Any] = []
        self._topics: dict[str, _Topic] = {}
        self._names: list[str] | None = None
        self._refused = 0
        self._rlog = RateLimitedLog(log, 5.0, time.monotonic)

    # --- life --------------------------------------------------------------------------------

    def start(self) -> None:
        """Join both networks and announce the node; raises LinkTimeoutError naming the
        network that did not answer."""
        cfg = self.cfg
        try:
            try:
                self._ros = open_client(BusConfig(endpoint=cfg.endpoint), self.connect_timeout_s)
            except LinkTimeoutError:
                raise LinkTimeoutError(
                    f"no zenoh router of the ROS 2 system at [ros2].endpoint {cfg.endpoint}: "
                    "is rmw_zenohd (ros2 run rmw_zenoh_cpp rmw_zenohd) running there?"
                ) from None
            zid = str(self._ros.info.zid())
            node_id = 0
            self._node_token = self._ros.liveliness().declare_token(
                node_token(cfg.domain_id, zid, node_id, cfg.namespace, cfg.node_name)
            )
            wanted = ["joint_states"] + ["joint_commands"] * cfg.commands
            for entity_id, name in enumerate(wanted, start=1):
                self._topics[name] = self._declare(zid, node_id, entity_id, name)
            self._cell = open_client(self.bus, self.connect_timeout_s, identity=OBSERVER)
            keys = self.bus.keys
            self._subs.append(self._cell.declare_subscriber(keys.joint_state, self._on_state))
            if cfg.commands:
                self._subs.append(
                    self._cell.declare_subscriber(keys.joint_command, self._on_command)
                )
        except BaseException:
            self.stop()
            raise
        log.info(
            "ROS 2 bridge: %s on domain %d at %s (node %s%s)",
            ", ".join(t.name for t in self._topics.values()),
            cfg.domain_id,
            cfg.endpoint,
            cfg.namespace,
            f"/{cfg.node_name}",
        )

    def _declare(self, zid: str, node_id: int, entity_id: int, name: str) -> _Topic:
        cfg, topic = self.cfg, self.cfg.topic(name)
        h = self._cdr.type_hash
        token = publisher_token(
            cfg.domain_id, zid, node_id, entity_id, cfg.namespace, cfg.node_name, topic,
            JOINT_STATE_TYPE, h,
        )  # fmt: skip
        t = _Topic(
            name=topic,
            key=topic_key(cfg.domain_id, topic, JOINT_STATE_TYPE, h),
            token=token,
            gid=gid_of(token),
            min_period_s=1.0 / cfg.rate_hz if cfg.rate_hz > 0 else 0.0,
        )
        assert self._ros is not None
        t.publisher = self._ros.declare_publisher(t.key)
        t.liveliness = self._ros.liveliness().declare_token(token)
        return t

    def stop(self) -> None:
        """Undeclare everything and close both sessions (idempotent, never raises)."""
        undeclare_all(self._subs)
        self._subs = []
        for t in self._topics.values():
            undeclare_all([t.liveliness, t.publisher])
        undeclare_all([self._node_token])
        self._node_token = None
        for attr in ("_cell", "_ros"):
            session = getattr(self, attr)
            setattr(self, attr, None)
            if session is not None:
                try:
                    session.close()
                except Exception as exc:
                    log.debug("closing the %s session: %r", attr, exc)

    @property
    def counts(self) -> BridgeCounts:
        with self._lock:
            return BridgeCounts({t.name: t.published for t in self._topics.values()}, self._refused)

    # --- the two callbacks -------------------------------------------------------------------

    def _on_state(self, sample: zenoh.Sample) -> None:
        try:
            st = JointState.from_bytes(sample.payload.to_bytes())
        except MessageError as exc:
            self._refuse(f"{sample.key_expr}: {exc}")
            return
        self._publish("joint_states", st.stamp_s, st.q_rad, st.dq_rad_s)

    def _on_command(self, sample: zenoh.Sample) -> None:
        try:
            cmd = JointCommand.from_bytes(sample.payload.to_bytes())
        except MessageError as exc:
            self._refuse(f"{sample.key_expr}: {exc}")
            return
        self._publish("joint_commands", cmd.sent_stamp_s, cmd.q_cmd_rad, cmd.dq_cmd_rad_s)

    def _refuse(self, why: str) -> None:
        with self._lock:
            self._refused += 1
        self._rlog(logging.WARNING, "refused", "not bridged: %s", why)

    def _publish(self, name: str, mono_stamp_s: float, q: np.ndarray, dq: np.ndarray) -> None:
        t = self._topics.get(name)
        if t is None:
            return
        now_mono = time.monotonic()
        with self._lock:
            if not t.due(now_mono):
                return
            if self._names is None or len(self._names) != len(q):
                try:
                    self._names = self.cfg.names(len(q))
                except ConfigError as exc:
                    self._refused += 1
                    self._rlog(logging.ERROR, "names", "not bridged: %s", exc)
                    return
            t.sequence += 1
            seq = t.sequence
        # The bus stamps are CLOCK_MONOTONIC of this machine; ROS stamps are wall clock.
        now_ns = time.time_ns()
        stamp_ns = now_ns - round((now_mono - mono_stamp_s) * 1e9)
        payload = self._cdr.encode(stamp_ns, self._names, q, dq)
        t.publisher.put(payload, attachment=attachment(seq, now_ns, t.gid))
        with self._lock:
            t.published += 1


def configure_parser(p: argparse.ArgumentParser) -> None:
    p.description = (
        "Publish the arm's joint states (and commands) to a ROS 2 system over rmw_zenoh: "
        "sensor_msgs/JointState on /joint_states, one way, until Ctrl-C. Settings in [ros2]."
    )
    p.add_argument("--config", type=Path, default=None, help="cell config TOML ([bus], [ros2])")
    p.add_argument("--bus", default=None, help="zenoh endpoint of the gateway")
    p.add_argument("--ros-endpoint", default=None, help="zenoh endpoint of the ROS 2 router")
    p.add_argument("--duration", type=float, default=None, help="stop after this many seconds")


def cli_main(args: argparse.Namespace) -> int:
    bus, cfg = BusConfig(), Ros2Config()
    if args.config:
        raw = load_toml(args.config)
        bus = bus_config_from(raw, str(args.config))
        cfg = ros2_config_from(raw, str(args.config))
    if args.ros_endpoint:
        cfg = dataclasses.replace(cfg, endpoint=args.ros_endpoint)
    bridge = Ros2Bridge(bus.with_overrides(args.bus), cfg)
    stop = threading.Event()
    with StopSignals(stop):
        bridge.start()
        try:
            stop.wait(args.duration)
        finally:
            bridge.stop()
    c = bridge.counts
    log.info("published %s; %d bus messages refused", c.published, c.refused)
    return 0
