"""The one wrapper around the pymodbus client: every pymodbus client call lives here.

pymodbus moves quickly (``slave=`` became ``device_id=`` in 3.x, replies changed shape), so the
rest of the product talks to :class:`ModbusLink` only, which speaks plain ``list[int]`` /
``list[bool]`` and raises our own exceptions.

Addresses are *protocol* addresses: the 0-based number that goes on the wire, as printed in
most device manuals ("input register 0"). Manuals that use the old 1-based "30001"/"40001"
notation must be converted before they reach this module (40001 → holding register 0).

Errors, all subclasses of :class:`~gateway.errors.ModbusReplyError`:

* :class:`ModbusLinkError` (also a ``ConnectionError``): not connected, connection refused or
  dropped, a reply for another transaction. The socket is closed; reconnect before retrying.
* :class:`ModbusTimeoutError` (also a :class:`~gateway.errors.LinkTimeoutError`): no reply within
  ``timeout_s``. The socket is closed too, so a late reply cannot be taken for the next one.
* plain :class:`~gateway.errors.ModbusReplyError`: the device answered, but with an exception
  response or the wrong number of values. The connection stays usable.

Every message names the function, the address, the count and what came back.
"""

from __future__ import annotations

from collections.abc import Sequence

from pymodbus.client import ModbusTcpClient
from pymodbus.exceptions import ConnectionException, ModbusException, ModbusIOException
from pymodbus.pdu import ModbusPDU

from gateway.errors import LinkTimeoutError, ModbusReplyError

#: Protocol limits per request (Modbus Application Protocol V1.1b3, §6.1–6.4, §6.12).
MAX_READ_REGISTERS = 125
MAX_WRITE_REGISTERS = 123
MAX_READ_BITS = 2000

#: Names of the standard exception codes (Modbus Application Protocol V1.1b3, §7).
EXCEPTION_CODES = {
    1: "ILLEGAL FUNCTION",
    2: "ILLEGAL DATA ADDRESS",
    3: "ILLEGAL DATA VALUE",
    4: "SERVER DEVICE FAILURE",
    5: "ACKNOWLEDGE",
    6: "SERVER DEVICE BUSY",
    8: "MEMORY PARITY ERROR",
    10: "GATEWAY PATH UNAVAILABLE",
    11: "GATEWAY TARGET DEVICE FAILED TO RESPOND",
}


class ModbusLinkError(ModbusReplyError, ConnectionError):
    """The TCP link is down or out of step; it has been closed and must be reconnected."""


class ModbusTimeoutError(ModbusLinkError, LinkTimeoutError):
    """The device did not answer within the link's timeout."""


