"""Issue 10's Modbus fuzz: the Modbus driver polls the virtual I/O module through a proxy that
mangles its replies at random (mutation fuzzing), in-process, over real TCP.

Each request goes to the module; its reply comes back as it is, or cut short, padded, doubled,
with another transaction id, unit id, length, function code or byte count, as random bytes,
with random values, or not at all, or the connection is closed instead. The driver must stay
up, count and report every reply it cannot use, publish nothing from a mangled frame, and be
polling the module's true values again as soon as the replies are sane.

Random *values* in a well-formed reply are what Modbus TCP cannot tell from the module's own
(no checksum of its own above TCP's): the register map's plausibility checks refuse what is
outside each point's range, and what is inside is published. The test counts those, and says
how many showed the enabling device held: the enabling device's integrity is the safety
circuit's, wired to the controller, not this bus's (docs/safety.md).
"""

from __future__ import annotations

import contextlib
import math
import os
import socket
import struct
import threading
import time
import tomllib
from collections import Counter
from collections.abc import Iterator

import numpy as np
import pytest

from drivers.modbus.config import ModbusDriverConfig
from drivers.modbus.driver import ModbusDriver
from sim_bridge.modbus_server import VirtualIoServer, sim_modbus_section_toml

#: replies thrown at the driver: 5,000 in `make test` (about 15 s), 100,000 in `make faults`
#: (issue 10: at least 100,000 random CAN frames and Modbus replies), which sets this variable
REPLIES = int(os.environ.get("LEADTHROUGH_FUZZ_REPLIES", "5000"))
#: the driver's reply timeout in this test [s]: what a cut reply or silence costs (most of the
#: test's time). A sane reply passes this process's proxy thread and the module's; on a machine
#: running the stack tier beside this one, at 5 ms, they were late for about half the polls
#: whose replies were all sane (88 published the true values, 182 on an idle machine; session
#: 91). A late reply fails its poll like a lost one, and is counted as late.
TIMEOUT_S = 0.01
#: polls answered in time that must give the true values once the replies are sane, and the
#: most polls allowed for them (a poll late beyond TIMEOUT_S is retried, not judged)
SANE_POLLS = 8
MAX_SANE_POLLS = 200
#: the module's true inputs
TRUTH = (2.0, 3.5, False, True)

#: kind → relative weight; "valid" passes the reply through
KINDS = {
    "valid": 30,
    "values": 10,  # the payload's bytes random, the frame well formed
    "garbage": 6,  # random bytes of random length
    "cut": 3,  # a prefix of the reply (a timeout)
    "tid": 5,  # another transaction id
    "unit": 5,  # another unit id
    "protocol": 3,  # protocol id not 0
    "length": 6,  # the MBAP length field random
    "function": 8,  # the function code random (an exception response now and then)
    "byte_count": 8,  # the byte count random, the frame's length to match
    "padded": 5,  # random bytes after the reply
    "doubled": 4,  # the reply twice
    "close": 4,  # the connection closed instead of a reply
    "silent": 3,  # no reply (a timeout)
}
#: kinds that may leave bytes behind for the next request's reply
SPILL = {"padded", "doubled", "length", "byte_count", "garbage", "function"}


def _read_exact(sock: socket.socket, n: int) -> bytes:
    data = b""
    while len(data) < n:
        chunk = sock.recv(n - len(data))
        if not chunk:
            raise ConnectionError("closed")
        data += chunk
    return data


