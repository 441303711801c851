"""Virtual I/O module: the cell's Modbus TCP endpoint, served by the simulator.

The Modbus driver cannot tell this module from the real cell: same protocol, same driver, only
the ``[modbus]`` host/port and register map differ. The encodings below are deliberately mixed
(IEEE float, scaled integer, word-swapped int32) so the driver's register-map decoding is
exercised end to end. This is the module's "manual"; protocol addresses are 0-based, as on the
wire, unit id ``device_id`` (default 1):

=================  =======  ============  =======  ==================================  ====
table              address  name          type     encoding                            unit
=================  =======  ============  =======  ==================================  ====
input registers    0–1      p2 measured   float32  big-endian words and bytes ("ABCD")  bar
input registers    2        p3 measured   uint16   saturating 0..65535; NaN → 65535    mbar
holding registers  0–1      p2 set-point  int32    low word first, bytes big ("CDAB")  mbar
holding registers  2–3      p3 set-point  int32    as p2 set-point                     mbar
discrete inputs    0        enabling      bit      1 = enabling device held
discrete inputs    1        estop_ok      bit      1 = e-stop chain closed
discrete inputs    2        mark          bit      1 = teach handle's mark button pressed
coils              0        (reserved)    bit      none; present so the table exists
=================  =======  ============  =======  ==================================  ====

Any other register address answers exception 2 (ILLEGAL DATA ADDRESS); discrete inputs
3–15 and coils 1–15 exist (pymodbus stores bits 16 to a word) and read 0. Set-points are
stored as written (no clamping: the driver owns the limits) and read back unchanged.

The encodings here are written out with :mod:`struct`, independently of
:mod:`drivers.modbus.registermap`, so a symmetric bug in the map cannot hide itself.

:func:`sim_modbus_section_toml` gives the matching ``[modbus]`` section for the cell config.

Threading: the pymodbus server runs on its own asyncio loop in a background thread.
:meth:`VirtualIoServer.set_inputs` (simulator loop, ~1 kHz) only swaps one tuple reference; the
registers are encoded from that snapshot when a request arrives, on the server thread.
"""

from __future__ import annotations

import asyncio
import contextlib
import math
import struct
import threading

from pymodbus.server import ModbusTcpServer
from pymodbus.simulator import DataType, SimData, SimDevice

#: Function codes by table (Modbus Application Protocol V1.1b3, §6).
_FC_READ_COILS, _FC_READ_DI, _FC_READ_HR, _FC_READ_IR = 1, 2, 3, 4
_FC_WRITE_HR = (6, 16, 23)

_FLOAT32_MAX = 3.4028234663852886e38
_N_HOLDING = 4
_DRAIN_TURNS = 5
_N_INPUT = 3

_SIM_POINTS_TOML = """\
[[modbus.points]]
name = "p2_bar"
table = "input_registers"
address = 0
type = "float32"
byte_order = "big"
word_order = "big"
min = -0.5
max = 12.0

[[modbus.points]]
name = "p3_bar"
table = "input_registers"
address = 2
type = "uint16"
scale = 0.001
max = 12.0

[[modbus.points]]
name = "p2_set_bar"
table = "holding_registers"
address = 0
type = "int32"
scale = 0.001
byte_order = "big"
word_order = "little"
min = 0.0
max = 12.0

[[modbus.points]]
name = "p3_set_bar"
table = "holding_registers"
address = 2
type = "int32"
scale = 0.001
byte_order = "big"
word_order = "little"
min = 0.0
max = 12.0

[[modbus.points]]
name = "enabling"
table = "discrete_inputs"
address = 0
type = "bool"

[[modbus.points]]
name = "estop_ok"
table = "discrete_inputs"
address = 1
type = "bool"

[[modbus.points]]
name = "mark"
table = "discrete_inputs"
address = 2
type = "bool"
"""


def sim_register_points_toml() -> str:
    """``[[modbus.points]]`` entries describing this module (paste below ``[modbus]``)."""
    return _SIM_POINTS_TOML


def sim_modbus_section_toml(host: str = "127.0.0.1", port: int = 5020, device_id: int = 1) -> str:
    """A complete ``[modbus]`` section for the virtual I/O module at ``host:port``."""
    return (
        "[modbus]\n"
        'adapter = "register_map"\n'
        f'host = "{host}"\n'
        f"port = {port}\n"
        f"device_id = {device_id}\n"
        "timeout_s = 0.1\n"
        "poll_period_s = 0.02\n"
        "max_setpoint_bar = 10.0\n"
        "\n" + _SIM_POINTS_TOML
    )


