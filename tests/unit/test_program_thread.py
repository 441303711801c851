"""The taught program written off the gateway's tick (gateway/program_thread.py): the tick's
calls return while the disk is slow, a mark is answered once it is on disk, a disk that refuses
or stalls ends teaching with a fault, and the session's thread ends with the session.

The slow disk is ``os.fsync`` made slow in gateway/program.py: under a competing writer a
small file's fsync took up to 0.5-1.6 s on these machines (the module's docs)."""

from __future__ import annotations

import os
import threading
import time
from pathlib import Path

import numpy as np
import pytest
from recording_session import RecordingSession

from gateway.bus import BusConfig
from gateway.gateway_config import GatewayConfig
from gateway.messages import ControllerState, JointState, Lifecycle, decode_json, encode_json
from gateway.program import ProgramError, program_path, read_program
from gateway.program_thread import STALL_S, ProgramThread
from gateway.supervisor import Gateway

#: the slow disk's fsync [s]
SLOW_FSYNC_S = 0.3
#: a tick's call into the program may take this long [s]: a queue put and a copy of six
#: numbers, far below the slow fsync even on a machine 3x slower than the fastest
TICK_CALL_S = 0.05
#: a whole tick of the gateway here (the program followed, the requests answered, the
#: lifecycle published) [s]. The fault this guards against, a tick that waits for the disk,
#: lasts one slow fsync at least; half of one leaves this test process's own pauses outside
#: the claim (a garbage collection of a whole suite's heap, a wake-up on a busy machine: one
#: tick took 133 ms in a full `make test`, 2026-12-04, where alone it keeps under 50 ms).
TICK_S = SLOW_FSYNC_S / 2


def _q(k: int) -> np.ndarray:
    return np.linspace(0.0, 0.5, 6) + 1e-3 * k


@pytest.fixture
def slow_disk(monkeypatch):
    real = os.fsync

    def fsync(fd: int) -> None:
        time.sleep(SLOW_FSYNC_S)
        real(fd)

    monkeypatch.setattr("gateway.program.os.fsync", fsync)


def test_the_ticks_calls_return_while_the_disk_is_slow_and_everything_reaches_the_file(
    tmp_path, slow_disk
):
    prog = ProgramThread("cell.toml")
    path = program_path(tmp_path, "slow")
    prog.prepare(path)
    slowest = 0.0
    for k in range(40):  # 0.4 s of 100 Hz ticks: opens the file, a segment, 40 samples
        t0 = time.monotonic()
        prog.follow(True, True, "enabling device held", 0.01 * k, 100 + k, _q(k))
        slowest = max(slowest, time.monotonic() - t0)
    marked = prog.mark(0.4, 140, _q(40), "corner", "cli")
    t0 = time.monotonic()
    prog.follow(False, False, "stop requested by operator", 0.41, 141, _q(41))
    slowest = max(slowest, time.monotonic() - t0)
    assert slowest < TICK_CALL_S, f"a tick's call took {slowest * 1e3:.0f} ms"
    mark, where = marked.result(timeout=10 * SLOW_FSYNC_S + 5.0)
    assert (mark.index, mark.label, where) == (1, "corner", path)
    prog.close(None, "gateway stopped")
    back = read_program(path)
    assert back.t_s.size == 40 and [m.label for m in back.marks] == ["corner"]
    assert prog.status()["last_closed"] == str(path) and not prog.status()["open"]


def test_a_mark_is_done_only_after_a_sync_that_had_it(tmp_path, monkeypatch):
    real, synced_marks = os.fsync, []

    def fsync(fd: int) -> None:
        real(fd)
        synced_marks.append(path.read_text().count('"type":"mark"'))

    monkeypatch.setattr("gateway.program.os.fsync", fsync)
    prog = ProgramThread()
    path = program_path(tmp_path, "m")
    prog.prepare(path)
    prog.follow(True, True, "held", 0.0, 1, _q(0))
    seen: list[int] = []
    prog.mark(0.0, 1, _q(0), "a", "cli").add_done_callback(lambda _f: seen.append(synced_marks[-1]))
    prog.close(0.1, "gateway stopped")
    assert seen == [1]


def test_a_mark_without_a_program_is_refused_and_is_no_failure(tmp_path):
    prog = ProgramThread()
    with pytest.raises(ProgramError, match="no program"):
        prog.mark(0.0, 1, _q(0), "", "cli").result(timeout=5.0)
    assert prog.failure() is None
    prog.close(None, "gateway stopped")


