"""Adapters chosen by name in configuration, imported lazily, open to entry points.

Like python-can's interface registry: built-in names map to ``"module:attribute"`` strings and
are imported only when asked for; any installed package can add more through an entry-point
group, e.g. in its ``pyproject.toml``::

    [project.entry-points."leadthrough.can_adapters"]
    my_vendor = "my_package.can:MyVendorAdapter"

Built-ins win over entry points of the same name.
"""

from __future__ import annotations

import importlib
import importlib.metadata
from typing import Any

from gateway.errors import ConfigError

#: group -> name -> "module:attribute", for adapters shipped with this package.
BUILTINS: dict[str, dict[str, str]] = {
    "leadthrough.can_adapters": {
        "ltc_dbc": "drivers.can.ltc:LtcAdapter",  # LTC-1, classic CAN (PROTOCOL.md §2)
        "ltc_fd": "drivers.can.ltc_fd:LtcFdAdapter",  # LTC-1F, CAN FD (PROTOCOL.md §10)
        "cia402": "drivers.can.cia402:Cia402Adapter",  # CiA 402 drives over CANopen
    },
}


def _entry_points(group: str) -> dict[str, importlib.metadata.EntryPoint]:
    return {ep.name: ep for ep in importlib.metadata.entry_points(group=group)}


def available(group: str) -> list[str]:
    """Every name :func:`load_adapter` would accept for ``group``, sorted."""
    return sorted(set(BUILTINS.get(group, {})) | set(_entry_points(group)))


def _import(target: str) -> Any:
    module_name, _, attribute = target.partition(":")
    obj: Any = importlib.import_module(module_name)
    for part in filter(None, attribute.split(".")):
        obj = getattr(obj, part)
    return obj


def load_adapter(group: str, name: str) -> Any:
    """The object registered as ``name`` in ``group`` (usually a class), imported now.

    Raises ConfigError listing the available names for an unknown ``name``, and naming the
    target for one that fails to import.
    """
    builtin = BUILTINS.get(group, {}).get(name)
    if builtin is not None:
        target = builtin
        loader = lambda: _import(builtin)  # noqa: E731
    else:
        ep = _entry_points(group).get(name)
        if ep is None:
            raise ConfigError(
                f"unknown adapter {name!r} for {group}; available: {available(group)}"
            )
        target = ep.value
        loader = ep.load
    try:
        return loader()
    except (ImportError, AttributeError) as exc:
        raise ConfigError(f"adapter {name!r} ({target}) cannot be imported: {exc}") from exc