def _float32_abcd(value: float) -> list[int]:
    if math.isfinite(value) and abs(value) > _FLOAT32_MAX:
        value = math.copysign(math.inf, value)  # struct refuses to round these to infinity
    hi, lo = struct.unpack(">HH", struct.pack(">f", value))
    return [hi, lo]


def _mbar_uint16(bar: float) -> int:
    if math.isnan(bar):
        return 0xFFFF  # what a transmitter with a broken bridge reports: over-range
    return max(0, min(0xFFFF, round(bar * 1000.0)))


def _int32_cdab(value: int) -> list[int]:
    hi, lo = struct.unpack(">HH", struct.pack(">i", value))
    return [lo, hi]


def _cdab_int32(regs: list[int]) -> int:
    lo, hi = regs
    return struct.unpack(">i", struct.pack(">HH", hi, lo))[0]


def _mbar_int32(bar: float) -> int:
    return max(-(2**31), min(2**31 - 1, round(bar * 1000.0)))


def stored_bar(bar: float) -> float:
    """A set-point [bar] as the module holds it: rounded to its int32 mbar register."""
    return _mbar_int32(bar) / 1000.0


class VirtualIoServer:
    """Modbus TCP server for the virtual I/O module (see the module docstring for its registers).

    :param host: interface to listen on.
    :param port: TCP port; 0 picks a free one (read :attr:`port` after :meth:`start`).
    :param device_id: unit id the module answers to.
    :param p2_set_bar, p3_set_bar: set-points held before any client writes [bar].
    """

    #: How long :meth:`start` waits for the listener and :meth:`stop` for the thread [s].
    START_TIMEOUT_S = 5.0
    STOP_TIMEOUT_S = 5.0

    def __init__(
        self,
        host: str = "127.0.0.1",
        port: int = 5020,
        device_id: int = 1,
        *,
        p2_set_bar: float = 0.0,
        p3_set_bar: float = 0.0,
    ) -> None:
        self.host = host
        self.port = port
        self.device_id = device_id
        self._inputs: tuple[float, float, bool, bool, bool] = (0.0, 0.0, False, False, False)
        self._initial_holding = _int32_cdab(_mbar_int32(p2_set_bar)) + _int32_cdab(
            _mbar_int32(p3_set_bar)
        )
        self._setpoints: tuple[float, float] = (stored_bar(p2_set_bar), stored_bar(p3_set_bar))
        #: Number of write requests that changed the set-points.
        self.setpoint_writes = 0
        self._thread: threading.Thread | None = None
        self._loop: asyncio.AbstractEventLoop | None = None
        self._server: ModbusTcpServer | None = None
        self._stopped: asyncio.Event | None = None
        self._started = threading.Event()
        self._start_error: BaseException | None = None

    # Simulator side ----------------------------------------------------------------------

    def set_inputs(
        self, p2_bar: float, p3_bar: float, enabling: bool, estop_ok: bool, mark: bool = False
    ) -> None:
        """Publish new input values [bar]. Cheap and thread-safe: one reference swap."""
        self._inputs = (float(p2_bar), float(p3_bar), bool(enabling), bool(estop_ok), bool(mark))

    def setpoints(self) -> tuple[float, float]:
        """``(p2_set_bar, p3_set_bar)`` as last written by a client (or the initial values)."""
        return self._setpoints

    # Lifecycle ---------------------------------------------------------------------------

    def start(self) -> None:
        """Start listening; returns once the port is bound (raises OSError if it cannot be)."""
        if self._thread is not None:
            raise RuntimeError("VirtualIoServer already started")
        self._started.clear()
        self._start_error = None
        self._thread = threading.Thread(
            target=self._run, name=f"virtual-io-{self.host}:{self.port}", daemon=True
        )
        self._thread.start()
        if not self._started.wait(self.START_TIMEOUT_S):
            self.stop()
            raise TimeoutError(f"virtual I/O server on {self.host}:{self.port} did not start")
        if self._start_error is not None:
            err = self._start_error
            self.stop()
            raise OSError(f"virtual I/O server cannot listen on {self.host}:{self.port}: {err}")

    def stop(self) -> None:
        """Close the listener and every client connection, then join the thread (idempotent)."""
        thread, loop, stopped = self._thread, self._loop, self._stopped
        if thread is None:
            return
        if loop is not None and stopped is not None and not loop.is_closed():
            with contextlib.suppress(RuntimeError):  # the loop finished meanwhile
                loop.call_soon_threadsafe(stopped.set)
        thread.join(self.STOP_TIMEOUT_S)
        if thread.is_alive():
            raise RuntimeError(f"virtual I/O server thread {thread.name} did not stop")
        self._thread = None

    def __enter__(self) -> VirtualIoServer:
        self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()

    # Server thread -----------------------------------------------------------------------

    def _run(self) -> None:
        loop = asyncio.new_event_loop()
        self._loop = loop
        try:
            loop.run_until_complete(self._serve())
        finally:
            try:
                pending = asyncio.all_tasks(loop)
                for task in pending:
                    task.cancel()
                if pending:
                    loop.run_until_complete(asyncio.gather(*pending, return_exceptions=True))
                loop.run_until_complete(loop.shutdown_asyncgens())
            finally:
                loop.close()
                self._loop = None
                self._started.set()  # never leave start() waiting

    async def _serve(self) -> None:
        self._stopped = asyncio.Event()
        # SimData addresses are protocol addresses (0 = first register on the wire). The
        # deprecated ModbusSequentialDataBlock instead subtracts 1 from its start address;
        # tests/transport/test_modbus_link.py pins address 0 to the first value.
        device = SimDevice(
            id=self.device_id,
            simdata=(
                [SimData(0, values=[False] * 16, datatype=DataType.BITS)],
                [SimData(0, values=[False] * 16, datatype=DataType.BITS)],
                [SimData(0, values=list(self._initial_holding), datatype=DataType.REGISTERS)],
                [SimData(0, values=[0] * _N_INPUT, datatype=DataType.REGISTERS)],
            ),
            action=self._on_request,
        )
        server = ModbusTcpServer(device, address=(self.host, self.port))
        self._server = server
        try:
            await server.serve_forever(background=True)
        except (OSError, RuntimeError) as exc:
            self._start_error = exc
            server.close()
            self._started.set()
            return
        try:
            sockets = getattr(server.transport, "sockets", None)
            if sockets:
                self.port = sockets[0].getsockname()[1]
            self._started.set()
            await self._stopped.wait()
        finally:
            # Let accepts already under way reach pymodbus first: asyncio (3.11) cannot attach a
            # connection to a closed Server and would leak that connection's socket.
            for _ in range(_DRAIN_TURNS):
                await asyncio.sleep(0)
            await server.shutdown()
            # A connection accepted just before the shutdown reaches pymodbus only a loop turn
            # later, after the shutdown closed the others: close stragglers too, and let the
            # transports' close callbacks (which close the sockets) run before the loop ends.
            for _ in range(_DRAIN_TURNS):
                await asyncio.sleep(0)
                for conn in list(server.active_connections.values()):
                    conn.close()
            self._server = None

    async def _on_request(
        self,
        function_code: int,
        start_address: int,
        address: int,
        count: int,
        registers: list[int],
        set_values: list[int] | list[bool] | None,
    ) -> None:
        """pymodbus action hook: runs on the server loop before every access to a table.

        ``registers`` is the whole table (index 0 = protocol address ``start_address``, which is
        0 here); editing it in place changes what this request reads.
        """
        if function_code == _FC_READ_IR:
            p2, p3, _, _, _ = self._current_inputs()
            registers[0:_N_INPUT] = [*_float32_abcd(p2), _mbar_uint16(p3)]
        elif function_code == _FC_READ_DI:
            _, _, enabling, estop_ok, mark = self._current_inputs()
            registers[0] = int(enabling) | (int(estop_ok) << 1) | (int(mark) << 2)
        elif function_code in _FC_WRITE_HR and set_values is not None:
            # The hook runs before pymodbus stores the values: apply them to a copy to decode.
            regs = list(registers[0:_N_HOLDING])
            first = address - start_address
            regs[first : first + len(set_values)] = [int(v) for v in set_values]
            self._store_setpoints(_cdab_int32(regs[0:2]) / 1000.0, _cdab_int32(regs[2:4]) / 1000.0)
        return None

    # Where the inputs come from and the set-points go (VirtualIoProcess: shared memory) ---

    def _current_inputs(self) -> tuple[float, float, bool, bool, bool]:
        return self._inputs

    def _store_setpoints(self, p2_bar: float, p3_bar: float) -> None:
        self._setpoints = (p2_bar, p3_bar)
        self.setpoint_writes += 1
