"""``[can]`` section of the cell config: the CAN driver's adapter, transport, deadlines and limits.

Example (virtual controller)::

    [can]
    adapter = "ltc_dbc"
    joints = 6
    deadline_s = 0.010
    max_following_error_rad = [0.05, 0.05, 0.05, 0.08, 0.08, 0.08]
    max_velocity_rad_s = 1.0          # one number applies to every joint

    [can.transport]                   # keyword arguments of can.Bus()
    interface = "seqpacket"           # drivers/can/seqpacket.py
    channel = "@leadthrough-vcan0"
    connect_timeout_s = 5.0

Production differs only in the transport: ``interface = "socketcan"``, ``channel = "can0"``.
The compiled CAN driver speaks only these two interfaces (drivers/can/rt/src/can_socket.rs);
any other is refused.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from drivers.can.seqpacket import address_problem
from gateway.bus import BusConfig, bus_config_from
from gateway.cell_section import CellSection
from gateway.config import from_mapping, load_toml, require, require_count, resolve_path

#: ``lost_cycle_answer`` values (drivers/can/rt/src/lost_cycles.rs)
COAST_ANSWER, HOLD_ANSWER = "coast", "hold"

_TRANSPORT_SCALARS = (str, int, float, bool)
#: The interfaces the compiled CAN driver speaks (drivers/can/rt/src/can_socket.rs).
TRANSPORT_INTERFACES = ("socketcan", "seqpacket")
#: the transport of the virtual controller (sim_bridge), the only one that may run lock-step
VIRTUAL_INTERFACE = "seqpacket"
#: ``[can].lockstep_answer_wait_s`` at most [s]: below the lock-step virtual controller's own
#: wait for an answer (sim_bridge's ``lockstep_timeout_s``, 0.25 s), so the driver's hold
#: reaches it first
LOCKSTEP_ANSWER_WAIT_MAX_S = 0.2
#: Keyword arguments SeqpacketBus takes; anything else would be silently ignored, so refuse it.
_SEQPACKET_KEYS = ("interface", "channel", "fd", "connect_timeout_s")


def _production_transport() -> dict[str, Any]:
    return {"interface": "socketcan", "channel": "can0"}


#: CiA 301's manufacturer-specific area: the only objects ``startup_sdo`` may write
MANUFACTURER_AREA = (0x2000, 0x5FFF)


@dataclass(frozen=True)
class Cia402Config:
    """``[can.cia402]``: CiA 402 servo drives over CANopen (``[can] adapter = "cia402"``,
    drivers/can/cia402.py). The host is the SYNC producer and the NMT master."""

    #: The drives' electronic data sheet (relative to the cell config).
    eds: str = ""
    #: The drives' node ids in joint order (empty: 1..joints).
    node_ids: tuple[int, ...] = ()
    #: The host's own node id: its heartbeat is COB 0x700 + this.
    host_node_id: int = 0x7F
    #: "csp" (cyclic synchronous position: 0x607A target, 0x60B1 velocity offset) or "csv"
    #: (cyclic synchronous velocity: 0x60FF target velocity).
    mode: str = "csp"
    #: SYNC period: the loop rate the host clocks [s] (0x1006 on the drives).
    cycle_period_s: float = 0.008
    #: The drives stop (0x6007) when the host's heartbeat is missing this long [s] (0x1016).
    consumer_heartbeat_s: float = 0.1
    #: The drives' own heartbeat period [s] (0x1017).
    producer_heartbeat_s: float = 0.05
    #: 0x6007 abort connection option code: 1 fault, 2 disable voltage, 3 quick stop.
    abort_connection_option: int = 3
    #: Per joint: motor revolutions per joint revolution; checked against each drive's 0x6091.
    gear_ratio: tuple[float, ...] = ()
    #: Per joint: the motor's rated current [A]; checked against each drive's 0x6075.
    rated_current_a: tuple[float, ...] = ()
    #: Encoder increments per motor revolution; checked against each drive's 0x608F.
    encoder_increments: int = 1 << 20
    #: Writes every drive gets by SDO at start-up, after the adapter's own: [index, subindex,
    #: value], each in the manufacturer-specific area (what the drive's vendor documents: a
    #: current filter, a brake delay); the objects the adapter sets and checks are not here.
    #: Written in this order, each as the EDS types it; a refusal fails the start, naming it.
    startup_sdo: tuple[tuple[int, int, int], ...] = ()
    #: Each SDO request, and the drives' boot-up, must be answered within these [s].
    sdo_timeout_s: float = 0.5
    boot_timeout_s: float = 5.0

    def __post_init__(self) -> None:
        w = "[can.cia402]"
        require(self.mode in ("csp", "csv"), f"{w}.mode", f"{self.mode!r} is neither csp nor csv")
        require(1 <= self.host_node_id <= 127, f"{w}.host_node_id", "must be in 1..127")
        bad = [i for i in self.node_ids if not 1 <= i <= 127 or i == self.host_node_id]
        require(not bad, f"{w}.node_ids", f"{bad} not in 1..127 or the host's own id")
        require(len(set(self.node_ids)) == len(self.node_ids), f"{w}.node_ids", "an id given twice")
        for name in ("cycle_period_s", "consumer_heartbeat_s", "producer_heartbeat_s",
                     "sdo_timeout_s", "boot_timeout_s"):  # fmt: skip
            value = getattr(self, name)
            require(0 < value <= 60, f"{w}.{name}", f"{value!r} must be in (0, 60] s")
        require(
            self.consumer_heartbeat_s >= 2 * self.cycle_period_s,
            f"{w}.consumer_heartbeat_s",
            "must be at least two cycle periods",
        )
        require(
            self.abort_connection_option in (1, 2, 3),
            f"{w}.abort_connection_option",
            "must be 1 (fault), 2 (disable voltage) or 3 (quick stop): a drive must stop when "
            "the host goes silent",
        )
        ok = all(math.isfinite(g) and g > 0 for g in self.gear_ratio)
        require(ok, f"{w}.gear_ratio", "every ratio must be positive")
        ok = all(math.isfinite(i) and i > 0 for i in self.rated_current_a)
        require(ok, f"{w}.rated_current_a", "every current must be positive")
        require(self.encoder_increments > 0, f"{w}.encoder_increments", "must be positive")
        for k, (index, subindex, _value) in enumerate(self.startup_sdo):
            require(
                MANUFACTURER_AREA[0] <= index <= MANUFACTURER_AREA[1] and 0 <= subindex <= 0xFF,
                f"{w}.startup_sdo[{k}]",
                f"0x{index:X} sub {subindex} is not an object of the manufacturer-specific area "
                f"0x{MANUFACTURER_AREA[0]:04X}-0x{MANUFACTURER_AREA[1]:04X} (sub 0-255): the "
                "communication and drive profile objects are the adapter's",
            )

    def check_joints(self, joints: int) -> None:
        """ConfigError unless the per-joint lists fit ``joints`` (called by the adapter)."""
        w = "[can.cia402]"
        require(bool(self.eds), f"{w}.eds", "the drives' EDS file is required")
        for name in ("gear_ratio", "rated_current_a"):
            n = len(getattr(self, name))
            require(n == joints, f"{w}.{name}", f"{n} values for {joints} joints")
        if self.node_ids:
            n = len(self.node_ids)
            require(n == joints, f"{w}.node_ids", f"{n} ids for {joints} joints")

    def ids(self, joints: int) -> tuple[int, ...]:
        return self.node_ids or tuple(range(1, joints + 1))


@dataclass(frozen=True)
class CanDriverConfig:
    """``[can]`` section of the cell config. Every duration is in seconds."""

    #: Name of the controller protocol adapter (see drivers/registry.py).
    adapter: str = "ltc_dbc"
    #: Number of robot joints the driver reports and commands.
    joints: int = 6
    #: Keyword arguments of ``can.Bus(**transport)``. Only this differs between the virtual
    #: controller (interface "seqpacket") and the cell (interface "socketcan", channel "can0").
    transport: dict[str, Any] = field(default_factory=_production_transport)
    #: A JointCommand older than this (driver clock − its state_stamp_s) is never forwarded [s].
    #: An unanswered cycle is answered with a hold set at this age, or earlier if the
    #: controller's cycle period demands it (see drivers/can/rt/src/core.rs).
    deadline_s: float = 0.010
    #: An unanswered cycle is answered (coast or hold) this far into the controller's period
    #: at the latest [1]: the rest is margin for the frames to reach the controller before its
    #: next cycle. A lock-step virtual controller waits for the answer, so there the whole
    #: period may be used.
    answer_by_period_fraction: float = 0.5
    #: 0 (a real controller, always): as above. > 0: the controller is the lock-step virtual
    #: one (transport "seqpacket", sim_bridge --lockstep), which starts its next cycle only
    #: once this one is answered; the driver then waits this long for a command before it
    #: coasts or holds, and forwards a command up to this old [s]. A product process slowed
    #: by a loaded machine then slows the virtual plant instead of cutting holds into the
    #: motion it records (commissioning). At most 0.2 s: below the virtual controller's own
    #: wait for an answer (its lockstep_timeout_s, 0.25 s).
    lockstep_answer_wait_s: float = 0.0
    #: The gateway's lifecycle message counts as fresh for this long [s].
    lifecycle_timeout_s: float = 0.25
    #: The Modbus driver's IoState counts as fresh for this long [s].
    io_timeout_s: float = 0.25
    #: The controller link is up while a complete cycle arrived within this time [s].
    controller_timeout_s: float = 0.1
    #: Period of HEARTBEAT_HOST and of the repeated HOST_REQUEST [s].
    heartbeat_period_s: float = 0.1
    #: The joint states reach the readers off the cycle (the gateway) as one StateWindow per
    #: this long [s] (gateway/messages.py); keep it well under the gateway's
    #: joint_state_timeout_s, which a window's age adds to.
    state_window_s: float = 0.02
    #: Per joint (or one value for all): a command with |q_cmd − q| beyond this is rejected [rad].
    max_following_error_rad: float | tuple[float, ...] = 0.05
    #: Per joint (or one value for all): a command with |dq_cmd| beyond this is rejected [rad/s].
    max_velocity_rad_s: float | tuple[float, ...] = 1.0
    #: The current sensors' zero is the mean of the newest this-many cycles reported with the
    #: servo power off, subtracted from every published current
    #: (drivers/can/rt/src/current_zero.rs); the first servo-on waits for it. 0: off (currents
    #: as the drives report them).
    current_zero_cycles: int = 0
    #: Cycles skipped after the servo power goes off before they count towards the zero.
    current_zero_settle_cycles: int = 5
    #: The zero `leadthrough identify` ran with (its ``current_zero.json``; relative to the
    #: cell config): used from the start instead of the one measured now, so the currents
    #: agree with the identified model (gateway/current_zero_file.py). "": none, measure it.
    current_zero_file: str = ""
    #: Hand guiding's speed limit for the tool point and the flange [m/s], monitored from the
    #: measured positions while teaching or replaying (drivers/can/rt/src/speed_monitor.rs):
    #: past it the driver holds every cycle and reports the trip; the gateway faults. 0: no
    #: monitor.
    hand_guiding_max_speed_m_s: float = 0.25
    #: A command with a position closer than this to a joint's limit (the robot description's,
    #: the datasheet's) is rejected and the cycle held [rad]: the driver's own joint limits,
    #: behind the control law's soft walls ([control] soft_limit_margin_rad, further inside).
    joint_limit_margin_rad: float = 0.01
    #: Per joint (or one value for all): releasing the enabling device, or the lifecycle
    #: leaving a commanding state for READY, ramps the last command's velocity to zero at
    #: this deceleration, every joint over the same time, then holds (stop category 2,
    #: drivers/can/rt/src/stop_ramp.rs) [rad/s²].
    stop_deceleration_rad_s2: float | tuple[float, ...] = 2.0
    #: Monitored standstill while the driver holds with the servo on: after settling this
    #: long [s], a joint more than standstill_band_rad from the hold in
    #: standstill_confirm_cycles cycles in a row trips it; the driver asks for the brakes and
    #: the gateway faults (drivers/can/rt/src/stop_ramp.rs).
    standstill_settle_s: float = 0.5
    standstill_band_rad: float = 0.02
    standstill_confirm_cycles: int = 3
    #: This many CAN error frames within bus_error_window_s latch a bus fault, as a bus-off
    #: does at once; the fault clears once no error frame came for the window and the cell is
    #: stopped (drivers/can/rt/src/bus_errors.rs).
    bus_error_limit: int = 10
    bus_error_window_s: float = 1.0
    #: A cycle forwarding was allowed for whose command did not come in time is *lost*
    #: (drivers/can/rt/src/lost_cycles.rs): answered with "coast" (the last command moved on
    #: by its velocity, while it answered one of the coast_max_cycles cycles before, then a
    #: hold) or "hold" (at once).
    lost_cycle_answer: str = "coast"
    #: A late cycle coasts only on the command forwarded for one of this many cycles before
    #: it: 1, one late cycle costs nothing and a second in a row holds (open loop for at most
    #: one period, 2 mm at the tool at 0.25 m/s and 8 ms).
    coast_max_cycles: int = 1
    #: This many lost cycles in a row, or lost_cycles_max_per_window within
    #: lost_cycles_window_s, trip: the arm is stopped as for a released enabling device and
    #: the gateway faults until the operator re-arms. 0 turns a rule off. 50 cycles is 0.4 s
    #: at LTC-1's 8 ms, before the gateway's 0.5 s health watchdog would find a silent
    #: control process; 100 in 2 s two cycles in five. (13 in a row and 40 in 1 s tripped
    #: replays on a 2-core machine loaded twice over.)
    lost_cycles_max_consecutive: int = 50
    lost_cycles_max_per_window: int = 100
    lost_cycles_window_s: float = 2.0
    #: A cycle in which a joint's measured position moved faster than this from the last
    #: cycle taken is dropped as implausible (drivers/can/rt/src/plausibility.rs): a broken
    #: node or a glitched encoder, not the arm. Above every joint's top speed (a painting
    #: robot's wrist: about 7 rad/s); 0 turns the check off.
    feedback_max_joint_speed_rad_s: float = 10.0
    #: The CiA 402 adapter's settings (used only with ``adapter = "cia402"``).
    cia402: Cia402Config = field(default_factory=Cia402Config)

    def __post_init__(self) -> None:
        where = "[can]"
        require(bool(self.adapter), f"{where}.adapter", "must name an adapter, e.g. 'ltc_dbc'")
        require(1 <= self.joints <= 16, f"{where}.joints", f"{self.joints} outside 1..16")
        if self.adapter == "cia402":
            self.cia402.check_joints(self.joints)
        self._check_transport(dict(self.transport))
        object.__setattr__(self, "transport", dict(self.transport))
        for name, lo, hi in (
            ("deadline_s", 0.0, 0.1),
            ("lifecycle_timeout_s", 0.0, 5.0),
            ("io_timeout_s", 0.0, 5.0),
            ("controller_timeout_s", 0.0, 5.0),
            ("heartbeat_period_s", 0.0, 1.0),
            ("state_window_s", 0.0, 0.05),
        ):
            value = getattr(self, name)
            require(
                math.isfinite(value) and lo < value <= hi,
                f"{where}.{name}",
                f"{value!r} s outside ({lo}, {hi}]",
            )
        limit = self.hand_guiding_max_speed_m_s
        require(
            isinstance(limit, int | float) and math.isfinite(limit) and 0.0 <= limit <= 1.0,
            f"{where}.hand_guiding_max_speed_m_s",
            f"{limit!r} m/s outside 0..1 (ISO 10218-1: 0.25; 0 turns the monitor off)",
        )
        margin = self.joint_limit_margin_rad
        require(
            isinstance(margin, int | float) and math.isfinite(margin) and 0.0 <= margin <= 0.2,
            f"{where}.joint_limit_margin_rad",
            f"{margin!r} rad outside 0..0.2",
        )
        for name, lo, hi, unit in (
            ("standstill_settle_s", 0.0, 10.0, "s"),
            ("standstill_band_rad", 0.0, 0.5, "rad"),
            ("bus_error_window_s", 0.0, 60.0, "s"),
            ("lost_cycles_window_s", 0.0, 60.0, "s"),
        ):
            value = getattr(self, name)
            require(
                isinstance(value, int | float) and math.isfinite(value) and lo < value <= hi,
                f"{where}.{name}",
                f"{value!r} {unit} outside ({lo}, {hi}]",
            )
        speed = self.feedback_max_joint_speed_rad_s
        require(
            isinstance(speed, int | float) and math.isfinite(speed) and 0.0 <= speed <= 1000.0,
            f"{where}.feedback_max_joint_speed_rad_s",
            f"{speed!r} rad/s outside 0..1000 (0 turns the check off)",
        )
        require_count(
            self.standstill_confirm_cycles, f"{where}.standstill_confirm_cycles", 1000, "cycles"
        )
        require(
            self.standstill_confirm_cycles >= 1,
            f"{where}.standstill_confirm_cycles",
            "must be at least 1",
        )
        require_count(self.bus_error_limit, f"{where}.bus_error_limit", 10_000, "frames")
        require(self.bus_error_limit >= 1, f"{where}.bus_error_limit", "must be at least 1")
        for name in ("lost_cycles_max_consecutive", "lost_cycles_max_per_window"):
            require_count(getattr(self, name), f"{where}.{name}", 100_000, "cycles")
        require(
            self.lost_cycle_answer in (COAST_ANSWER, HOLD_ANSWER),
            f"{where}.lost_cycle_answer",
            f"{self.lost_cycle_answer!r} is neither {COAST_ANSWER!r} nor {HOLD_ANSWER!r}",
        )
        require_count(self.coast_max_cycles, f"{where}.coast_max_cycles", 10, "cycles")
        require(self.coast_max_cycles >= 1, f"{where}.coast_max_cycles", "must be at least 1")
        for name in ("current_zero_cycles", "current_zero_settle_cycles"):
            require_count(getattr(self, name), f"{where}.{name}", 100_000, "cycles")
        require(
            math.isfinite(self.answer_by_period_fraction)
            and 0.0 < self.answer_by_period_fraction <= 1.0,
            f"{where}.answer_by_period_fraction",
            f"{self.answer_by_period_fraction!r} outside (0, 1]",
        )
        require(
            math.isfinite(self.lockstep_answer_wait_s)
            and 0.0 <= self.lockstep_answer_wait_s <= LOCKSTEP_ANSWER_WAIT_MAX_S,
            f"{where}.lockstep_answer_wait_s",
            f"{self.lockstep_answer_wait_s!r} s outside 0..{LOCKSTEP_ANSWER_WAIT_MAX_S}",
        )
        require(
            self.lockstep_answer_wait_s == 0.0
            or self.transport.get("interface") == VIRTUAL_INTERFACE,
            f"{where}.lockstep_answer_wait_s",
            f"{self.lockstep_answer_wait_s} s needs the lock-step virtual controller (transport "
            f"{VIRTUAL_INTERFACE!r}); a real controller does not wait for an answer: set it to 0",
        )
        require(
            self.lockstep_answer_wait_s == 0.0 or self.adapter != "cia402",
            f"{where}.lockstep_answer_wait_s",
            "CiA 402 drives are clocked by the host's SYNC and never wait for an answer: "
            "set it to 0",
        )
        for name in ("max_following_error_rad", "max_velocity_rad_s", "stop_deceleration_rad_s2"):
            object.__setattr__(self, name, self._per_joint(name, getattr(self, name)))

    def _per_joint(self, name: str, value: float | tuple[float, ...]) -> tuple[float, ...]:
        if isinstance(value, int | float):
            values = (float(value),) * self.joints
        else:
            values = tuple(float(v) for v in value)
        require(
            len(values) == self.joints,
            f"[can].{name}",
            f"has {len(values)} values for {self.joints} joints",
        )
        for k, v in enumerate(values):
            require(
                math.isfinite(v) and v > 0, f"[can].{name}[{k}]", f"{v!r} must be finite and > 0"
            )
        return values

    @staticmethod
    def _check_transport(t: dict[str, Any]) -> None:
        where = "[can].transport"
        interface = t.get("interface")
        require(
            interface in TRANSPORT_INTERFACES,
            f"{where}.interface",
            f"{interface!r}: the CAN driver speaks only 'socketcan' (the cell) and 'seqpacket' "
            "(the virtual controller)",
        )
        for key, value in t.items():
            require(
                isinstance(value, _TRANSPORT_SCALARS),
                f"{where}.{key}",
                f"{value!r} must be a string, number or boolean",
            )
        require(
            isinstance(t.get("channel"), str) and bool(t.get("channel")),
            f"{where}.channel",
            f"{t.get('channel')!r}: name the CAN channel, e.g. 'can0' or 'vcan0'",
        )
        if interface == "seqpacket":
            unknown = sorted(set(t) - set(_SEQPACKET_KEYS))
            require(
                not unknown, where, f"seqpacket takes only {list(_SEQPACKET_KEYS)}, not {unknown}"
            )
            problem = address_problem(t["channel"])
            require(not problem, f"{where}.channel", problem)
            require(
                isinstance(t.get("fd", False), bool),
                f"{where}.fd",
                f"{t.get('fd')!r}: true or false",
            )
            timeout = t.get("connect_timeout_s", 0.0)
            require(
                isinstance(timeout, int | float)
                and not isinstance(timeout, bool)
                and 0.0 <= timeout <= 60.0,
                f"{where}.connect_timeout_s",
                f"{timeout!r} s outside 0..60",
            )


def load_can_config(cell_config_path: str | Path) -> tuple[CanDriverConfig, BusConfig]:
    """The ``[can]`` and ``[bus]`` sections of a cell config file (absent sections: defaults)."""
    doc = load_toml(cell_config_path)
    bus_cfg = bus_config_from(doc, str(cell_config_path))  # first: it refuses an unknown section
    can_cfg = from_mapping(CanDriverConfig, doc.get("can", {}), f"{cell_config_path} [can]")
    if can_cfg.current_zero_file:
        zero_file = resolve_path(cell_config_path, can_cfg.current_zero_file)
        can_cfg = dataclasses.replace(can_cfg, current_zero_file=str(zero_file))
    if can_cfg.cia402.eds:
        eds = str(resolve_path(cell_config_path, can_cfg.cia402.eds))
        can_cfg = dataclasses.replace(can_cfg, cia402=dataclasses.replace(can_cfg.cia402, eds=eds))
    return can_cfg, bus_cfg


#: the ``[can]`` section of the cell config, registered in pyproject.toml; the gateway checks
#: it before it starts the driver
CELL_SECTION = CellSection(
    "can", lambda path, raw: load_can_config(path), CanDriverConfig, order=3, checked_at_start=True
)
