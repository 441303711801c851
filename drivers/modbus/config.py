"""``[modbus]`` section of the cell config: where the I/O module is and what its registers mean.

Example (the virtual I/O module's section is
:func:`sim_bridge.modbus_server.sim_modbus_section_toml`)::

    [modbus]
    adapter = "register_map"
    host = "192.168.10.20"
    port = 502

    [[modbus.points]]
    name = "p2_bar"
    table = "input_registers"
    address = 0
    type = "float32"
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

from drivers.modbus.registermap import Point
from gateway.bus import check_cell_sections
from gateway.cell_section import CellSection
from gateway.config import from_mapping, require


@dataclass(frozen=True)
class ModbusDriverConfig:
    """``[modbus]`` section."""

    #: IP address or host name of the Modbus TCP I/O module.
    host: str
    #: TCP port of the module (502 on real devices; the virtual module defaults to 5020).
    port: int
    #: Adapter that turns registers into pressures and safety inputs, by name: the built-in
    #: ``register_map`` or one registered under entry-point group ``leadthrough.modbus_adapters``.
    adapter: str = "register_map"
    #: Modbus unit identifier of the module, 0..255.
    device_id: int = 1
    #: Connect and reply timeout per request [s].
    timeout_s: float = 0.2
    #: Poll period of the inputs [s]; IoState is published once per successful poll.
    poll_period_s: float = 0.02
    #: Highest cylinder pressure set-point the driver will write [bar]; higher requests are refused.
    max_setpoint_bar: float = 10.0
    #: The register map (``[[modbus.points]]``), see :class:`~drivers.modbus.registermap.Point`.
    points: tuple[Point, ...] = ()

    def __post_init__(self) -> None:
        require(bool(self.host.strip()), "[modbus].host", f"{self.host!r} must not be empty")
        require(1 <= self.port <= 65535, "[modbus].port", f"{self.port} is outside 1..65535")
        require(bool(self.adapter), "[modbus].adapter", f"{self.adapter!r} must name an adapter")
        require(
            0 <= self.device_id <= 255, "[modbus].device_id", f"{self.device_id} outside 0..255"
        )
        require(
            0.0 < self.timeout_s <= 10.0,
            "[modbus].timeout_s",
            f"{self.timeout_s} must be in (0, 10] s",
        )
        require(
            0.001 <= self.poll_period_s <= 1.0,
            "[modbus].poll_period_s",
            f"{self.poll_period_s} must be in [0.001, 1] s",
        )
        require(
            math.isfinite(self.max_setpoint_bar) and 0.0 < self.max_setpoint_bar <= 16.0,
            "[modbus].max_setpoint_bar",
            f"{self.max_setpoint_bar} must be in (0, 16] bar",
        )

    @classmethod
    def from_cell_config(
        cls, cell: dict[str, Any], where: str = "cell config"
    ) -> ModbusDriverConfig:
        """Build from a whole parsed cell config (its ``[modbus]`` table)."""
        check_cell_sections(cell, where)
        require("modbus" in cell, where, "has no [modbus] section")
        return from_mapping(cls, cell["modbus"], f"{where} [modbus]")


#: the ``[modbus]`` section of the cell config, registered in pyproject.toml; the gateway
#: checks it before it starts the driver
CELL_SECTION = CellSection(
    "modbus",
    lambda path, raw: ModbusDriverConfig.from_cell_config(raw, str(path)),
    ModbusDriverConfig,
    order=4,
    checked_at_start=True,
)
