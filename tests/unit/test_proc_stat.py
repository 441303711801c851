"""sim_bridge.proc_stat: /proc stat lines read by their fields, whatever the command name."""

from __future__ import annotations

import os
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

from sim_bridge import proc_stat

BURN_S = 0.2


def test_a_command_name_with_spaces_and_parentheses_does_not_shift_the_fields(tmp_path):
    stat = tmp_path / "stat"
    stat.write_text("4242 (a) b (c) d) S 17 4242 4242 0 -1 4194560 1 0 0 0 250 50 0 0 20 0\n")
    fields = proc_stat.fields(stat)
    assert fields[0] == "S" and fields[1] == "17"
    assert proc_stat.cpu_s(stat) == pytest.approx(300 / os.sysconf("SC_CLK_TCK"))


def test_a_gone_process_reads_as_none(tmp_path):
    assert proc_stat.fields(tmp_path / "absent") is None
    assert proc_stat.cpu_s(tmp_path / "absent") is None


def test_a_named_thread_shows_the_cpu_it_burned_and_an_absent_name_is_refused():
    burned, done = threading.Event(), threading.Event()

    def burn():
        # the thread names itself as the Rust loop's thread is named (Linux comm)
        Path(f"/proc/self/task/{threading.get_native_id()}/comm").write_text("proc-stat-burn")
        end = time.thread_time() + BURN_S
        while time.thread_time() < end:
            pass
        burned.set()
        done.wait(10)

    thread = threading.Thread(target=burn)
    thread.start()
    try:
        assert burned.wait(10)
        assert BURN_S * 0.9 <= proc_stat.thread_cpu_s("proc-stat-burn") <= BURN_S + 0.1
    finally:
        done.set()
        thread.join()
    with pytest.raises(LookupError, match="no-such-thread"):
        proc_stat.thread_cpu_s("no-such-thread")


def test_children_and_their_state():
    child = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(30)"])
    try:
        assert child.pid in proc_stat.children(os.getpid())
        assert proc_stat.state(child.pid) in ("S", "R")
    finally:
        child.kill()
        child.wait()
    assert child.pid not in proc_stat.children(os.getpid())
    assert proc_stat.state(child.pid) is None
    assert not Path(f"/proc/{child.pid}").exists()


def test_an_exited_child_not_yet_reaped_is_listed_only_with_zombies():
    child = subprocess.Popen([sys.executable, "-c", "pass"])
    try:
        deadline = time.monotonic() + 10
        while proc_stat.state(child.pid) != "Z" and time.monotonic() < deadline:
            time.sleep(0.01)
        assert proc_stat.state(child.pid) == "Z"
        assert child.pid in proc_stat.children(os.getpid())
        assert child.pid not in proc_stat.children(os.getpid(), zombies=False)
    finally:
        child.wait()