def test_a_disk_that_refuses_is_one_failure_and_the_program_is_closed(tmp_path, monkeypatch):
    prog = ProgramThread()
    path = program_path(tmp_path, "full")
    prog.prepare(path)
    prog.follow(True, True, "held", 0.0, 1, _q(0))
    prog.mark(0.0, 1, _q(0), "first", "cli").result(timeout=5.0)

    def full(_fd: int) -> None:
        raise OSError(28, "No space left on device")

    monkeypatch.setattr("gateway.program.os.fsync", full)
    with pytest.raises(ProgramError, match="No space left"):
        prog.mark(0.1, 2, _q(1), "second", "cli").result(timeout=5.0)
    failure = prog.failure()
    assert failure is not None and "No space left" in str(failure)
    assert prog.failure() is None  # reported once
    assert not prog.status()["open"]
    monkeypatch.undo()
    prog.follow(False, False, "fault", 0.2, 3, _q(2))
    prog.close(None, "gateway stopped")
    assert [m.label for m in read_program(path).marks][:1] == ["first"]


def test_a_write_the_disk_has_not_finished_shows_how_long_it_waits(tmp_path, monkeypatch):
    release = threading.Event()
    real = os.fsync

    def stuck(fd: int) -> None:
        release.wait(10.0)
        real(fd)

    prog = ProgramThread()
    prog.prepare(program_path(tmp_path, "stuck"))
    monkeypatch.setattr("gateway.program.os.fsync", stuck)
    prog.follow(True, True, "held", 0.0, 1, _q(0))  # opens the file: its header is synced
    deadline = time.monotonic() + 5.0
    while prog.stalled_s(time.monotonic()) < 0.2 and time.monotonic() < deadline:
        time.sleep(0.01)
    assert prog.stalled_s(time.monotonic()) >= 0.2
    release.set()
    prog.follow(False, False, "stop", 0.1, 2, _q(1))
    prog.close(None, "gateway stopped")
    assert prog.stalled_s(time.monotonic()) == 0.0


class _Payload:
    def __init__(self, data: bytes) -> None:
        self._data = data

    def to_bytes(self) -> bytes:
        return self._data


class _Query:
    """An operator request as the gateway's queryable hands it over."""

    def __init__(self, request: dict) -> None:
        self.payload = _Payload(encode_json(request))
        self.key_expr = "leadthrough/request"
        self.replies: list[dict] = []
        self.dropped = False

    def reply(self, _key: str, data: bytes) -> None:
        self.replies.append(decode_json(data, "reply"))

    def drop(self) -> None:
        self.dropped = True


class _Requests:
    def __init__(self, queries: list[_Query]) -> None:
        self._queries = list(queries)

    def try_recv(self) -> _Query | None:
        return self._queries.pop(0) if self._queries else None


def _state() -> JointState:
    z = np.zeros(6)
    return JointState(10, 1.0, ControllerState.EXTERNAL, 0, _q(0), z, z, _q(0), z, 0.008)


def test_the_gateways_tick_goes_on_while_a_mark_waits_for_a_slow_disk(tmp_path, slow_disk):
    gw = Gateway(Path("cell.toml"), BusConfig(), GatewayConfig())
    gw.session = RecordingSession()
    gw.teach.prepare(program_path(tmp_path, "taught"))
    gw.machine._go(Lifecycle.TEACHING, "enabling device held")
    gw.watch._state = _state()  # the newest joint state, as folded from the CAN driver
    query = _Query({"command": "mark", "label": "corner"})
    gw._requests = _Requests([query])
    slowest, ticks = 0.0, 0
    deadline = time.monotonic() + 10 * SLOW_FSYNC_S + 5.0
    while not query.replies and time.monotonic() < deadline:
        t0 = time.monotonic()
        gw._follow_program()
        gw._serve_requests()
        gw._publish_lifecycle(t0)
        slowest, ticks = max(slowest, time.monotonic() - t0), ticks + 1
        time.sleep(0.01)
    assert query.replies and query.dropped
    reply = query.replies[0]
    assert reply["ok"] and reply["message"].startswith("mark 1 recorded in"), reply
    assert reply["program"]["marks"] == 1
    assert ticks > 5, "the tick stood still while the mark was written"
    assert slowest < TICK_S, f"a tick took {slowest * 1e3:.0f} ms"
    gw.machine._go(Lifecycle.STOPPED, "stop requested by operator")
    gw._follow_program()
    gw.teach.close(None, "gateway stopped")
    assert STALL_S > 10 * SLOW_FSYNC_S  # the slow disk here is not a stalled one
