"""A locked-down bus: who may join the zenoh bus, and who may put what on it.

With ``[bus] credentials_file`` set, every session authenticates with zenoh's user/password
scheme, and the router (hosted by the gateway) applies a default-deny access-control list:

=================  ==========================================================================
identity           may put (ingress at the router) / query
=================  ==========================================================================
``control``        joint commands, pressure set-points, its health, telemetry, plan progress
``can-driver``     joint states and state windows, its health, driver telemetry
``modbus-driver``  I/O state, its health, driver telemetry
``operator``       queries on the gateway's request key (start, stop, reset, status, ...)
``observer``       nothing: subscribes only (recorders, monitors)
``gateway``        the lifecycle; it answers the operator's queries (its session is a client
                   of the router it hosts, :class:`gateway.bus.LockedRouter`)
=================  ==========================================================================

Every identity may declare subscribers and receive what the router forwards; no identity may
put where the table does not say so, and a session without credentials, or with a wrong
password, is refused at connection. The lifecycle can therefore come only from the gateway,
commands only from the control process, I/O state only from the Modbus driver.

**Topology.** zenoh's user/password authentication runs one way: the side that accepts a link
learns the connecting side's user name, not the reverse (measured with zenoh 1.10: on a
peer-to-peer link the connecting side cannot match the other to any subject, so a default-deny
list blocks the link both ways). So with credentials every process is a *client* of the
router and listens on nothing: the router accepts every link, knows every user, and is the
one place the list is applied. The cost is the router hop on the loop's two zenoh legs and
the router's work: `leadthrough bench --profile fd --rates 250 --cycles 3000 [--locked-bus]`,
two adjacent pairs on 2026-11-27, read 85-130 µs more per leg (p50) and the gateway's CPU
0.28 → 0.50-0.58 ms per 4 ms cycle.

**Credentials file.** zenoh's dictionary format, one ``identity:password`` line per identity
and nothing else (zenoh refuses comments and blank lines). The router reads it whole (its
dictionary of accepted users); every other process reads its own line. It must be readable by
the service user only: a file with any group or other permission bit, or owned by another user,
is refused. ``deploy/install.sh`` writes one with random passwords.

Refused messages are dropped by zenoh inside the router and never reach a driver; the router
counts them per identity, action and key (gateway/router, read by
:mod:`gateway.bus_refusals`), and `leadthrough status` names them.
"""

from __future__ import annotations

import json
import os
import re
import secrets
import stat
from collections.abc import Callable
from pathlib import Path
from typing import Any

from gateway.errors import ConfigError
from gateway.messages import Keys

GATEWAY = "gateway"
CONTROL = "control"
CAN_DRIVER = "can-driver"
MODBUS_DRIVER = "modbus-driver"
OPERATOR = "operator"
OBSERVER = "observer"
IDENTITIES = (GATEWAY, CONTROL, CAN_DRIVER, MODBUS_DRIVER, OPERATOR, OBSERVER)
#: Shortest password accepted [characters]: the file is machine-written (install script).
MIN_PASSWORD_CHARS = 16

_LINE_RE = re.compile(r"^([a-z][a-z-]*):(\S+)$")

#: identity → the keys it may put (functions of the cell's :class:`~gateway.messages.Keys`)
PUTS: dict[str, Callable[[Keys], list[str]]] = {
    CONTROL: lambda k: [
        k.joint_command,
        k.pressure_setpoint,
        k.health("control"),
        k.control_telemetry,
        k.experiment,
    ],
    CAN_DRIVER: lambda k: [
        k.joint_state,
        k.state_window,
        k.health("can_driver"),
        k.driver_telemetry,
    ],
    MODBUS_DRIVER: lambda k: [k.io_state, k.health("modbus_driver"), k.driver_telemetry],
    GATEWAY: lambda k: [k.lifecycle],
}
#: identity → the keys it may query
QUERIES: dict[str, Callable[[Keys], list[str]]] = {OPERATOR: lambda k: [k.request]}
#: declarations every identity may make and receive (what routing needs)
_DECLARATIONS = [
    "declare_subscriber",
    "declare_queryable",
    "liveliness_token",
    "declare_liveliness_subscriber",
    "liveliness_query",
]


def read_credentials(path: str | Path) -> dict[str, str]:
    """``{identity: password}`` from the credentials file; :class:`ConfigError` naming the
    file (and line) when it is missing, readable by others, not the user's, or malformed."""
    p = Path(path)
    where = f"[bus].credentials_file {p}"
    try:
        st = p.stat()
        text = p.read_text(encoding="utf-8")
    except OSError as exc:
        raise ConfigError(f"{where}: cannot read: {exc.strerror or exc}") from None
    if st.st_mode & (stat.S_IRWXG | stat.S_IRWXO):
        raise ConfigError(
            f"{where}: mode {stat.S_IMODE(st.st_mode):04o} lets other users read or change "
            f"it; it must be readable by the service user only (chmod 600)"
        )
    if st.st_uid != os.geteuid():
        raise ConfigError(f"{where}: owned by uid {st.st_uid}, not by this user ({os.geteuid()})")
    out: dict[str, str] = {}
    for number, raw in enumerate(text.splitlines(), start=1):
        m = _LINE_RE.match(raw)
        if m is None:
            raise ConfigError(
                f"{where}:{number}: expected 'identity:password' (no blanks, comments or spaces)"
            )
        name, password = m.groups()
        if name not in IDENTITIES:
            raise ConfigError(f"{where}:{number}: unknown identity {name!r}; known {IDENTITIES}")
        if name in out:
            raise ConfigError(f"{where}:{number}: identity {name!r} given twice")
        if len(password) < MIN_PASSWORD_CHARS:
            raise ConfigError(
                f"{where}:{number}: the password of {name!r} is shorter than "
                f"{MIN_PASSWORD_CHARS} characters"
            )
        out[name] = password
    return out


