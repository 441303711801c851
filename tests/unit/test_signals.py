"""gateway.signals.StopSignals: a stop signal sets the event without a lock in the handler, so a
process cannot hang in its own signal handler (see the module docstring)."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap
import threading
from pathlib import Path

from gateway.signals import StopSignals

ROOT = Path(__file__).resolve().parents[2]


def _child(body: str) -> subprocess.Popen[str]:
    code = "import os, signal, sys, threading\nfrom gateway.signals import StopSignals\n"
    return subprocess.Popen(
        [sys.executable, "-c", code + textwrap.dedent(body)],
        cwd=ROOT,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )


def _finish(proc: subprocess.Popen[str], timeout_s: float) -> tuple[int | None, str]:
    """The child's exit code (None: it hung and was killed) and its output."""
    try:
        out, err = proc.communicate(timeout=timeout_s)
        return proc.returncode, out + err
    except subprocess.TimeoutExpired:
        proc.kill()
        out, err = proc.communicate()
        return None, out + err


def test_a_signal_arriving_while_the_event_lock_is_held_still_stops_the_process():
    # The hang, made certain: the main thread holds the event's condition lock (as
    # Event.wait does whenever it wakes) when the signal's handler runs. A handler that
    # called Event.set() would block on that lock for ever.
    proc = _child("""
        stop = threading.Event()
        with StopSignals(stop) as signals:
            with stop._cond:  # the lock Event.set() takes
                signal.raise_signal(signal.SIGTERM)  # its Python handler runs here
                print("handler returned", flush=True)
            assert stop.wait(5.0), "the watcher did not set the event"
            assert signals.signum == signal.SIGTERM, signals.signum
        print("stopped", flush=True)
    """)
    code, out = _finish(proc, 20.0)
    assert code == 0 and "handler returned" in out and "stopped" in out, (code, out)


def test_a_burst_of_signals_stops_every_process():
    # 1 in 20 processes hung this way with a handler calling Event.set().
    body = """
        stop = threading.Event()
        with StopSignals(stop):
            print("ready", flush=True)
            while not stop.wait(0.0002):
                pass
        print("stopped", flush=True)
    """
    procs = [_child(body) for _ in range(8)]
    for proc in procs:
        assert proc.stdout is not None
        assert proc.stdout.readline().strip() == "ready"
        for _ in range(300):
            os.kill(proc.pid, signal.SIGTERM)
    results = [_finish(proc, 20.0) for proc in procs]
    # Stopped, or (after the handlers were put back) ended by a later signal of the burst.
    hung = [out for code, out in results if code not in (0, -signal.SIGTERM)]
    assert not hung, f"{len(hung)} of {len(procs)} did not stop: {hung[0]}"
    assert all("stopped" in out for code, out in results if code == 0)


def test_sigint_stops_too_and_the_handlers_are_put_back():
    proc = _child("""
        before = signal.getsignal(signal.SIGINT), signal.getsignal(signal.SIGTERM)
        stop = threading.Event()
        with StopSignals(stop) as signals:
            os.kill(os.getpid(), signal.SIGINT)  # no KeyboardInterrupt: a stop request
            assert stop.wait(5.0)
            assert signals.signum == signal.SIGINT
        after = signal.getsignal(signal.SIGINT), signal.getsignal(signal.SIGTERM)
        assert after == before, (before, after)
        assert signal.set_wakeup_fd(-1) == -1, "the wakeup descriptor was left set"
        assert [t.name for t in threading.enumerate()] == ["MainThread"]
        print("ok", flush=True)
    """)
    code, out = _finish(proc, 20.0)
    assert code == 0 and "ok" in out, (code, out)


def test_outside_the_main_thread_it_installs_nothing():
    handler = signal.getsignal(signal.SIGTERM)
    seen: list[object] = []

    def run() -> None:
        with StopSignals(threading.Event()):
            seen.append(signal.getsignal(signal.SIGTERM))

    worker = threading.Thread(target=run)
    worker.start()
    worker.join()
    assert seen == [handler]


def test_no_process_installs_a_signal_handler_of_its_own():
    # Every process stops through StopSignals: a handler of its own could take a lock.
    offenders = []
    for package in ("gateway", "drivers", "control", "sim_bridge"):
        for path in sorted((ROOT / package).rglob("*.py")):
            if path == ROOT / "gateway" / "signals.py":
                continue
            for number, line in enumerate(path.read_text().splitlines(), 1):
                if "signal.signal(" in line:
                    offenders.append(f"{path.relative_to(ROOT)}:{number}: {line.strip()}")
    assert not offenders, "use gateway.signals.StopSignals instead:\n" + "\n".join(offenders)
