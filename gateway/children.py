"""The gateway's child processes: what the gateway keeps of each one, and what each does in the
fork before exec (normal scheduling, SIGTERM when the gateway dies)."""

from __future__ import annotations

import subprocess
from dataclasses import dataclass, field

from gateway.parent_death import sigterm_on_parent_death
from gateway.realtime import normal_priority_after_fork


@dataclass
class Child:
    name: str
    argv: list[str]
    proc: subprocess.Popen | None = None
    started_s: float = 0.0
    restart_at_s: float | None = None
    exits: list[int] = field(default_factory=list)
    #: it exited refusing its configuration: not restarted until `reset`
    config_refused: bool = False


def _die_with_parent() -> None:
    """In the child, before exec: normal scheduling (the gateway's own SCHED_FIFO is not for
    its children, gateway/realtime.py), and ask Linux to SIGTERM us when the gateway dies."""
    normal_priority_after_fork()
    # not Linux: the gateway's own shutdown path still stops the children
    sigterm_on_parent_death()
