"""Reading Linux ``/proc/<pid>/stat`` and ``/proc/<pid>/task/<tid>/stat`` (proc(5)).

The one place that parses those lines: the state, the parent and the CPU time of a process
or a thread, and the children of a process. The command name (field 2) may hold spaces and
parentheses, so a line is split after its last closing parenthesis.
"""

from __future__ import annotations

import os
from pathlib import Path

_CLK_TCK = os.sysconf("SC_CLK_TCK")


def fields(stat: Path) -> list[str] | None:
    """The fields of ``stat`` from field 3 (the state) on, or None if it is gone."""
    try:
        text = stat.read_text()
    except OSError:
        return None
    return text[text.rindex(")") + 2 :].split()


def cpu_s(stat: Path) -> float | None:
    """utime + stime of the process or thread whose stat file is ``stat`` [s], or None if it
    is gone (a process's file counts all its threads)."""
    f = fields(stat)
    return None if f is None else (int(f[11]) + int(f[12])) / _CLK_TCK  # fields 14, 15


def process_cpu_s(pid: int) -> float | None:
    """utime + stime of process ``pid``, all its threads [s], or None if it is gone."""
    return cpu_s(Path(f"/proc/{pid}/stat"))


def thread_cpu_s(name: str) -> float:
    """utime + stime of this process's thread called ``name`` [s] (the first such)."""
    for task in Path("/proc/self/task").iterdir():
        try:
            comm = (task / "comm").read_text().strip()
        except OSError:
            continue
        if comm == name:
            found = cpu_s(task / "stat")
            if found is not None:
                return found
    raise LookupError(f"this process has no thread named {name!r}")


def state(pid: int) -> str | None:
    """The state letter of process ``pid`` (R, S, D, Z, ...), or None if it is gone."""
    f = fields(Path(f"/proc/{pid}/stat"))
    return None if f is None else f[0]


def children(pid: int, *, zombies: bool = True) -> list[int]:
    """PIDs whose parent is ``pid``; ``zombies=False`` leaves out the exited ones not yet
    reaped (state Z, see :func:`state`)."""
    out = []
    for entry in os.listdir("/proc"):
        if not entry.isdigit():
            continue
        f = fields(Path(f"/proc/{entry}/stat"))
        if f is not None and int(f[1]) == pid and (zombies or f[0] != "Z"):
            out.append(int(entry))
    return out
