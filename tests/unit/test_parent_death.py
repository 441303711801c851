"""gateway/parent_death.py: a process the harness starts stops when the harness dies."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest

from gateway.errors import ConfigError
from gateway.parent_death import ENV, die_with_parent_from_env

REPO = Path(__file__).resolve().parents[2]
#: a child that asks to die with the pid in ENV, says whether it asked and whether a process it
#: starts would still inherit the ask, and waits
CHILD = (
    "import os, time; from gateway.parent_death import ENV, die_with_parent_from_env; "
    "print(die_with_parent_from_env(), ENV in os.environ, flush=True); time.sleep(60)"
)


def test_without_the_variable_nothing_is_asked():
    assert die_with_parent_from_env({}) is False


@pytest.mark.parametrize("value", ["abc", "", "-3", "0"])
def test_a_value_that_is_not_a_pid_is_refused_naming_it(value):
    with pytest.raises(ConfigError, match=f"{ENV}={value!r} is not a process id"):
        die_with_parent_from_env({ENV: value})


def _gone(pid: int, timeout_s: float) -> bool:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        try:
            os.kill(pid, 0)
        except ProcessLookupError:
            return True
        time.sleep(0.05)
    return False


def test_a_child_stops_when_its_parent_is_killed_and_its_own_children_do_not_inherit_the_ask():
    # the parent starts the child (in a session of its own, as the harness does) and is
    # killed with SIGKILL: no code of the parent runs after it
    parent = textwrap.dedent(f"""
        import os, subprocess, sys, time
        env = {{**os.environ, {ENV!r}: str(os.getpid())}}
        child = subprocess.Popen([sys.executable, "-c", {CHILD!r}], env=env, cwd={str(REPO)!r},
                                 stdout=subprocess.PIPE, text=True, start_new_session=True)
        assert child.stdout.readline().split() == ["True", "False"]
        print(child.pid, flush=True)
        time.sleep(60)
    """)
    proc = subprocess.Popen([sys.executable, "-c", parent], stdout=subprocess.PIPE, text=True,
                            cwd=REPO)  # fmt: skip
    try:
        child = int(proc.stdout.readline())
        proc.send_signal(signal.SIGKILL)
        proc.wait(5)
        assert _gone(child, 5.0), f"pid {child} outlived its killed parent"
    finally:
        proc.kill()
        proc.wait()


def test_a_child_whose_parent_died_before_it_asked_stops_at_once():
    # the named pid is not the child's parent (the parent died and the child was adopted)
    env = {**os.environ, ENV: str(os.getpid() + 1_000_000)}
    child = subprocess.run([sys.executable, "-c", CHILD], env=env, cwd=REPO, timeout=30,
                           capture_output=True, text=True)  # fmt: skip
    assert child.returncode == -signal.SIGTERM, child