class MutatingProxy:
    """Forwards each Modbus TCP request to ``upstream_port`` and mangles the reply; records the
    kind of every reply it sent (``kinds``, since the last :meth:`take`)."""

    def __init__(self, upstream_port: int, rng: np.random.Generator) -> None:
        self._upstream_port = upstream_port
        self._rng = rng
        names = list(KINDS)
        weights = np.array([KINDS[k] for k in names], dtype=float)
        self._names, self._p = names, weights / weights.sum()
        self.only_valid = False
        self.replies = 0
        self.counts: Counter[str] = Counter()
        self._kinds: list[str] = []
        self._lock = threading.Lock()
        self._listener = socket.create_server(("127.0.0.1", 0))
        self._listener.settimeout(0.05)
        self.port = self._listener.getsockname()[1]
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="modbus-fuzz-proxy", daemon=True)
        self._thread.start()

    def take(self) -> list[str]:
        with self._lock:
            kinds, self._kinds = self._kinds, []
        return kinds

    def close(self) -> None:
        self._stop.set()
        self._thread.join(5.0)
        self._listener.close()

    def _run(self) -> None:
        while not self._stop.is_set():
            try:
                conn, _ = self._listener.accept()
            except TimeoutError:
                continue
            with conn, socket.create_connection(("127.0.0.1", self._upstream_port)) as up:
                conn.settimeout(0.05)
                with contextlib.suppress(ConnectionError, OSError):  # the driver closed it
                    self._serve(conn, up)

    def _serve(self, conn: socket.socket, up: socket.socket) -> None:
        while not self._stop.is_set():
            try:
                header = _read_exact(conn, 7)
            except TimeoutError:
                continue
            (length,) = struct.unpack(">H", header[4:6])
            request = header + _read_exact(conn, length - 1)
            up.sendall(request)
            head = _read_exact(up, 7)
            reply = head + _read_exact(up, struct.unpack(">H", head[4:6])[0] - 1)
            kind = "valid" if self.only_valid else str(self._rng.choice(self._names, p=self._p))
            with self._lock:
                self._kinds.append(kind)
                self.counts[kind] += 1
                self.replies += 1
            if kind == "close":
                return
            out = self._mangle(kind, reply)
            if out:
                conn.sendall(out)

    def _mangle(self, kind: str, reply: bytes) -> bytes:
        rng = self._rng
        b = bytearray(reply)
        if kind == "valid":
            return reply
        if kind == "values":
            return bytes(b[:9]) + rng.bytes(len(b) - 9) if len(b) > 9 else reply
        if kind == "garbage":
            return rng.bytes(int(rng.integers(1, 300)))
        if kind == "cut":
            return bytes(b[: int(rng.integers(1, len(b)))])
        if kind == "tid":
            b[0:2] = struct.pack(
                ">H", (struct.unpack(">H", b[0:2])[0] + 1 + int(rng.integers(0, 0xFFFE))) & 0xFFFF
            )
        elif kind == "unit":
            b[6] = (b[6] + 1 + int(rng.integers(0, 254))) & 0xFF
        elif kind == "protocol":
            b[2:4] = struct.pack(">H", int(rng.integers(1, 0x10000)))
        elif kind == "length":
            b[4:6] = struct.pack(">H", int(rng.integers(0, 0x10000)))
        elif kind == "function":
            b[7] = int(rng.integers(0, 256))
            if b[7] & 0x80:
                return bytes(b[:8]) + bytes([int(rng.integers(0, 256))])
        elif kind == "byte_count" and len(b) > 8:
            count = (b[8] + 1 + int(rng.integers(0, 255))) & 0xFF  # never the right one
            body = rng.bytes(count)
            b = b[:8] + bytes([count]) + body
            b[4:6] = struct.pack(">H", len(b) - 6)
        elif kind == "padded":
            return reply + rng.bytes(int(rng.integers(1, 20)))
        elif kind == "doubled":
            return reply + reply
        elif kind == "silent":
            return b""
        return bytes(b)


@pytest.fixture
def module() -> Iterator[VirtualIoServer]:
    srv = VirtualIoServer("127.0.0.1", 0)
    srv.start()
    srv.set_inputs(*TRUTH)
    try:
        yield srv
    finally:
        srv.stop()


@pytest.fixture
def proxy(module: VirtualIoServer) -> Iterator[MutatingProxy]:
    p = MutatingProxy(module.port, np.random.default_rng(10))
    try:
        yield p
    finally:
        p.close()


class _Clock:
    """Real time plus a skip: each step jumps past any reconnect back-off (the test calls
    :meth:`ModbusDriver.step` itself, as fast as the replies come)."""

    def __init__(self) -> None:
        self.skip_s = 0.0

    def __call__(self) -> float:
        return time.monotonic() + self.skip_s


def _plausible(state) -> bool:
    pressures = (state.p2_bar, state.p3_bar, state.p2_set_bar, state.p3_set_bar)
    return all(math.isfinite(p) and -1.0 <= p <= 65.6 for p in pressures)


