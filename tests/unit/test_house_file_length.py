"""Files of one idea (issue 49): no source file of the product's folders over 600 lines.

The bound is the issue's. A file that grows past it holds more than one idea: split it where
its ideas part, never by moving lines into a neighbour that holds another.
"""

from __future__ import annotations

from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
#: the folders the design names for the product and its virtual cell
FOLDERS = ("gateway", "drivers", "control", "sim_bridge", "deploy")
SUFFIXES = (".py", ".rs")
MAX_LINES = 600


def _sources() -> list[Path]:
    return sorted(
        p
        for folder in FOLDERS
        for p in (REPO / folder).rglob("*")
        if p.suffix in SUFFIXES and p.is_file() and "target" not in p.relative_to(REPO).parts
    )


def test_the_folders_hold_sources_to_measure():
    names = {p.relative_to(REPO).as_posix() for p in _sources()}
    assert "control/process.py" in names and "drivers/can/rt/src/core.rs" in names


def test_no_product_source_file_is_over_600_lines():
    over = {
        p.relative_to(REPO).as_posix(): n
        for p in _sources()
        if (n := len(p.read_text(encoding="utf-8").splitlines())) > MAX_LINES
    }
    assert not over, f"files over {MAX_LINES} lines (split each where its ideas part): {over}"
