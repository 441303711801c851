"""Placement of the product's processes ([realtime]) and of the virtual cell (the harness): what
the OS grants is applied and reported, what it refuses is reported and the process runs on, and a
bad section is refused naming the setting."""

from __future__ import annotations

import os
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest
import tomli_w

from gateway.cli import main
from gateway.errors import EXIT_CONFIG, ConfigError
from gateway.realtime import (
    Realtime,
    apply_realtime,
    apply_scheduling,
    below_the_cycle,
    normal_priority_children,
    realtime_config_from,
)
from sim_bridge.harness import pin_process_tree, placement


@pytest.fixture
def own_affinity():
    """The test process's CPUs, restored afterwards (the tests below change them)."""
    cpus = os.sched_getaffinity(0)
    yield sorted(cpus)
    os.sched_setaffinity(0, cpus)


@pytest.mark.parametrize(
    "section, names",
    [
        ({"cpu_affinity": [0, 0]}, "cpu_affinity"),
        ({"cpu_affinity": [-1]}, "cpu_affinity"),
        ({"sched_fifo_priority": 100}, "sched_fifo_priority"),
        ({"sched_fifo_priority": 2}, "sched_fifo_priority"),  # the supervisors would be at 0
        ({"mlockall": "yes"}, "mlockall"),
        ({"cpu_set": [0]}, "cpu_set"),
    ],
)
def test_a_bad_realtime_section_is_refused_naming_the_setting(section, names):
    with pytest.raises(ConfigError, match=names):
        realtime_config_from({"realtime": section}, "cell.toml")


def test_the_default_places_nothing(own_affinity):
    assert realtime_config_from({}, "cell.toml") == Realtime()
    assert apply_realtime(Realtime(), "control") == {}
    assert sorted(os.sched_getaffinity(0)) == own_affinity


def test_affinity_is_applied_and_a_refusal_is_reported_not_raised(own_affinity, caplog):
    first = own_affinity[0]
    assert apply_scheduling((first,), 0, False, "test") == {"cpu_affinity": [first]}
    assert os.sched_getaffinity(0) == {first}
    report = apply_scheduling((4095,), 0, False, "test")  # no such CPU
    assert report["cpu_affinity"].startswith("not applied")
    assert "cpu_affinity" in caplog.text and os.sched_getaffinity(0) == {first}


def test_the_cycle_gets_the_priority_and_the_supervisors_run_two_below(monkeypatch):
    asked = []
    monkeypatch.setattr(os, "sched_setscheduler", lambda *a: asked.append(a[2].sched_priority))
    cfg = Realtime(sched_fifo_priority=40)
    for process in ("gateway", "modbus-driver", "can-driver", "control", "record", "sim"):
        apply_realtime(cfg, process)
    assert asked == [38, 38, 40, 40]
    asked.clear()
    for process in ("gateway", "modbus-driver", "can-driver", "control"):
        apply_realtime(Realtime(), process)
    assert asked == []


def test_a_refused_fifo_priority_and_mlockall_are_reported(monkeypatch):
    def refuse(*_):
        raise PermissionError(1, "Operation not permitted")

    monkeypatch.setattr(os, "sched_setscheduler", refuse)
    report = apply_realtime(Realtime(sched_fifo_priority=10, mlockall=True), "control")
    assert report["sched_fifo_priority"].startswith("not applied")
    # mlockall either took effect (a root test run) or says why not; never an exception
    assert report["mlockall"] is True or report["mlockall"].startswith("not applied")


def test_a_product_process_with_a_bad_realtime_section_exits_with_the_config_code(tmp_path):
    cell = tmp_path / "cell.toml"
    cell.write_bytes(tomli_w.dumps({"realtime": {"sched_fifo_priority": 120}}).encode())
    assert main(["control", "--config", str(cell)]) == EXIT_CONFIG


def test_the_harness_gives_the_simulator_one_cpu_and_the_product_the_others(own_affinity):
    split = placement()
    if len(own_affinity) < 2:
        assert split is None
        return
    assert split == (tuple(own_affinity[:-1]), (own_affinity[-1],))
    os.sched_setaffinity(0, {own_affinity[0]})
    assert placement() is None


