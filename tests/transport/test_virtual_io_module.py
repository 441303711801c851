"""The virtual I/O module's compiled server (sim_bridge/rt/src/io_module/): the simulator's
values on the wire and the clients' set-points back, replies that do not wait for Python, the
simulator loop's priority on every thread, and no server left behind."""

from __future__ import annotations

import os
import socket
import subprocess
import sys
import textwrap

import pytest

from drivers.modbus.client import ModbusLink
from sim_bridge.modbus_server import VirtualIoServer


def _listening(port: int) -> bool:
    try:
        with socket.create_connection(("127.0.0.1", port), timeout=0.2):
            return True
    except OSError:
        return False


def test_the_module_answers_with_the_simulators_values_and_hands_back_the_setpoints():
    with VirtualIoServer("127.0.0.1", 0, p2_set_bar=1.5, p3_set_bar=2.0) as io:
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


def test_a_pressure_the_module_cannot_encode_saturates_instead_of_failing_the_poll():
    with VirtualIoServer("127.0.0.1", 0) as io:
        io.set_inputs(float("inf"), float("inf"), False, True)
        with ModbusLink("127.0.0.1", io.port, timeout_s=1.0) as link:
            assert link.read_input_registers(0, 3) == [0x7F80, 0x0000, 0xFFFF]
            io.set_inputs(float("nan"), float("-inf"), False, True)
            assert link.read_input_registers(2, 1) == [0]


def test_a_port_in_use_is_an_error_naming_it():
    with VirtualIoServer("127.0.0.1", 0) as taken:
        io = VirtualIoServer("127.0.0.1", taken.port)
        with pytest.raises(OSError, match=f"cannot listen on 127.0.0.1:{taken.port}"):
            io.start()
        io.stop()


def test_the_module_answers_while_python_holds_the_gil():
    """The simulator's loop is Python; in lock-step it runs flat out. Here this process's only
    Python thread never lets go of the GIL for a whole second (a switch interval of 10 s) while
    another process polls the module: every reply still comes in time, because no thread of
    the server takes the GIL."""
    client = textwrap.dedent(
        """
        import sys, time
        from drivers.modbus.client import ModbusLink
        worst = 0.0
        with ModbusLink("127.0.0.1", int(sys.argv[1]), timeout_s=0.5) as link:
            print("connected", flush=True)
            sys.stdin.readline()  # the parent holds the GIL from here
            for _ in range(40):
                t = time.monotonic()
                assert link.read_input_registers(0, 3) == [0x3FC0, 0, 3250]
                worst = max(worst, time.monotonic() - t)
                time.sleep(0.01)
        print(worst, flush=True)
        """
    )
    with VirtualIoServer("127.0.0.1", 0) as io:
        io.set_inputs(1.5, 3.25, False, True)
        proc = subprocess.Popen(
            [sys.executable, "-c", client, str(io.port)],
            stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True,
        )  # fmt: skip
        assert proc.stdin is not None and proc.stdout is not None
        assert proc.stdout.readline().strip() == "connected"
        interval = sys.getswitchinterval()
        sys.setswitchinterval(10.0)
        try:
            proc.stdin.write("go\n")
            proc.stdin.flush()
            spin = 0
            while proc.poll() is None and spin < 200_000_000:  # pure Python: keeps the GIL
                spin += 1
        finally:
            sys.setswitchinterval(interval)
        out, _ = proc.communicate(timeout=30)
    assert proc.returncode == 0, out
    assert float(out.strip()) < 0.1, f"a reply took {float(out):.3f} s"


def _fifo_permitted() -> bool:
    """This process may put a child at SCHED_FIFO (root, or an rtprio limit)."""
    code = "import os; os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(1))"
    return subprocess.run([sys.executable, "-c", code], capture_output=True).returncode == 0


def test_every_thread_of_the_module_runs_at_the_priority_of_the_thread_that_started_it():
    """The simulator applies ``[scheduling]`` to its loop before it starts the module: the
    acceptor and every connection's thread inherit it."""
    if not _fifo_permitted():
        pytest.skip("this OS refuses SCHED_FIFO to this user")
    code = textwrap.dedent(
        """
        import os
        from pathlib import Path
        from drivers.modbus.client import ModbusLink
        from sim_bridge.modbus_server import VirtualIoServer
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(7))
        with VirtualIoServer("127.0.0.1", 0) as io, ModbusLink("127.0.0.1", io.port) as link:
            assert link.read_discrete_inputs(0, 3) == [False, False, False]
            for task in Path("/proc/self/task").iterdir():
                name = (task / "comm").read_text().strip()
                if name.startswith("virtual-io"):
                    tid = int(task.name)
                    print(name, os.sched_getscheduler(tid), os.sched_getparam(tid).sched_priority)
        """
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=30)
    assert out.returncode == 0, out.stderr
    rows = [line.split() for line in out.stdout.splitlines()]
    assert {name for name, _, _ in rows} == {"virtual-io", "virtual-io-conn"}
    assert all(int(policy) == os.SCHED_FIFO and int(prio) == 7 for _, policy, prio in rows), rows


def test_the_module_stops_with_its_simulator_however_it_ends():
    code = (
        "import os\n"
        "from sim_bridge.modbus_server import VirtualIoServer\n"
        "io = VirtualIoServer('127.0.0.1', 0)\n"
        "io.start()\n"
        "print(io.port, flush=True)\n"
        "os._exit(0)\n"  # no stop(): as SIGKILL would leave it
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=30)
    assert not _listening(int(out.stdout.strip())), "the module outlived its simulator"
