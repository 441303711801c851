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
3–15 and coils 1–15 exist and read 0. Set-points are
stored as written (no clamping: the driver owns the limits) and read back unchanged.

The encodings are written out in the module's own code (``sim_bridge/rt/src/io_module/``),
independently of :mod:`drivers.modbus.registermap`, so a symmetric bug in the map cannot hide
itself. Requests past a table answer exception 2 (ILLEGAL DATA ADDRESS), quantities outside the
spec's limits exception 3, other functions exception 1, another unit id exception 4.

:func:`sim_modbus_section_toml` gives the matching ``[modbus]`` section for the cell config.

Threading: the server is compiled (``sim_bridge._rt``, ``sim_bridge/rt/``): one native thread
accepts and one per connection answers, none of them takes Python's GIL, so the simulator's
loop cannot make a reply late, and the threads are created at the priority of the thread that
starts the server (the simulator's loop, after ``[scheduling]``). A real module answers on its
own processor. (It was pymodbus's server on an asyncio loop, first in the simulator's process,
where the loop's GIL made replies 0.1-0.3 s late, then in a child process of its own, which
cost 0.35-0.44 ms of CPU per 8 ms cycle for 50 polls a second: issue 45.)
:meth:`VirtualIoServer.set_inputs` (simulator loop, once a cycle) stores one snapshot; the
registers are encoded from it when a request arrives.
"""

from __future__ import annotations

from sim_bridge._rt import VirtualIoModule

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


class VirtualIoServer:
    """Modbus TCP server for the virtual I/O module (see the module docstring for its registers).

    :param host: interface to listen on.
    :param port: TCP port; 0 picks a free one (read :attr:`port` after :meth:`start`).
    :param device_id: unit id the module answers to.
    :param p2_set_bar, p3_set_bar: set-points held before any client writes [bar], stored as
        the module stores every set-point (int32 mbar).
    """

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
        self._module = VirtualIoModule(host, port, device_id, p2_set_bar, p3_set_bar)

    # Simulator side ----------------------------------------------------------------------

    def set_inputs(
        self, p2_bar: float, p3_bar: float, enabling: bool, estop_ok: bool, mark: bool = False
    ) -> None:
        """Publish new input values [bar]; thread-safe, one snapshot of all five."""
        self._module.set_inputs(float(p2_bar), float(p3_bar), bool(enabling), bool(estop_ok),
                                bool(mark))  # fmt: skip

    def setpoints(self) -> tuple[float, float]:
        """``(p2_set_bar, p3_set_bar)`` as last written by a client (or the initial values)."""
        return self._module.setpoints()

    @property
    def setpoint_writes(self) -> int:
        """Number of write requests that reached the set-points."""
        return self._module.setpoint_writes

    # Lifecycle ---------------------------------------------------------------------------

    def start(self) -> None:
        """Start listening; returns once the port is bound (raises OSError if it cannot be)."""
        self.port = self._module.start()

    def stop(self) -> None:
        """Close the listener and every client connection, then join the server's threads
        (idempotent)."""
        self._module.stop()

    close = stop

    def __enter__(self) -> VirtualIoServer:
        self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()
