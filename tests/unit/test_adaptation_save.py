"""The control process keeps the adapted mass (control/model_adaptation.py) off its slow loop:
the write (an fsync, which waits for the disk) runs in its own thread; the slow loop learns its
outcome later, and closing the process waits for it (issue 45)."""

from __future__ import annotations

import dataclasses
import threading
import time

from example_cell import example_cell

from control.cell_config import load_control_config
from control.process import ControlProcess


def _process(tmp_path) -> ControlProcess:
    cfg, bus = load_control_config(example_cell(tmp_path))
    kept = tmp_path / "adapted_payload.json"
    return ControlProcess(dataclasses.replace(cfg, model_adaptation_file=kept), bus)


def test_a_slow_write_holds_neither_the_slow_loop_nor_loses_its_outcome(tmp_path):
    proc = _process(tmp_path)
    release = threading.Event()

    def slow_disk() -> None:
        release.wait(5.0)
        raise OSError(28, "No space left on device")

    proc._saving = proc._saver.submit(slow_disk)
    t0 = time.monotonic()
    proc._check_saved()  # the write has not ended: the slow loop goes on
    assert time.monotonic() - t0 < 0.1
    assert proc.adaptation_problem is None
    release.set()
    proc._saver.shutdown(wait=True)
    proc._check_saved()
    assert proc.adaptation_problem is not None
    assert "adapted payload not kept" in proc.adaptation_problem
    assert "No space left on device" in proc.adaptation_problem


def test_closing_the_process_waits_for_the_write_under_way(tmp_path):
    proc = _process(tmp_path)
    written = threading.Event()

    def write() -> None:
        time.sleep(0.3)
        written.set()

    proc._saving = proc._saver.submit(write)
    proc.close()
    assert written.is_set()
    assert proc.adaptation_problem is None
