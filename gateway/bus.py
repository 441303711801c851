"""The zenoh bus: one router (hosted by the gateway); the drivers and the control process
join as peers, short-lived tools (operator commands, the recorder) as clients.

Multicast scouting is off: every session names the router's endpoint explicitly, so a test on
a free loopback port never meets a stray zenoh peer on 7447. Peers learn each other through
the router (gossip) and then talk directly, which saves the router hop on the control loop's
two zenoh legs (measured here: 268 → 181 µs one-way p50).
"""

from __future__ import annotations

import json
import logging
import os
import re
from collections.abc import Callable, Iterable
from dataclasses import dataclass, replace
from typing import Any

import zenoh

from gateway import bus_security as security
from gateway import bus_tls as tls
from gateway.cell_section import CellSection, section_names
from gateway.config import from_mapping, require
from gateway.errors import LinkTimeoutError
from gateway.messages import Keys

log = logging.getLogger(__name__)

ENDPOINT_ENV = "LEADTHROUGH_BUS_ENDPOINT"
_ENDPOINT_RE = re.compile(r"^(tcp|udp|unixsock-stream|tls)/.+$")


@dataclass(frozen=True)
class BusConfig:
    """``[bus]`` section of the cell config."""

    #: zenoh endpoint the gateway's router listens on and every other process connects to.
    #: Overridden by the environment variable LEADTHROUGH_BUS_ENDPOINT, then by --bus.
    endpoint: str = "tcp/127.0.0.1:7460"
    #: Prefix of every key expression (lets two cells share one network).
    key_prefix: str = "lt"
    #: Where each peer process listens for the others (port 0: any free port).
    peer_listen: str = "tcp/127.0.0.1:0"
    #: File of ``identity:password`` lines (mode 600): when set, every session authenticates,
    #: the router applies a default-deny access-control list and every process joins as a
    #: client of the router (:mod:`gateway.bus_security`). Empty: an open bus (tests, bench).
    credentials_file: str = ""
    #: A second endpoint the router listens on for machines outside the cell PC, with mutual
    #: TLS (``tls/0.0.0.0:7461``; :mod:`gateway.bus_tls`). Empty: loopback only.
    remote_endpoint: str = ""
    #: The cell's certificate authority, this machine's certificate and its private key (PEM,
    #: the key mode 600): required with a ``tls/`` endpoint or remote endpoint.
    tls_ca_file: str = ""
    tls_cert_file: str = ""
    tls_key_file: str = ""

    def __post_init__(self) -> None:
        require(
            bool(_ENDPOINT_RE.match(self.endpoint)),
            "[bus].endpoint",
            f"{self.endpoint!r} is not a zenoh endpoint like 'tcp/127.0.0.1:7460'",
        )
        require(
            not self.remote_endpoint or self.remote_endpoint.startswith("tls/"),
            "[bus].remote_endpoint",
            f"{self.remote_endpoint!r}: a link off the cell PC must be mutual TLS, "
            "like 'tls/0.0.0.0:7461'",
        )
        Keys(self.key_prefix)  # validates the prefix

    @property
    def tls(self) -> bool:
        """Links with mutual TLS: a ``tls/`` endpoint (a remote machine) or remote endpoint
        (the cell PC's router)."""
        return self.endpoint.startswith("tls/") or bool(self.remote_endpoint)

    def insert_tls(self, cfg: zenoh.Config) -> None:
        """Mutual TLS into ``cfg`` when :attr:`tls` (ConfigError naming a bad file)."""
        if self.tls:
            files = (self.tls_ca_file, self.tls_cert_file, self.tls_key_file)
            tls.check_tls_files(*files, "[bus]")
            tls.insert_tls(cfg, *files)

    @property
    def keys(self) -> Keys:
        return Keys(self.key_prefix)

    def with_overrides(self, endpoint: str | None = None) -> BusConfig:
        """Apply the documented precedence: explicit argument, then environment, then file."""
        chosen = endpoint or os.environ.get(ENDPOINT_ENV) or self.endpoint
        return replace(self, endpoint=chosen)

    @property
    def locked(self) -> bool:
        """Authenticated sessions and the router's access-control list."""
        return bool(self.credentials_file)


#: how long a process keeps trying to reach the router at start-up [s]
CONNECT_TIMEOUT_S = 10.0


#: Batches zenoh's transmission queue holds for real-time messages, per link (zenoh allows
#: 1-16; its default, 2, is too few to hold a burst of cycles). The control loop's data goes out
#: express at real-time priority, one batch per message, and is dropped when no batch frees
#: within 1 ms (CongestionControl.DROP: a slow peer must never stall the loop). A controller
#: that ran late sends the cycles it owes back to back, and so does a driver that reads a
#: backlog after its thread was held: the driver's and the router's queues then took the
#: first two joint states of a 12-cycle burst and dropped the rest, the newest among them (the
#: one the driver waits to have answered), in 4 of 6 runs of
#: tests/transport/test_can_driver.py::test_a_burst_of_cycles_reaches_control_whole... on an
#: idle 2-core machine (2026-12-07). 16 holds such a burst; the batches are allocated lazily,
#: so a queue that never fills costs nothing.
REAL_TIME_QUEUE_BATCHES = 16


