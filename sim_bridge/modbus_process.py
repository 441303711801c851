"""The virtual I/O module in a process of its own.

In the simulator's process the Modbus server thread shares one interpreter with the physics
loop. In lock-step that loop runs flat out, and on a loaded 2-core machine the server then
answered a poll 0.1-0.3 s late, often enough that the cell faulted on stale I/O during
commissioning (`make test`, 2026-11-26). A real I/O module answers on its own hardware: here it
answers from its own process (``python -m sim_bridge.modbus_process``), behind
:class:`VirtualIoProcess`, which has the simulator-side API of
:class:`~sim_bridge.modbus_server.VirtualIoServer`.

It runs at the SCHED_FIFO priority it is given (``--fifo-priority``; the harness gives the
virtual controller's, in lock-step runs too): it answers requests and sleeps otherwise, as a
module's own processor does, and the test machine's load must not make it late. At normal
priority beside one busy process on a 2-core machine, lock-step commissioning at 3x saw its
replies past the driver's 0.1 s four times in 7 s, and the cell faulted on stale I/O before
the plan began (`tests/stack/test_identify_stack.py` under `make test-loaded`, 2026-12-04).

The two processes share eight doubles in an anonymous memory file (inputs the simulator
writes, set-points the module's clients write); each is one aligned double, so a reader sees
the old or the new value of each. The child reports ``ok PORT`` or ``error MESSAGE`` on its
stdout and serves until its stdin closes: when the simulator stops it, and when the simulator
dies however it dies (no server is left behind, and no multiprocessing resource tracker).
"""

from __future__ import annotations

import argparse
import logging
import mmap
import os
import select
import subprocess
import sys
from typing import IO, Any

from gateway.realtime import apply_scheduling as place
from sim_bridge.modbus_server import VirtualIoServer, stored_bar

log = logging.getLogger(__name__)

#: shared array layout
_P2, _P3, _ENABLING, _ESTOP_OK, _MARK, _SP2, _SP3, _WRITES = range(8)
_N = 8
_SIZE = _N * 8  # doubles


class _Shared:
    """The shared doubles, indexed, through a memoryview: each element is read and written as
    one 8-byte copy, so the other process never sees half a value (``struct.pack_into`` zeroes
    the bytes before it packs them: a reader caught in between read a pressure of 0 bar), and
    :meth:`release` lets go of the mapping however many references the server still holds (a
    ctypes view kept it from closing)."""

    __slots__ = ("view",)

    def __init__(self, mm: mmap.mmap) -> None:
        self.view = memoryview(mm).cast("d")

    def __getitem__(self, k: int) -> float:
        return self.view[k]

    def __setitem__(self, k: int, value: float) -> None:
        self.view[k] = value

    def release(self) -> None:
        self.view.release()


def _view(fd: int) -> tuple[mmap.mmap, _Shared]:
    mm = mmap.mmap(fd, _SIZE)
    return mm, _Shared(mm)