class ModbusLink:
    """A synchronous Modbus TCP connection to one device (unit id ``device_id``).

    Not thread-safe: use it from one thread (the driver's poll thread).

    :param host: IP address or host name of the Modbus TCP server.
    :param port: TCP port (502 on real devices).
    :param device_id: Modbus unit identifier, 0..255.
    :param timeout_s: connect and reply timeout [s]. There are no automatic retries: the caller
        polls again next cycle, which is fresher than a retried stale request.
    """

    def __init__(self, host: str, port: int, device_id: int = 1, timeout_s: float = 0.2) -> None:
        if not 0 <= device_id <= 255:
            raise ValueError(f"device_id {device_id} outside 0..255")
        if not timeout_s > 0:
            raise ValueError(f"timeout_s {timeout_s} must be > 0")
        self.host = host
        self.port = port
        self.device_id = device_id
        self.timeout_s = timeout_s
        self._client = ModbusTcpClient(
            host, port=port, timeout=timeout_s, retries=0, name=f"modbus-{host}:{port}"
        )

    def __repr__(self) -> str:
        return f"ModbusLink({self.host}:{self.port}, device {self.device_id})"

    @property
    def connected(self) -> bool:
        return self._client.connected

    def connect(self) -> None:
        """Open the TCP connection; raise :class:`ModbusLinkError` if the server is unreachable."""
        try:
            ok = self._client.connect()
        except (OSError, ModbusException) as exc:
            self.close()
            raise ModbusLinkError(f"{self}: connect failed: {exc}") from exc
        if not ok:
            raise ModbusLinkError(
                f"{self}: connect failed (refused or no answer within {self.timeout_s} s)"
            )

    def close(self) -> None:
        """Close the connection (idempotent)."""
        self._client.close()

    def __enter__(self) -> ModbusLink:
        self.connect()
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # Reads -------------------------------------------------------------------------------

    def read_input_registers(self, address: int, count: int) -> list[int]:
        """Function 0x04: ``count`` input registers from ``address`` (0..65535 each)."""
        return self._read_registers("read_input_registers", address, count)

    def read_holding_registers(self, address: int, count: int) -> list[int]:
        """Function 0x03: ``count`` holding registers from ``address`` (0..65535 each)."""
        return self._read_registers("read_holding_registers", address, count)

    def read_discrete_inputs(self, address: int, count: int) -> list[bool]:
        """Function 0x02: ``count`` discrete inputs from ``address``."""
        return self._read_bits("read_discrete_inputs", address, count)

    def read_coils(self, address: int, count: int) -> list[bool]:
        """Function 0x01: ``count`` coils from ``address``."""
        return self._read_bits("read_coils", address, count)

    # Writes ------------------------------------------------------------------------------

    def write_registers(self, address: int, values: Sequence[int]) -> None:
        """Function 0x10: write holding registers ``address..address+len(values)-1``."""
        values = [int(v) for v in values]
        what = f"write_registers(address={address}, count={len(values)})"
        _check_range(what, address, len(values), MAX_WRITE_REGISTERS)
        bad = [v for v in values if not 0 <= v <= 0xFFFF]
        if bad:
            raise ValueError(f"{what}: values {bad} do not fit a 16-bit register")
        reply = self._call(what, "write_registers", address, values)
        if reply.address != address or reply.count != len(values):
            raise ModbusReplyError(
                f"{self} {what}: reply echoes address={reply.address} count={reply.count}"
            )

    def write_coil(self, address: int, value: bool) -> None:
        """Function 0x05: set one coil."""
        what = f"write_coil(address={address}, count=1, value={bool(value)})"
        _check_range(what, address, 1, 1)
        reply = self._call(what, "write_coil", address, bool(value))
        if reply.address != address or list(reply.bits[:1]) != [bool(value)]:
            raise ModbusReplyError(
                f"{self} {what}: reply echoes address={reply.address} bits={reply.bits[:1]}"
            )

    # Internals ---------------------------------------------------------------------------

    def _read_registers(self, function: str, address: int, count: int) -> list[int]:
        what = f"{function}(address={address}, count={count})"
        _check_range(what, address, count, MAX_READ_REGISTERS)
        reply = self._call(what, function, address, count=count)
        regs = list(reply.registers)
        if len(regs) != count:
            raise ModbusReplyError(f"{self} {what}: reply holds {len(regs)} registers {regs}")
        return regs

    def _read_bits(self, function: str, address: int, count: int) -> list[bool]:
        what = f"{function}(address={address}, count={count})"
        _check_range(what, address, count, MAX_READ_BITS)
        reply = self._call(what, function, address, count=count)
        bits = [bool(b) for b in reply.bits]
        # Bits travel packed in whole bytes: a correct reply holds exactly the bytes that take
        # ``count`` bits (up to 7 padding bits); one byte more or less is another reply's.
        if len(bits) != 8 * ((count + 7) // 8):
            raise ModbusReplyError(
                f"{self} {what}: reply holds {len(bits) // 8} bytes of bits {bits[:16]}"
                f"{'...' if len(bits) > 16 else ''}, not the {(count + 7) // 8} that {count} take"
            )
        return bits[:count]

    def _call(self, what: str, function: str, *args: object, **kwargs: object) -> ModbusPDU:
        if not self._client.connected:
            raise ModbusLinkError(f"{self} {what}: not connected")
        try:
            reply = getattr(self._client, function)(*args, device_id=self.device_id, **kwargs)
        except ModbusIOException as exc:
            self.close()
            if "no response" in str(exc).lower():
                raise ModbusTimeoutError(
                    f"{self} {what}: no reply within {self.timeout_s} s"
                ) from exc
            raise ModbusLinkError(f"{self} {what}: {exc}") from exc
        except (ConnectionException, OSError) as exc:
            self.close()
            raise ModbusLinkError(f"{self} {what}: connection lost: {exc}") from exc
        except ModbusException as exc:
            self.close()
            raise ModbusLinkError(f"{self} {what}: {exc}") from exc
        if reply is None:
            raise ModbusReplyError(f"{self} {what}: no reply object")
        if reply.isError():
            code = getattr(reply, "exception_code", None)
            name = EXCEPTION_CODES.get(code, "unknown code") if isinstance(code, int) else "?"
            raise ModbusReplyError(f"{self} {what}: exception response {code} ({name})")
        return reply


def _check_range(what: str, address: int, count: int, max_count: int) -> None:
    if not 1 <= count <= max_count:
        raise ValueError(f"{what}: count must be 1..{max_count}")
    if address < 0 or address + count - 1 > 0xFFFF:
        raise ValueError(f"{what}: addresses outside 0..65535")