def _zenoh_config(
    mode: str,
    listen: list[str],
    connect: list[str],
    connect_timeout_s: float = CONNECT_TIMEOUT_S,
    cfg: Any = None,
) -> Any:
    cfg = zenoh.Config() if cfg is None else cfg
    cfg.insert_json5("mode", json.dumps(mode))
    cfg.insert_json5("scouting/multicast/enabled", "false")
    cfg.insert_json5("scouting/gossip/enabled", json.dumps(mode != "client"))
    cfg.insert_json5("listen/endpoints", json.dumps(listen))
    cfg.insert_json5("connect/endpoints", json.dumps(connect))
    cfg.insert_json5("transport/link/tx/queue/size/real_time", str(REAL_TIME_QUEUE_BATCHES))
    if connect:
        # Keep retrying the router during start-up instead of failing the first attempt.
        cfg.insert_json5("connect/timeout_ms", str(max(1, round(connect_timeout_s * 1000))))
        cfg.insert_json5("connect/exit_on_failure", "true")
    return cfg


def open_router(bus: BusConfig) -> zenoh.Session | LockedRouter:
    """Open the router every other process connects to (gateway only) and the gateway's own
    session on it. On an open bus the router is that session. On a locked bus it is
    :class:`LockedRouter`: a compiled router that authenticates every link, applies the
    access-control list and counts what the list refuses, with the gateway's session a client
    of it."""
    listen = [bus.endpoint, *[bus.remote_endpoint] * bool(bus.remote_endpoint)]
    if bus.locked:
        return LockedRouter.open(bus, listen)
    cfg = _zenoh_config("router", listen, [])
    bus.insert_tls(cfg)
    return zenoh.open(cfg)


class LockedRouter:
    """A locked bus's router and the gateway's own session, used as that session (every
    attribute but :meth:`refusals` and :meth:`close` is the session's).

    The router is compiled (gateway/router, the extension ``gateway._router``): zenoh's router
    with the same settings the wheel would get, whose access-control decisions go to an
    in-memory counter. The wheel reports them only as a formatted log line per decision, two
    per message on the cycle, which the gateway had to read back through a pipe from its own
    standard output: lines that filled the journal, and a router that stopped routing when the
    pipe's reader was late (a locked-bus stack test faulted on "no fresh joint state" in CI).
    The gateway's session is a client of it as the ``gateway`` identity, under the same list
    as every other process."""

    def __init__(self, router: Any, session: zenoh.Session) -> None:
        self._router = router
        self._session = session

    @classmethod
    def open(cls, bus: BusConfig, listen: list[str]) -> LockedRouter:
        from gateway import _router  # compiled (make); only a locked bus needs it

        entries = _zenoh_config("router", listen, [], cfg=_Entries())
        bus.insert_tls(entries)
        security.insert_router_security(entries, bus.credentials_file, bus.keys)
        try:
            router = _router.Router(entries.items)
        except OSError as exc:
            raise LinkTimeoutError(f"the bus router could not open on {listen}: {exc}") from exc
        try:
            session = _open_linked(
                _zenoh_config("client", [], [bus.endpoint]), bus, security.GATEWAY,
                CONNECT_TIMEOUT_S,
            )  # fmt: skip
        except BaseException:
            router.close()
            raise
        return cls(router, session)

    def refusals(self) -> list[tuple[str, str, str, int]]:
        """Every (identity, action, key) the access-control list refused so far, with its
        count (``gateway.bus_refusals.BusRefusals`` reads it)."""
        return self._router.refusals()

    def close(self) -> None:
        try:
            self._session.close()
        finally:
            self._router.close()

    def __getattr__(self, name: str) -> Any:
        return getattr(self._session, name)


def _open_linked(cfg: zenoh.Config, bus: BusConfig, identity: str, timeout_s: float):
    bus.insert_tls(cfg)
    if bus.locked:
        security.insert_session_credentials(cfg, bus.credentials_file, identity)
    try:
        return zenoh.open(cfg)
    except zenoh.ZError as exc:
        refused = (
            f" or it refused identity {identity!r} (check [bus].credentials_file)"
            if bus.locked
            else ""
        )
        if bus.tls:
            refused += (
                " or the TLS handshake failed (a certificate not signed by [bus].tls_ca_file, "
                "or a name the router's certificate was not made for)"
            )
        raise LinkTimeoutError(
            f"no zenoh router (gateway) reachable at {bus.endpoint} within {timeout_s:g} s"
            f"{refused}: is `leadthrough gateway` running there?"
        ) from exc


