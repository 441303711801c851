"""`leadthrough config check CELL.toml`: every section of a cell config read by the loader of the
process that uses it, every error at once, each naming the file, the section and the key.
`leadthrough config schema` prints a JSON Schema of the cell config for editors (TOML language
servers such as Taplo take one): sections, keys and their types, unknown keys refused.

The gateway runs the same check when it starts its children (gateway/supervisor.py,
:data:`GATEWAY_START_SECTIONS`): an error in any of those sections is reported there, once, and
the gateway exits with EX_CONFIG (78), which the systemd unit does not restart, instead of
starting children that would each refuse it. ``[control]`` is left to the control process (its
loader's imports take seconds; it exits 78 on a bad section, and the gateway faults naming it
without restarting it).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import types
import typing
from collections.abc import Callable
from pathlib import Path
from typing import Any

from gateway.errors import EXIT_CONFIG, ConfigError


def _bus(path: Path, raw: dict[str, Any]) -> object:
    from gateway.bus import bus_config_from

    return bus_config_from(raw, str(path))


def _gateway(path: Path, raw: dict[str, Any]) -> object:
    from gateway.gateway_config import load_gateway_config

    return load_gateway_config(path)


def _can(path: Path, raw: dict[str, Any]) -> object:
    from drivers.can.config import load_can_config

    return load_can_config(path)


def _modbus(path: Path, raw: dict[str, Any]) -> object:
    from drivers.modbus.config import ModbusDriverConfig

    return ModbusDriverConfig.from_cell_config(raw, str(path))


def _control(path: Path, raw: dict[str, Any]) -> object:
    from control.cell_config import load_control_config

    return load_control_config(path)


def _realtime(path: Path, raw: dict[str, Any]) -> object:
    from gateway.realtime import realtime_config_from

    return realtime_config_from(raw, str(path))


def _ros2(path: Path, raw: dict[str, Any]) -> object:
    from gateway.ros2 import ros2_config_from

    return ros2_config_from(raw, str(path))


#: the sections the gateway checks before it starts its children (its own and [bus] are read
#: before that, by load_gateway_config)
GATEWAY_START_SECTIONS = ("can", "modbus", "realtime")

#: section → its loader (the one the process that reads it uses)
LOADERS: dict[str, Callable[[Path, dict[str, Any]], object]] = {
    "bus": _bus,
    "gateway": _gateway,
    "can": _can,
    "modbus": _modbus,
    "control": _control,
    "realtime": _realtime,
    "ros2": _ros2,
}


def check_cell(path: Path, sections: tuple[str, ...] | None = None) -> dict[str, str]:
    """Section → its error ("" when it is fine), for ``sections`` (default: all). A file that
    cannot be read or parsed is one error under ``"file"``."""
    from gateway.config import load_toml

    try:
        raw = load_toml(path)
    except ConfigError as exc:
        return {"file": str(exc)}
    result: dict[str, str] = {}
    for section, load in LOADERS.items():
        if sections is not None and section not in sections:
            continue
        try:
            load(path, raw)
        except ConfigError as exc:
            result[section] = str(exc)
        else:
            result[section] = ""
    return result


def problems(path: Path, sections: tuple[str, ...] | None = None) -> list[str]:
    """The errors of :func:`check_cell`, one line each (empty: the config is fine)."""
    return _distinct(check_cell(path, sections))


def _distinct(result: dict[str, str]) -> list[str]:
    seen: list[str] = []
    for message in result.values():
        if message and message not in seen:  # an unknown section fails every loader alike
            seen.append(message)
    return seen


def _section_classes() -> dict[str, type]:
    from control.config import ControlConfig
    from drivers.can.config import CanDriverConfig
    from drivers.modbus.config import ModbusDriverConfig
    from gateway.bus import BusConfig
    from gateway.gateway_config import GatewayConfig
    from gateway.realtime import Realtime
    from gateway.ros2 import Ros2Config

    return {
        "bus": BusConfig,
        "gateway": GatewayConfig,
        "can": CanDriverConfig,
        "modbus": ModbusDriverConfig,
        "control": ControlConfig,
        "realtime": Realtime,
        "ros2": Ros2Config,
    }


def _type_schema(hint: Any) -> dict[str, Any]:
    """JSON Schema of one field's type (what TOML can write for it)."""
    origin = typing.get_origin(hint)
    args = typing.get_args(hint)
    if hint is bool:
        return {"type": "boolean"}
    if hint is int:
        return {"type": "integer"}
    if hint is float:
        return {"type": "number"}
    if hint is str or hint is Path:
        return {"type": "string"}
    if hint is type(None):
        return {"type": "null"}
    if origin in (typing.Union, types.UnionType):
        return {"anyOf": [_type_schema(a) for a in args]}
    if origin is typing.Literal:
        return {"enum": list(args)}
    if origin in (tuple, list):
        if origin is tuple and args and args[-1] is not Ellipsis:
            items = [_type_schema(a) for a in args]
            return {"type": "array", "prefixItems": items, "minItems": len(items),
                    "maxItems": len(items)}  # fmt: skip
        return {"type": "array", "items": _type_schema(args[0]) if args else {}}
    if origin is dict or hint is dict:
        return {"type": "object"}
    if dataclasses.is_dataclass(hint):
        return _class_schema(hint)
    return {}


def _class_schema(cls: type) -> dict[str, Any]:
    hints = typing.get_type_hints(cls)
    props: dict[str, Any] = {}
    required: list[str] = []
    for f in dataclasses.fields(cls):
        if not f.init:
            continue
        schema = _type_schema(hints[f.name])
        if f.default is not dataclasses.MISSING and isinstance(
            f.default, bool | int | float | str | tuple
        ):
            schema["default"] = list(f.default) if isinstance(f.default, tuple) else f.default
        elif f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING:
            required.append(f.name)
        props[f.name] = schema
    out: dict[str, Any] = {"type": "object", "properties": props, "additionalProperties": False}
    if required:
        out["required"] = required
    return out


def cell_schema() -> dict[str, Any]:
    """The cell config's JSON Schema, from the sections' own dataclasses."""
    return {
        "$schema": "https://json-schema.org/draft/2020-12/schema",
        "title": "leadthrough cell config",
        "type": "object",
        "properties": {name: _class_schema(cls) for name, cls in _section_classes().items()},
        "additionalProperties": False,
    }


def configure_parser(p: argparse.ArgumentParser) -> None:
    p.description = (
        "Check a cell config: every section read as the process that uses it reads it; every "
        "error, with file, section and key. Exit 0 when it is fine, 78 (EX_CONFIG) otherwise."
    )
    p.add_argument(
        "action",
        choices=["check", "schema"],
        help="check FILE, or print the cell config's JSON Schema",
    )
    p.add_argument("file", type=Path, nargs="?", help="cell config TOML (for check)")


def cli_main(args: argparse.Namespace) -> int:
    if args.action == "schema":
        print(json.dumps(cell_schema(), indent=1))
        return 0
    if args.file is None:
        raise ConfigError("config check: name the cell config file to check")
    result = check_cell(args.file)
    errors = _distinct(result)
    for section, message in result.items():
        if not message:
            print(f"[{section}] ok")
    for message in errors:
        print(f"error: {message}", file=sys.stderr)
    if errors:
        print(f"{args.file}: {len(errors)} error(s)", file=sys.stderr)
        return EXIT_CONFIG
    print(f"{args.file}: ok")
    return 0
