"""`leadthrough config check CELL.toml`: every section of a cell config read by the loader of the
process that uses it, every error at once, each naming the file, the section and the key.
`leadthrough config schema` prints a JSON Schema of the cell config for editors (TOML language
servers such as Taplo take one): sections, keys and their types, unknown keys refused.

The sections, their loaders and their config classes come from the registry of cell-config
sections (gateway/cell_section.py: pyproject.toml's entry points), so this module imports no
process; a registry that cannot be read is a ConfigError naming the broken entry point.

The gateway runs the same check when it starts its children (gateway/supervisor.py,
:func:`gateway_start_sections`): an error in any of those sections is reported there, once, and
the gateway exits with EX_CONFIG (78), which the systemd unit does not restart, instead of
starting children that would each refuse it. ``[control]`` is left to the control process (it
exits 78 on a bad section, and the gateway faults naming it without restarting it).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import types
import typing
from pathlib import Path
from typing import Any

from gateway.cell_section import cell_sections
from gateway.errors import EXIT_CONFIG, ConfigError


def gateway_start_sections() -> tuple[str, ...]:
    """The sections the gateway checks before it starts its children (``checked_at_start`` in
    the registry: its own and [bus] it reads before that, by load_gateway_config)."""
    return tuple(section.name for section in cell_sections() if section.checked_at_start)


def check_cell(path: Path, sections: tuple[str, ...] | None = None) -> dict[str, str]:
    """Section → its error ("" when it is fine), for ``sections`` (default: all). A file that
    cannot be read or parsed is one error under ``"file"``."""
    from gateway.config import load_toml

    registered = cell_sections()
    try:
        raw = load_toml(path)
    except ConfigError as exc:
        return {"file": str(exc)}
    result: dict[str, str] = {}
    for section in registered:
        if sections is not None and section.name not in sections:
            continue
        try:
            section.loader(path, raw)
        except ConfigError as exc:
            result[section.name] = str(exc)
        else:
            result[section.name] = ""
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
        "properties": {s.name: _class_schema(s.config_class) for s in cell_sections()},
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