def open_client(
    bus: BusConfig,
    connect_timeout_s: float = CONNECT_TIMEOUT_S,
    identity: str = security.OPERATOR,
) -> zenoh.Session:
    """Open a client session connected to the router at ``bus.endpoint`` (short-lived tools),
    as ``identity`` on a locked bus.

    Raises :class:`~gateway.errors.LinkTimeoutError` when no router answers there within
    ``connect_timeout_s`` (or, on a locked bus, it refuses the credentials)."""
    cfg = _zenoh_config("client", [], [bus.endpoint], connect_timeout_s)
    return _open_linked(cfg, bus, identity, connect_timeout_s)


def open_peer(bus: BusConfig, identity: str) -> zenoh.Session:
    """Open a product process's session: on an open bus a peer that connects to the router,
    then directly to the other peers; on a locked bus a client of the router as ``identity``
    (see :mod:`gateway.bus_security` for why)."""
    return _open_linked(_peer_config(bus, zenoh.Config()), bus, identity, CONNECT_TIMEOUT_S)


def _peer_config(bus: BusConfig, cfg: Any) -> Any:
    """:func:`open_peer`'s session settings, inserted into ``cfg`` (anything with zenoh.Config's
    ``insert_json5``)."""
    mode, listen = ("client", []) if bus.locked else ("peer", [bus.peer_listen])
    return _zenoh_config(mode, listen, [bus.endpoint], cfg=cfg)


class _Entries:
    """Records ``insert_json5`` calls: a zenoh config as (key, JSON5 value) pairs."""

    def __init__(self) -> None:
        self.items: list[tuple[str, str]] = []

    def insert_json5(self, key: str, value: str) -> None:
        self.items.append((key, value))


def peer_config_entries(bus: BusConfig, identity: str) -> list[tuple[str, str]]:
    """The settings :func:`open_peer` gives a session of ``identity``, as (key, JSON5 value)
    pairs: a compiled piece (drivers/can/rt) opens its own zenoh session (the zenoh crate, the
    same version as this wheel) with exactly these, so it joins the bus as its process does."""
    entries = _peer_config(bus, _Entries())
    bus.insert_tls(entries)
    if bus.locked:
        security.insert_session_credentials(entries, bus.credentials_file, identity)
    return entries.items


def on_receiving_thread(callback: Callable[[zenoh.Sample], Any]) -> zenoh.handlers.Callback:
    """A subscriber's callback for the control loop's data, run on the zenoh thread that
    received the sample. zenoh-python's default runs each subscriber's callbacks on a Python
    thread of its own, handing every sample over (a wake-up per sample, and the scheduler's
    latency on a busy core); this takes the hand-off out of the loop. The callback must be
    quick and never block: the link's next sample waits for it (the loop's callbacks decode,
    compute and publish in well under one cycle)."""
    return zenoh.handlers.Callback(callback, indirect=False)


def declare_loop_publisher(session: zenoh.Session, key: str):
    """Publisher for the control loop's data: never blocks (a dead or slow peer must not stall
    the loop: the message is dropped and the receiver's deadline handles it), sent at once
    (no batching), at real-time priority."""
    return session.declare_publisher(
        key,
        congestion_control=zenoh.CongestionControl.DROP,
        priority=zenoh.Priority.REAL_TIME,
        express=True,
    )


def bus_config_from(cell: dict[str, Any], where: str) -> BusConfig:
    """The ``[bus]`` section of a parsed cell config (defaults when absent). Every process
    and tool reads its cell config through here, so a section nobody reads (a typo: a
    ``[contorl]`` whose settings would quietly do nothing) is refused here, naming it."""
    check_cell_sections(cell, where)
    return from_mapping(BusConfig, cell.get("bus", {}), f"{where} [bus]")


def check_cell_sections(cell: dict[str, Any], where: str) -> None:
    """Refuse a cell config with a section nobody reads (ConfigError naming it):
    :func:`bus_config_from` calls it, and a loader that does not read ``[bus]``. The sections
    are the registered ones (gateway/cell_section.py); each process reads its own and [bus]."""
    known = sorted(section_names())
    unknown = sorted(set(cell) - set(known))
    require(
        not unknown,
        where,
        f"unknown section(s) {unknown}: a cell config has {[f'[{s}]' for s in known]}",
    )


#: the ``[bus]`` section of the cell config, registered in pyproject.toml
CELL_SECTION = CellSection(
    "bus", lambda path, raw: bus_config_from(raw, str(path)), BusConfig, order=1
)


def undeclare_all(entities: Iterable[Any]) -> None:
    """Undeclare zenoh subscribers/publishers/queryables on the way out; never raises (a
    session that is already gone has nothing left to undo). ``None`` entries are skipped."""
    for entity in entities:
        if entity is None:
            continue
        try:
            entity.undeclare()
        except Exception as exc:
            log.debug("undeclare of %r failed: %r", entity, exc)
