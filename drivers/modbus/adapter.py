"""The pressure/safety I/O port and its Modbus implementations, chosen by name.

:class:`PressureIoAdapter` is the small abstract port the Modbus driver talks to. The built-in
``register_map`` adapter reads everything through a configurable
:class:`~drivers.modbus.registermap.RegisterMap`; a module that needs code (a handshake, a
vendor-specific function) can ship an adapter in its own package and register it under the
entry-point group ``leadthrough.modbus_adapters``::

    [project.entry-points."leadthrough.modbus_adapters"]
    acme_io = "acme_leadthrough.io:AcmeAdapter"

An adapter class is constructed as ``cls(config: ModbusDriverConfig)``.
"""

from __future__ import annotations

import abc
from importlib.metadata import entry_points
from typing import NamedTuple

from drivers.modbus.client import ModbusLink
from drivers.modbus.config import ModbusDriverConfig
from drivers.modbus.registermap import RegisterMap
from gateway.errors import ConfigError

ENTRY_POINT_GROUP = "leadthrough.modbus_adapters"


class IoReading(NamedTuple):
    """One poll of the cell's pressure and safety I/O."""

    p2_bar: float  #: measured pressure, assist cylinder of joint 2 [bar]
    p3_bar: float  #: measured pressure, assist cylinder of joint 3 [bar]
    p2_set_bar: float  #: set-point as read back from the valve [bar]
    p3_set_bar: float
    enabling: bool  #: enabling device held in its middle position
    estop_ok: bool  #: e-stop chain closed
    mark: bool = False  #: the teach handle's mark button pressed (False: the cell has none)


class PressureIoAdapter(abc.ABC):
    """Port to the cylinder pressures, valve set-points, enabling device and e-stop chain.

    Every method raises :class:`~gateway.errors.ModbusReplyError` (or a subclass) on failure;
    :class:`~drivers.modbus.client.ModbusLinkError` means "reconnect before the next call".
    """

    @abc.abstractmethod
    def connect(self) -> None:
        """Open the link to the I/O module."""

    @abc.abstractmethod
    def read(self) -> IoReading:
        """Read every input once."""

    @abc.abstractmethod
    def write_setpoints(self, p2_bar: float, p3_bar: float) -> None:
        """Write both cylinder pressure set-points [bar] (together, in one request if possible).

        :raises ValueError: (not a ModbusReplyError) a value the module cannot represent;
            nothing was written.
        """

    @abc.abstractmethod
    def close(self) -> None:
        """Close the link (idempotent, never raises)."""


class RegisterMapAdapter(PressureIoAdapter):
    """Adapter ``register_map``: every value is a :class:`~drivers.modbus.registermap.Point`.

    Required points: ``p2_bar``, ``p3_bar`` (measured, numeric), ``p2_set_bar``, ``p3_set_bar``
    (numeric, in ``holding_registers``: they are written for set-points and read back),
    ``enabling`` and ``estop_ok`` (``bool``). Optional: ``mark`` (``bool``), the teach
    handle's button that marks a waypoint in the taught program.

    :param link: inject a link (tests); by default one is built from the config.
    """

    REQUIRED = ("p2_bar", "p3_bar", "p2_set_bar", "p3_set_bar", "enabling", "estop_ok")
    SETPOINTS = ("p2_set_bar", "p3_set_bar")
    BOOLS = ("enabling", "estop_ok")
    OPTIONAL_BOOLS = ("mark",)

    def __init__(self, config: ModbusDriverConfig, link: ModbusLink | None = None) -> None:
        where = "[modbus].points"
        self.map = RegisterMap(config.points, required=self.REQUIRED, where=where)
        for name in self.SETPOINTS:
            p = self.map[name]
            if p.table != "holding_registers" or p.type == "bool":
                raise ConfigError(
                    f"{where}: {name!r} must be a numeric point in holding_registers (it is "
                    f"written), not {p.type} in {p.table}"
                )
        for name in ("p2_bar", "p3_bar"):
            if self.map[name].type == "bool":
                raise ConfigError(f"{where}: {name!r} must be numeric, not bool")
        for name in (*self.BOOLS, *(b for b in self.OPTIONAL_BOOLS if b in self.map)):
            if self.map[name].type != "bool":
                raise ConfigError(
                    f"{where}: {name!r} must have type 'bool', not {self.map[name].type!r}"
                )
        self.link = link or ModbusLink(config.host, config.port, config.device_id, config.timeout_s)

    def connect(self) -> None:
        self.link.connect()

    def read(self) -> IoReading:
        v = self.map.read_all(self.link)
        return IoReading(
            float(v["p2_bar"]),
            float(v["p3_bar"]),
            float(v["p2_set_bar"]),
            float(v["p3_set_bar"]),
            bool(v["enabling"]),
            bool(v["estop_ok"]),
            bool(v.get("mark", False)),
        )

    def write_setpoints(self, p2_bar: float, p3_bar: float) -> None:
        # Encode both before writing either, so a refused value writes nothing.
        writes = self.map.encode_writes({"p2_set_bar": p2_bar, "p3_set_bar": p3_bar})
        for _table, address, raw in writes:
            self.link.write_registers(address, raw)

    def close(self) -> None:
        self.link.close()


_BUILTIN: dict[str, type[PressureIoAdapter]] = {"register_map": RegisterMapAdapter}


def available_adapters() -> list[str]:
    """Names of the built-in adapters and of those registered as entry points."""
    return sorted(set(_BUILTIN) | {ep.name for ep in entry_points(group=ENTRY_POINT_GROUP)})


def adapter_class(name: str) -> type[PressureIoAdapter]:
    """Look an adapter up by name: built-ins first, then the entry-point group (imported lazily).

    :raises ConfigError: unknown name (listing the available ones), or an entry point that does
        not load to a :class:`PressureIoAdapter` subclass.
    """
    if name in _BUILTIN:
        return _BUILTIN[name]
    matches = [ep for ep in entry_points(group=ENTRY_POINT_GROUP) if ep.name == name]
    if not matches:
        raise ConfigError(
            f"[modbus].adapter: unknown adapter {name!r}; available: {available_adapters()}"
        )
    try:
        cls = matches[0].load()
    except Exception as exc:
        raise ConfigError(
            f"[modbus].adapter: entry point {matches[0].value!r} for {name!r} failed to load: "
            f"{exc!r}"
        ) from exc
    if not (isinstance(cls, type) and issubclass(cls, PressureIoAdapter)):
        raise ConfigError(
            f"[modbus].adapter: {matches[0].value!r} is not a PressureIoAdapter subclass"
        )
    return cls


def create_adapter(config: ModbusDriverConfig) -> PressureIoAdapter:
    """Build the adapter named by ``config.adapter``."""
    return adapter_class(config.adapter)(config)
