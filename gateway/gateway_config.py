"""The ``[gateway]`` section of the cell config: what the supervisor (gateway/supervisor.py)
watches and how long it waits, and its loader. Apart from the supervisor so that the config
check (gateway/config_check.py) reads it without the supervisor, which checks the cell config
with it at start."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from gateway.bus import BusConfig, bus_config_from
from gateway.cell_section import CellSection
from gateway.config import from_mapping, load_toml, require

#: the processes the gateway may start and supervise
SUPERVISED = ("can-driver", "modbus-driver", "control")


@dataclass(frozen=True)
class GatewayConfig:
    """``[gateway]`` section of the cell config."""

    joint_state_timeout_s: float = 0.1
    io_timeout_s: float = 0.25
    standstill_rad_s: float = 2e-3  #: teaching starts only below this joint speed [rad/s]
    standstill_s: float = 0.3  #: ... held for this long [s]
    #: ... and the servo on for this long [s] (gateway/lifecycle.py Limits.servo_settle_s)
    servo_settle_s: float = 1.0
    health_timeout_s: float = 0.5  #: a child whose heartbeat is older is "silent"
    #: a child started this long ago [s] with no heartbeat yet is still booting, not silent.
    #: Measured: control's first log line came 12 s after its start under `taskset -c 0`
    #: with the CiA 402 cell (the simulator, its drives and four product processes starting on
    #: one core); the fixed 10 s faulted the cell. Nothing moves meanwhile: teaching waits for
    #: control's health and its static-load check, and a child that dies is caught by its exit.
    boot_grace_s: float = 30.0
    #: the enabling device counts as held once this many I/O states in a row read it held
    #: (a release counts at once): one corrupt or forged Modbus reply does not start teaching
    enabling_confirm_polls: int = 2
    restart_backoff_s: float = 2.0
    processes: tuple[str, ...] = SUPERVISED
    #: where taught programs are written (relative: to the cell config's folder)
    program_dir: str = "programs"

    def __post_init__(self) -> None:
        for p in self.processes:
            require(p in SUPERVISED, "[gateway].processes", f"{p!r} not one of {SUPERVISED}")
        require(
            self.boot_grace_s > 0 and self.boot_grace_s < 600,
            "[gateway].boot_grace_s",
            f"{self.boot_grace_s!r} outside (0, 600) s",
        )
        n = self.enabling_confirm_polls
        require(
            isinstance(n, int) and not isinstance(n, bool) and 1 <= n <= 50,
            "[gateway].enabling_confirm_polls",
            f"{n!r} outside 1..50 I/O states",
        )


def load_gateway_config(cell_path: Path) -> tuple[GatewayConfig, BusConfig]:
    raw = load_toml(cell_path)
    bus = bus_config_from(raw, str(cell_path))  # first: it refuses an unknown section
    cfg = from_mapping(GatewayConfig, raw.get("gateway", {}), f"{cell_path} [gateway]")
    return cfg, bus


#: the ``[gateway]`` section of the cell config, registered in pyproject.toml
CELL_SECTION = CellSection(
    "gateway", lambda path, raw: load_gateway_config(path), GatewayConfig, order=2
)