def test_a_process_tree_is_pinned_thread_by_thread_children_included(own_affinity):
    script = (
        "import subprocess, sys, threading, time\n"
        "threading.Thread(target=time.sleep, args=(30,), daemon=True).start()\n"
        "subprocess.Popen([sys.executable, '-c', 'import time; time.sleep(30)'])\n"
        "print('up', flush=True); time.sleep(30)\n"
    )
    proc = subprocess.Popen([sys.executable, "-c", script], stdout=subprocess.PIPE)
    try:
        assert proc.stdout is not None and proc.stdout.readline() == b"up\n"
        time.sleep(0.1)  # the grandchild has exec'd
        target = (own_affinity[-1],)
        assert pin_process_tree(proc.pid, target) >= 3  # main, its thread, the grandchild
        tasks = list(Path(f"/proc/{proc.pid}/task").iterdir())
        assert len(tasks) == 2 and all(os.sched_getaffinity(int(t.name)) == {target[0]}
                                       for t in tasks)  # fmt: skip
        children = (tasks[0] / "children").read_text().split()
        children += (tasks[1] / "children").read_text().split()
        assert len(children) == 1 and os.sched_getaffinity(int(children[0])) == {target[0]}
        assert pin_process_tree(2**22 + 7, target) == 0  # gone: nothing, no error
    finally:
        for c in Path(f"/proc/{proc.pid}/task").glob("*/children"):
            for pid in c.read_text().split():
                os.kill(int(pid), 9)
        proc.kill()
        proc.wait()


def test_a_child_started_by_a_fifo_thread_runs_at_normal_priority_and_the_thread_keeps_fifo():
    """normal_priority_children: the plan builder's worker must not inherit the cycle's
    SCHED_FIFO (a CPU-bound child at that priority holds a shared core)."""
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(5))
    except PermissionError:
        pytest.skip("no CAP_SYS_NICE here: SCHED_FIFO cannot be set")
    probe = "import os; print(os.sched_getscheduler(0), os.sched_getparam(0).sched_priority)"
    try:
        with normal_priority_children():
            inside = os.sched_getscheduler(0)
            child = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True)
        after = os.sched_getscheduler(0), os.sched_getparam(0).sched_priority
    finally:
        os.sched_setscheduler(0, os.SCHED_OTHER, os.sched_param(0))
    assert child.stdout.split() == [str(os.SCHED_OTHER), "0"], child.stdout + child.stderr
    assert inside == os.SCHED_OTHER and after == (os.SCHED_FIFO, 5)


def test_a_process_the_gateway_starts_runs_at_normal_priority():
    """The gateway runs at SCHED_FIFO below the cycle; the children it starts (control, which
    imports and builds its model first) must not inherit it: they place themselves."""
    from gateway.children import _die_with_parent

    probe = "import os; print(os.sched_getscheduler(0), os.sched_getparam(0).sched_priority)"
    seen: dict[str, object] = {}

    def supervisor_thread() -> None:
        try:
            os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(38))
        except PermissionError:
            seen["skip"] = True
            return
        child = subprocess.run(
            [sys.executable, "-c", probe], capture_output=True, text=True,
            preexec_fn=_die_with_parent,
        )  # fmt: skip
        seen["child"] = child.stdout.split()
        seen["self"] = os.sched_getscheduler(0), os.sched_getparam(0).sched_priority

    t = threading.Thread(target=supervisor_thread)
    t.start()
    t.join(30.0)
    if seen.get("skip"):
        pytest.skip("SCHED_FIFO not permitted here (no CAP_SYS_NICE)")
    assert seen == {"child": [str(os.SCHED_OTHER), "0"], "self": (os.SCHED_FIFO, 38)}


def test_the_slow_loop_drops_below_the_cycle_and_the_cycle_threads_keep_its_priority():
    """A thread at SCHED_FIFO 40 (the control process's main thread after [realtime]) starts
    a cycle thread, which inherits 40, then drops itself to 39; at normal scheduling nothing
    changes. Run in threads of their own: the test process keeps its scheduling."""
    seen: dict[str, object] = {}
    release = threading.Event()

    def cycle() -> None:
        release.wait(5.0)
        seen["cycle"] = os.sched_getparam(0).sched_priority

    def main_thread() -> None:
        try:
            os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(40))
        except PermissionError:
            seen["skip"] = True
            return
        worker = threading.Thread(target=cycle)
        worker.start()
        seen["returned"] = below_the_cycle("test")
        seen["slow"] = os.sched_getparam(0).sched_priority
        release.set()
        worker.join(5.0)

    t = threading.Thread(target=main_thread)
    t.start()
    t.join(10.0)
    if seen.get("skip"):
        pytest.skip("SCHED_FIFO not permitted here (no CAP_SYS_NICE)")
    assert seen == {"returned": 39, "slow": 39, "cycle": 40}
    assert below_the_cycle("test") is None  # this thread is at normal scheduling
