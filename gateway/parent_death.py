"""A process a harness starts stops when the harness dies.

The virtual cell's harness (sim_bridge/harness.py ``Stack``) starts the simulator and the
gateway in sessions of their own, so a signal to the harness's process group does not reach
them. Killed (SIGTERM, or kill -9 of a test runner), the harness used to leave them running:
a gateway holding the arm and a simulator stepping it, nobody's children. The harness now names
itself in :data:`ENV`; :func:`die_with_parent_from_env`, called first thing by ``leadthrough``,
asks Linux to SIGTERM the process when that parent dies, and the gateway's own SIGTERM path
stops its children and brakes the arm (the gateway's children already die with the gateway,
gateway/children.py).
"""

from __future__ import annotations

import ctypes
import os
import signal

from gateway.errors import ConfigError

#: the pid of the process whose death must stop this one (set by the harness for its children)
ENV = "LEADTHROUGH_DIE_WITH_PID"
PR_SET_PDEATHSIG = 1


def die_with_parent_from_env(environ: dict[str, str] | os._Environ = os.environ) -> bool:
    """If :data:`ENV` names this process's parent: SIGTERM on its death (``prctl``), and
    SIGTERM now if it has died already. The variable is taken out of ``environ`` so that this
    process's own children do not inherit it (they have a parent of their own). Returns
    whether it was set; ConfigError naming the value when it is not a pid."""
    value = environ.pop(ENV, None)
    if value is None:
        return False
    try:
        parent = int(value)
    except ValueError:
        raise ConfigError(f"environment {ENV}={value!r} is not a process id") from None
    if parent <= 0:
        raise ConfigError(f"environment {ENV}={value!r} is not a process id")
    # not Linux: the harness's own stop path still stops the stack; else the parent may have
    # died between the fork and the prctl, and then we are someone else's
    if sigterm_on_parent_death() and os.getppid() != parent:
        os.kill(os.getpid(), signal.SIGTERM)
    return True


def sigterm_on_parent_death() -> bool:
    """Ask Linux to SIGTERM this process when the thread that started it exits
    (``prctl(PR_SET_PDEATHSIG)``); False where that cannot be asked (not Linux). Also what
    the gateway's children do before exec (gateway/children.py)."""
    try:
        libc = ctypes.CDLL("libc.so.6", use_errno=True)
        libc.prctl(PR_SET_PDEATHSIG, signal.SIGTERM)
    except OSError:
        return False
    return True