def write_credentials(path: str | Path, identities: tuple[str, ...] = IDENTITIES) -> Path:
    """Write a credentials file with a random password per identity, mode 600 from its
    creation (for the virtual cell, tests and benchmarks; ``deploy/install.sh`` writes the
    cell PC's). Returns the path."""
    p = Path(path)
    fd = os.open(p, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
    with os.fdopen(fd, "w", encoding="utf-8") as fh:
        os.fchmod(fh.fileno(), 0o600)
        fh.write("".join(f"{i}:{secrets.token_hex(16)}\n" for i in identities))
    return p


def password_of(path: str | Path, identity: str) -> str:
    """The password of ``identity`` in the credentials file (ConfigError when absent)."""
    creds = read_credentials(path)
    if identity not in creds:
        raise ConfigError(f"[bus].credentials_file {path}: no line for identity {identity!r}")
    return creds[identity]


def access_control(keys: Keys) -> dict[str, Any]:
    """The router's access-control list (zenoh's ``access_control`` section): default deny,
    declarations and deliveries for every identity, puts and queries per the tables."""
    everything = f"{keys.prefix}/**"
    rules: list[dict[str, Any]] = [
        {
            "id": "declare",
            "permission": "allow",
            "flows": ["ingress", "egress"],
            "messages": _DECLARATIONS,
            "key_exprs": [everything],
        },
        {
            "id": "deliver",
            "permission": "allow",
            "flows": ["egress"],
            "messages": ["put", "delete", "reply"],
            "key_exprs": [everything],
        },
    ]
    policies: list[dict[str, Any]] = [
        {"rules": ["declare", "deliver"], "subjects": list(IDENTITIES)}
    ]
    for table, message in ((PUTS, "put"), (QUERIES, "query")):
        for identity, key_list in table.items():
            rule_id = f"{message}-{identity}"
            rules.append(
                {
                    "id": rule_id,
                    "permission": "allow",
                    "flows": ["ingress"],
                    "messages": [message],
                    "key_exprs": key_list(keys),
                }
            )
            policies.append({"rules": [rule_id], "subjects": [identity]})
    # the gateway serves the request key: the operator's queries go out to it, its replies in
    rules += [
        {
            "id": "serve-gateway",
            "permission": "allow",
            "flows": ["egress"],
            "messages": ["query"],
            "key_exprs": [keys.request],
        },
        {
            "id": "reply-gateway",
            "permission": "allow",
            "flows": ["ingress"],
            "messages": ["reply"],
            "key_exprs": [keys.request],
        },
    ]
    policies.append({"rules": ["serve-gateway", "reply-gateway"], "subjects": [GATEWAY]})
    return {
        "enabled": True,
        "default_permission": "deny",
        "rules": rules,
        "subjects": [{"id": name, "usernames": [name]} for name in IDENTITIES],
        "policies": policies,
    }


def insert_router_security(cfg: Any, credentials_file: str | Path, keys: Keys) -> None:
    """Authenticate every link against the credentials file and apply :func:`access_control`
    (``cfg`` a ``zenoh.Config`` of the router)."""
    creds = read_credentials(credentials_file)
    missing = [i for i in IDENTITIES if i not in creds and i != OBSERVER]
    if missing:
        raise ConfigError(f"[bus].credentials_file {credentials_file}: no line for {missing}")
    cfg.insert_json5("transport/auth/usrpwd/user", json.dumps(GATEWAY))
    cfg.insert_json5("transport/auth/usrpwd/password", json.dumps(creds[GATEWAY]))
    cfg.insert_json5(
        "transport/auth/usrpwd/dictionary_file", json.dumps(str(Path(credentials_file).resolve()))
    )
    cfg.insert_json5("access_control", json.dumps(access_control(keys)))


def insert_session_credentials(cfg: Any, credentials_file: str | Path, identity: str) -> None:
    """Present ``identity``'s credentials on the link to the router (``cfg`` a zenoh.Config)."""
    if identity not in IDENTITIES:
        raise ConfigError(f"unknown bus identity {identity!r}; known {IDENTITIES}")
    cfg.insert_json5("transport/auth/usrpwd/user", json.dumps(identity))
    cfg.insert_json5(
        "transport/auth/usrpwd/password", json.dumps(password_of(credentials_file, identity))
    )
