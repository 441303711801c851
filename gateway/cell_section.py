"""The cell config's sections, registered in one place: the entry-point group
``leadthrough.cell_sections`` of pyproject.toml. Each entry's name is a table of the cell config
and its value the :class:`CellSection` that the package reading that table defines beside its
config class (``can = "drivers.can.config:CELL_SECTION"``), so the gateway knows the sections
without importing a process. The config check (gateway/config_check.py) with its JSON Schema,
the gateway's check before it starts its children, and the refusal of a section nobody reads
(gateway/bus.py) all come from here.

Entry points are the installed package's metadata: after a change to the group, re-install
(``pip install -e .``; `make` does, its venv stamp depends on pyproject.toml).
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from dataclasses import dataclass
from importlib.metadata import EntryPoint, entry_points
from pathlib import Path
from typing import Any

from gateway.errors import ConfigError

#: the entry-point group the sections are declared in
GROUP = "leadthrough.cell_sections"

#: (the cell config's path, the parsed file) → the section's config
SectionLoader = Callable[[Path, dict[str, Any]], object]


@dataclass(frozen=True)
class CellSection:
    """One section of the cell config, as the package that reads it declares it."""

    #: the TOML table (``"can"`` for ``[can]``); the entry point's name
    name: str
    #: reads the section as the process that uses it does; a bad section raises ConfigError
    #: naming the file, the section and the key
    loader: SectionLoader
    #: the frozen dataclass whose fields are the section's keys (the JSON Schema's source)
    config_class: type
    #: where the section comes in the config check's report and in the JSON Schema, lowest
    #: first (then by name). Installed entry points come sorted by name, whatever the order
    #: pyproject.toml declares them in, so the order is the section's to say.
    order: int
    #: the gateway checks the section before it starts its children (the children's sections;
    #: it reads its own and ``[bus]`` before that)
    checked_at_start: bool = False


def _registered(found: Iterable[EntryPoint] | None) -> tuple[EntryPoint, ...]:
    """The group's entry points; none is a ConfigError."""
    eps = tuple(entry_points(group=GROUP) if found is None else found)
    if not eps:
        raise ConfigError(
            f"no cell-config section is registered (entry-point group {GROUP!r}): the "
            "leadthrough package is not installed; install it (pip install -e ., or make)"
        )
    return eps


def section_names(found: Iterable[EntryPoint] | None = None) -> tuple[str, ...]:
    """The registered sections' names, without importing their packages (``found``: the entry
    points to read instead of the installed ones)."""
    return tuple(ep.name for ep in _registered(found))


def cell_sections(found: Iterable[EntryPoint] | None = None) -> tuple[CellSection, ...]:
    """Every registered section, loaded, by :attr:`CellSection.order` (the config check reports
    them, and the JSON Schema lists them, in that order). An entry point that cannot be loaded,
    is not a :class:`CellSection`, names another section or repeats one is a ConfigError naming
    it."""
    sections: dict[str, CellSection] = {}
    for ep in _registered(found):
        where = f"cell-config section entry point {ep.name} = {ep.value!r} (group {GROUP!r})"
        try:
            section = ep.load()
        except Exception as exc:  # whatever its import raised: the entry point is broken
            raise ConfigError(f"{where}: cannot be loaded: {type(exc).__name__}: {exc}") from None
        if not isinstance(section, CellSection):
            raise ConfigError(f"{where}: is a {type(section).__name__}, not a CellSection")
        if section.name != ep.name:
            raise ConfigError(f"{where}: declares the section [{section.name}], not [{ep.name}]")
        if ep.name in sections:
            raise ConfigError(f"{where}: the section [{ep.name}] is registered twice")
        sections[ep.name] = section
    return tuple(sorted(sections.values(), key=lambda s: (s.order, s.name)))