def _true(state) -> bool:
    return (
        state.p2_bar == pytest.approx(TRUTH[0], abs=1e-3)
        and state.p3_bar == pytest.approx(TRUTH[1], abs=1e-3)
        and state.enabling is TRUTH[2]
        and state.estop_ok is TRUTH[3]
    )


# its count of late polls is a wall-clock deadline of TIMEOUT_S: in the niced tier beside the
# stack tier 85 of 114 sane polls came late at 10 ms (2026-12-07, make test), against about half
# in session 91; a driver that lost step is late on all of them. So it runs where deadlines do,
# at normal priority one test at a time (tests/run_suite.py, ``deadline``)
@pytest.mark.deadline
def test_mangled_replies_never_publish_a_mangled_frame(proxy, module):
    text = sim_modbus_section_toml(port=proxy.port).replace(
        "timeout_s = 0.1", f"timeout_s = {TIMEOUT_S}"
    )
    config = ModbusDriverConfig.from_cell_config(tomllib.loads(text))
    clock = _Clock()
    driver = ModbusDriver(config, None, None, clock=clock)  # no bus: step() returns the state
    published = {"true": 0, "values": 0, "enabling_forged": 0}
    steps = failed = 0
    clean = late = 0  # polls whose replies were all sane, and those of them answered late
    spilled = False
    t0 = time.monotonic()
    try:
        while proxy.replies < REPLIES:
            before = driver.errors
            state = driver.step()  # raises nothing: a raise fails the test
            kinds = proxy.take()
            steps += 1
            clock.skip_s += ModbusDriver.RECONNECT_MAX_S
            sane = bool(kinds) and set(kinds) == {"valid"} and not spilled
            clean += sane
            if state is None:
                failed += 1
                assert driver.errors > before or not kinds, "a poll failed without an error"
                # sane replies fail a poll only by coming later than TIMEOUT_S
                assert not sane or "no reply within" in driver.last_error, driver.last_error
                late += sane
            elif _true(state):
                published["true"] += 1  # (a reply with junk behind it is still the reply)
            else:
                # not the module's values: only random values in a well-formed reply may be
                # published, and only plausible ones
                assert set(kinds) != {"valid"} or spilled, f"sane replies, wrong values {state}"
                assert _plausible(state), f"implausible values published: {state} ({kinds})"
                assert "values" in kinds or spilled, f"a mangled frame was published ({kinds})"
                published["values"] += 1
                published["enabling_forged"] += state.enabling
            spilled = bool(SPILL & set(kinds))
        elapsed = time.monotonic() - t0
        # sane replies again: the true values at once. The first two polls may still meet what
        # a mangled reply left behind. After them a poll may fail only by a reply later than
        # TIMEOUT_S (a thread of this process or the module not scheduled in time on a loaded
        # machine; the driver closes the link so the late reply is never read); every poll
        # answered in time must give the true values, SANE_POLLS of them within MAX_SANE_POLLS.
        proxy.only_valid = True
        for _ in range(2):
            driver.step()
            clock.skip_s += ModbusDriver.RECONNECT_MAX_S
        answered = late_after = 0
        for _ in range(MAX_SANE_POLLS):
            state = driver.step()
            clock.skip_s += ModbusDriver.RECONNECT_MAX_S
            if state is None:
                assert "no reply within" in driver.last_error, driver.last_error
                late_after += 1
                continue
            assert _true(state), f"sane replies, wrong values {state}"
            answered += 1
            if answered == SANE_POLLS:
                break
        assert answered == SANE_POLLS, f"{late_after} of {MAX_SANE_POLLS} sane polls late"
        assert driver.link_ok
    finally:
        driver.close()
    print(
        f"\n{proxy.replies} replies in {elapsed:.1f} s over {steps} polls: "
        f"{failed} polls failed (errors {driver.errors}), published {published}; "
        f"{clean} polls with sane replies ({late} late), {late_after} late after; "
        f"kinds {dict(proxy.counts)}"
    )
    assert failed > steps // 3
    # the polls whose replies were all sane (36 with this proxy's seed) publish the true values
    # (asserted one by one above) unless late; a driver that lost step with the replies would
    # be late on all of them, a loaded machine was on about half at 5 ms (TIMEOUT_S)
    assert clean >= 20 and late < clean // 2, (clean, late)
    assert published["true"] >= clean - late
