"""The virtual I/O module served from its own process (sim_bridge/modbus_process.py): the same
registers as in-process, set-points back to the simulator, and no server left behind."""

from __future__ import annotations

import os
import socket
import subprocess
import sys
import time

import pytest

from drivers.modbus.client import ModbusLink
from sim_bridge.modbus_process import _P2, _SIZE, VirtualIoProcess, _view
from sim_bridge.modbus_server import VirtualIoServer


def _listening(port: int) -> bool:
    try:
        with socket.create_connection(("127.0.0.1", port), timeout=0.2):
            return True
    except OSError:
        return False


def test_the_module_answers_from_its_process_with_the_simulators_values():
    with VirtualIoProcess("127.0.0.1", 0, p2_set_bar=1.5, p3_set_bar=2.0) as io:
        assert io.port != 0 and io.setpoints() == (1.5, 2.0)
        io.set_inputs(1.5, 3.25, True, False, True)
        with ModbusLink("127.0.0.1", io.port, timeout_s=1.0) as link:
            assert link.read_input_registers(0, 3) == [0x3FC0, 0x0000, 3250]
            assert link.read_discrete_inputs(0, 3) == [True, False, True]
            link.write_registers(0, [4500, 0, 0xFFFF & -2500, 0xFFFF])  # 4.5 and -2.5 bar
            assert link.read_holding_registers(0, 4) == [4500, 0, 0xFFFF & -2500, 0xFFFF]
        assert io.setpoints() == (4.5, -2.5)
        assert io.setpoint_writes == 1
        port = io.port
    assert not _listening(port)
    assert io._proc is None
    assert io.exit_code == 0, "the module stopped cleanly (its shared memory released)"


def _fifo_permitted() -> bool:
    """This process may put a child at SCHED_FIFO (root, or an rtprio limit)."""
    code = "import os; os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(1))"
    return subprocess.run([sys.executable, "-c", code], capture_output=True).returncode == 0


def test_the_module_answers_at_the_fifo_priority_it_is_given_on_every_thread():
    if not _fifo_permitted():
        pytest.skip("this OS refuses SCHED_FIFO to this user")
    with VirtualIoProcess("127.0.0.1", 0, fifo_priority=7) as io:
        assert io._proc is not None
        tids = [int(t) for t in os.listdir(f"/proc/{io._proc.pid}/task")]
        assert len(tids) >= 2, "the server's thread exists once the module listens"
        for tid in tids:
            assert os.sched_getscheduler(tid) == os.SCHED_FIFO, tid
            assert os.sched_getparam(tid).sched_priority == 7, tid
        with ModbusLink("127.0.0.1", io.port, timeout_s=1.0) as link:
            assert link.read_discrete_inputs(0, 3) == [False, False, False]
    with VirtualIoProcess("127.0.0.1", 0) as io:  # default: normal scheduling
        assert io._proc is not None
        assert os.sched_getscheduler(io._proc.pid) == os.SCHED_OTHER


def test_a_port_in_use_is_an_error_naming_it():
    with VirtualIoServer("127.0.0.1", 0) as taken:
        io = VirtualIoProcess("127.0.0.1", taken.port)
        with pytest.raises(OSError, match=f"cannot listen on 127.0.0.1:{taken.port}"):
            io.start()
        assert io._proc is None
        io.close()


def test_the_module_stops_when_its_simulator_is_killed():
    code = (
        "import os, sys\n"
        "from sim_bridge.modbus_process import VirtualIoProcess\n"
        "io = VirtualIoProcess('127.0.0.1', 0)\n"
        "io.start()\n"
        "print(io.port, flush=True)\n"
        "os._exit(0)\n"  # no stop(): as SIGKILL would leave it
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=30)
    port = int(out.stdout.strip())
    deadline = time.monotonic() + 5.0
    while _listening(port) and time.monotonic() < deadline:
        time.sleep(0.1)
    assert not _listening(port), "the orphaned module still serves"


def test_a_value_written_by_one_process_is_never_read_half_written_by_the_other():
    """The simulator writes the pressures every cycle while the module's server reads them:
    a reader must see the old value or the new one, never a torn or zeroed one (struct's
    pack_into zeroes the bytes before packing: a poll once read 0 bar)."""
    fd = os.memfd_create("torn-read-test", 0)
    try:
        os.ftruncate(fd, _SIZE)
        mm, shared = _view(fd)
        shared[_P2] = 6.0
        writer = subprocess.Popen(
            [sys.executable, "-c",
             "import sys, time\n"
             "from sim_bridge.modbus_process import _view, _P2\n"
             "mm, s = _view(int(sys.argv[1]))\n"
             "end = time.monotonic() + 1.0\n"
             "while time.monotonic() < end:\n"
             "    for v in (6.0, 3.5, 6.0, 3.5, 6.0, 3.5, 6.0, 3.5):\n"
             "        s[_P2] = v\n"
             "s.release(); mm.close()\n",
             str(fd)],
            pass_fds=(fd,),
        )  # fmt: skip
        try:
            seen = set()
            while writer.poll() is None:
                for _ in range(1000):
                    seen.add(shared[_P2])
        finally:
            writer.wait(10.0)
        assert writer.returncode == 0
        assert seen <= {6.0, 3.5}, f"read values nobody wrote: {seen - {6.0, 3.5}}"
        shared.release()
        mm.close()
    finally:
        os.close(fd)