class _SharedIoServer(VirtualIoServer):
    """A VirtualIoServer whose inputs and set-points live in the shared array."""

    def __init__(self, shared: _Shared, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self._shared = shared

    def _current_inputs(self) -> tuple[float, float, bool, bool, bool]:
        s = self._shared
        return s[_P2], s[_P3], s[_ENABLING] > 0.5, s[_ESTOP_OK] > 0.5, s[_MARK] > 0.5

    def _store_setpoints(self, p2_bar: float, p3_bar: float) -> None:
        s = self._shared
        s[_SP2], s[_SP3] = p2_bar, p3_bar
        s[_WRITES] += 1


class VirtualIoProcess:
    """:class:`~sim_bridge.modbus_server.VirtualIoServer` served from a child process (module
    docstring); same parameters and simulator-side methods."""

    START_TIMEOUT_S = 10.0
    STOP_TIMEOUT_S = 5.0

    def __init__(
        self,
        host: str = "127.0.0.1",
        port: int = 5020,
        device_id: int = 1,
        *,
        p2_set_bar: float = 0.0,
        p3_set_bar: float = 0.0,
        fifo_priority: int = 0,
    ) -> None:
        """``fifo_priority``: the SCHED_FIFO priority the module's process runs at (0: normal
        scheduling), as :func:`main` takes it."""
        self.host, self.port, self.device_id = host, port, device_id
        self.fifo_priority = fifo_priority
        self._fd = os.memfd_create("virtual-io", 0)
        os.ftruncate(self._fd, _SIZE)
        self._mm, self._shared = _view(self._fd)
        self._shared[_SP2], self._shared[_SP3] = stored_bar(p2_set_bar), stored_bar(p3_set_bar)
        self._proc: subprocess.Popen[str] | None = None
        self.exit_code: int | None = None  #: the child's, once stopped

    def set_inputs(
        self, p2_bar: float, p3_bar: float, enabling: bool, estop_ok: bool, mark: bool = False
    ) -> None:
        """Publish new input values [bar] to the module."""
        s = self._shared
        s[_P2], s[_P3] = float(p2_bar), float(p3_bar)
        s[_ENABLING], s[_ESTOP_OK], s[_MARK] = float(enabling), float(estop_ok), float(mark)

    def setpoints(self) -> tuple[float, float]:
        """``(p2_set_bar, p3_set_bar)`` as last written by a client (or the initial values)."""
        return self._shared[_SP2], self._shared[_SP3]

    @property
    def setpoint_writes(self) -> int:
        """Number of write requests that changed the set-points."""
        return int(self._shared[_WRITES])

    def start(self) -> None:
        """Start the child; returns once it listens (raises OSError if it cannot)."""
        if self._proc is not None:
            raise RuntimeError("VirtualIoProcess already started")
        args = [sys.executable, "-m", "sim_bridge.modbus_process", "--fd", str(self._fd),
                "--host", self.host, "--port", str(self.port),
                "--device-id", str(self.device_id),
                "--fifo-priority", str(self.fifo_priority)]  # fmt: skip
        self._proc = subprocess.Popen(
            args, stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True,
            pass_fds=(self._fd,), start_new_session=True,
        )  # fmt: skip
        assert self._proc.stdout is not None
        line = _readline(self._proc.stdout, self.START_TIMEOUT_S)
        kind, _, value = line.strip().partition(" ")
        if kind != "ok":
            self.stop()
            why = value or f"its process exited without a word ({line!r})"
            raise OSError(f"virtual I/O module cannot listen on {self.host}:{self.port}: {why}")
        self.port = int(value)

    def stop(self) -> None:
        """Stop the child and wait for it (idempotent); kill it if it does not stop."""
        proc = self._proc
        if proc is None:
            return
        for pipe in (proc.stdin, proc.stdout):
            if pipe is not None:
                pipe.close()  # its stdin at EOF: it stops
        try:
            proc.wait(self.STOP_TIMEOUT_S)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
        self._proc = None
        self.exit_code = proc.returncode
        if proc.returncode != 0:
            log.warning("virtual I/O module exited with %s", proc.returncode)

    def close(self) -> None:
        """Stop the child and release the shared memory."""
        self.stop()
        if self._fd >= 0:
            self._shared.release()
            self._mm.close()
            os.close(self._fd)
            self._fd = -1

    def __enter__(self) -> VirtualIoProcess:
        self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def _readline(stream: IO[str], timeout_s: float) -> str:
    ready, _, _ = select.select([stream], [], [], timeout_s)
    return stream.readline() if ready else "error did not start within the timeout"


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description="virtual I/O module (started by VirtualIoProcess)")
    p.add_argument("--fd", type=int, required=True)
    p.add_argument("--host", required=True)
    p.add_argument("--port", type=int, required=True)
    p.add_argument("--device-id", type=int, default=1)
    p.add_argument("--fifo-priority", type=int, default=0, choices=range(100), metavar="0..99",
                   help="SCHED_FIFO priority of this process (0: normal scheduling)")  # fmt: skip
    args = p.parse_args(argv)
    if args.fifo_priority:
        # Before the server's thread exists, which inherits it. A refusal is logged (to the
        # simulator's stderr) and the module answers on at normal priority.
        place((), args.fifo_priority, False, "virtual I/O module")
    mm, shared = _view(args.fd)
    server = _SharedIoServer(
        shared, args.host, args.port, args.device_id,
        p2_set_bar=shared[_SP2], p3_set_bar=shared[_SP3],
    )  # fmt: skip
    try:
        server.start()
    except (OSError, TimeoutError, RuntimeError) as exc:
        print(f"error {exc}", flush=True)
        return 1
    try:
        print(f"ok {server.port}", flush=True)
        sys.stdin.read()  # until the simulator closes it, or dies
    except (OSError, KeyboardInterrupt):
        pass
    finally:
        server.stop()
        shared.release()
        mm.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())
