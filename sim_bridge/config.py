"""The virtual controller's PRIVATE configuration: the plant's truth.

Nothing outside ``sim_bridge/`` (and the tests that check this) may read these files: they hold
what the real robot keeps to itself — the inner PI gains of eq. (19), the true friction, the
pressure dynamics, and any effect injected to test identification. ``control/`` must get by with
its own declared model and its own copy of ω and Υ_I, as it would on the real cell.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from drivers.can.seqpacket import address_problem
from gateway.config import from_mapping, load_toml, require

DEFAULT_TRUTH = Path(__file__).with_name("gr630st_truth.toml")

#: the names these effects had before they took the identification catalogue's
#: (control/identification/terms.py EFFECT_NAMES): refused, naming the new one
RENAMED_EFFECT_KINDS = {
    "ripple": "position_ripple",
    "load_friction": "load_dependent_friction",
    "delay": "time_delay",
    "drift": "thermal_drift",
    "coupling": "wrist_coupling",
}
EFFECT_KINDS = (
    "payload",  # mass on the last link: mass_kg, com_m [3] in the tool frame
    "spring",  # position-proportional spring: joint, k_nm_per_rad, q0_rad
    "position_ripple",  # position-periodic torque: joint, amplitude_nm, cycles_per_rev, phase_rad
    "stribeck",  # friction transition shape: joint, amplitude_nm, velocity_rad_s
    "load_dependent_friction",  # load-dependent friction: joint, coefficient (|tau_load| fraction)
    "time_delay",  # torque/kinematics time delay at the sensor: delay_s (all joints)
    "thermal_drift",  # slow thermal drift of the torque offset: joint, rate_nm_per_s
    "wrist_coupling",  # wrist cross-coupling: joint, from_joint, coefficient
)


@dataclass(frozen=True)
class InnerLoopTruth:
    """Gains of the vendor's PI velocity loop, eq. (19). Unknown to control/."""

    kp_a_s_per_rad: tuple[float, ...]  #: K_p per joint [A/(rad/s)]
    ki_a_per_rad: tuple[float, ...]  #: K_I per joint [A/rad]

    def __post_init__(self) -> None:
        require(len(self.kp_a_s_per_rad) == len(self.ki_a_per_rad), "[inner_loop]", "lengths")
        require(all(v > 0 for v in self.kp_a_s_per_rad), "[inner_loop].kp_a_s_per_rad", "> 0")
        require(all(v > 0 for v in self.ki_a_per_rad), "[inner_loop].ki_a_per_rad", "> 0")


@dataclass(frozen=True)
class FrictionTruth:
    """True joint friction, eq. (15) (our reading, see control/model/friction.py)."""

    tau_s_nm: float
    tau_c_nm: float
    tau_v1_nm_s_per_rad: float
    q_e_rad_s: float
    tau_v2_nm_s2_per_rad2: float = 0.0
    fourier_nm: tuple[float, float, float, float, float, float] = (0.0,) * 6

    def __post_init__(self) -> None:
        require(self.q_e_rad_s > 0, "[[friction]].q_e_rad_s", f"{self.q_e_rad_s} must be > 0")
        require(self.tau_c_nm >= 0 and self.tau_s_nm >= 0, "[[friction]]", "tau_c, tau_s >= 0")


@dataclass(frozen=True)
class DrivesTruth:
    """The drives: joint-side torque constant, current limit and gear ratio per joint."""

    gain_nm_per_a: tuple[float, ...]  #: K [N·m/A], joint side
    max_current_a: tuple[float, ...]  #: current limit [A]
    gear_ratio: tuple[float, ...]  #: R [-]

    def __post_init__(self) -> None:
        n = len(self.gain_nm_per_a)
        for name in ("gain_nm_per_a", "max_current_a", "gear_ratio"):
            values = getattr(self, name)
            require(len(values) == n, f"[drives].{name}", f"need {n} values, got {len(values)}")
            require(all(v > 0 for v in values), f"[drives].{name}", "every value must be > 0")


@dataclass(frozen=True)
class BrakesTruth:
    """The holding brakes. When the power is cut (the controller's fault or e-stop: stop
    category 0) the arm moves freely for ``engage_s``, then each joint's brake slows it with
    ``torque_nm`` until it stands, and holds it. A servo-off the host asks for closes the
    brakes while the drives still hold (no sag), as a controller does. Empty ``torque_nm``:
    ideal brakes that lock at once (the plant before issue 10)."""

    engage_s: float = 0.0  #: from the power cut to the brake torque [s]
    torque_nm: tuple[float, ...] = ()  #: each joint's brake torque [N·m]

    def __post_init__(self) -> None:
        require(
            math.isfinite(self.engage_s) and 0.0 <= self.engage_s <= 1.0,
            "[brakes].engage_s",
            f"{self.engage_s!r} s outside 0..1",
        )
        require(
            all(math.isfinite(v) and v > 0 for v in self.torque_nm),
            "[brakes].torque_nm",
            "every value must be finite and > 0",
        )


CYLINDER_LINKAGES = ("crank", "lever")


@dataclass(frozen=True)
class CylinderUnit:
    """One assist cylinder's linkage (see ``gr630st_truth.toml``)."""

    joint: int  #: 1-based joint it acts on
    kind: str  #: "crank" (pivot, rod end |AB|, barrel end |AC|) or "lever" (arm |AB|)
    piston_diameter_m: float
    ab_m: float
    sign: float  #: +1/-1: the direction of +q the cylinder's push turns the joint
    ac_m: float = 0.0
    #: the chamber's gas volume at q = 0 as a length of piston area [m] (chamber, hose and
    #: accumulator): the volume grows with the rod's extension, so the pressure drops as the
    #: cylinder extends faster than the regulator refills it; 0: an ideal reservoir
    gas_length_m: float = 0.0

    def __post_init__(self) -> None:
        where = f"[[cylinders.units]] (joint {self.joint})"
        require(
            self.kind in CYLINDER_LINKAGES, where, f"kind {self.kind!r} not in {CYLINDER_LINKAGES}"
        )
        require(self.piston_diameter_m > 0 and self.ab_m > 0, where, "sizes must be > 0")
        require(self.sign in (1.0, -1.0), where, "sign must be +1 or -1")
        require(self.kind != "crank" or self.ac_m > 0, where, "a crank needs ac_m > 0")
        require(self.gas_length_m >= 0, where, "gas_length_m must be >= 0")


@dataclass(frozen=True)
class CylinderTruth:
    time_constant_s: float = 0.25  #: first-order lag of pressure towards its set-point
    noise_bar: float = 0.003  #: std of the transmitter noise [bar]
    initial_bar: tuple[float, float] = (6.0, 4.0)
    units: tuple[CylinderUnit, ...] = ()

    def __post_init__(self) -> None:
        require(self.time_constant_s > 0, "[cylinders].time_constant_s", "must be > 0")
        require(
            len(self.units) == len(self.initial_bar),
            "[cylinders].units",
            f"need one linkage per pressure ({len(self.initial_bar)}), got {len(self.units)}",
        )


@dataclass(frozen=True)
class SensorTruth:
    current_noise_a: float = 0.02  #: std of the motor-current measurement noise [A]
    #: motor-side encoder resolution [bits per motor revolution]: the joint position is
    #: reported in steps of 2π / (2^bits · R), the velocity is the drive's difference of
    #: that position over its last servo tick; 0: exact (no encoder)
    encoder_bits: int = 20
    #: per joint, the current sensor's zero offset [A]: every reported current, the servo on
    #: or off, reads this much above the motor's; () none
    current_offset_a: tuple[float, ...] = ()
    #: for a seed > 0, the offset is drawn within ± this fraction of each joint's current
    #: limit (a drive's offset tolerance)
    current_offset_fraction: float = 0.0

    def __post_init__(self) -> None:
        require(self.current_noise_a >= 0, "[sensors].current_noise_a", "must be >= 0")
        require(
            0 <= self.current_offset_fraction <= 0.05,
            "[sensors].current_offset_fraction",
            f"{self.current_offset_fraction} not in 0..0.05",
        )
        require(
            all(math.isfinite(v) for v in self.current_offset_a),
            "[sensors].current_offset_a",
            "must be finite",
        )
        require(
            self.encoder_bits == 0 or 8 <= self.encoder_bits <= 32,
            "[sensors].encoder_bits",
            f"{self.encoder_bits} not 0 or in 8..32",
        )


#: ``[controller].can_profile``: LTC-1 on classic CAN or CAN FD, or CiA 402 drives
CAN_PROFILES = ("classic", "fd", "cia402")


@dataclass(frozen=True)
class ControllerSpec:
    """Public behaviour of the vendor controller (what its manual would say)."""

    cycle_period_s: float = 0.004  #: external-command cycle (feedback and command rate)
    max_missed_cycles: int = 25  #: consecutive cycles without commands before FAULT
    host_heartbeat_timeout_s: float = 0.5
    max_following_error_rad: float = 0.05  #: |q_cmd - q| beyond this → FAULT
    #: cycles between a command set's acceptance and the servo following it. A real controller
    #: reads the joints at a cycle boundary, the host answers during the cycle and the answer
    #: takes effect at a later boundary: 1 (the default) is the physical minimum. 0 applies it
    #: at the boundary that accepted it, in the same simulated instant as the measurement it
    #: answers. The product measures it (the inner-loop experiment) and sends each command for
    #: the state the arm will be in then (control/rt/src/law/delay.rs).
    command_delay_cycles: int = 1
    #: CAN profile of LTC-1 the controller speaks (drivers/can/PROTOCOL.md): "classic" (§2,
    #: JOINT_FB/JOINT_CMD per joint, host adapter "ltc_dbc") or "fd" (§10, one CAN FD frame
    #: each way per cycle, host adapter "ltc_fd"); or "cia402": no vendor controller but one
    #: CANopen CiA 402 drive per joint (sim_bridge/cia402_drives.py), clocked by the host's
    #: SYNC. There cycle_period_s is the drives' servo cycle (the plant's step between
    #: samples), max_missed_cycles the sync watchdog (communication cycles 0x1006 without a
    #: SYNC in Operation enabled), max_following_error_rad the following error limit (0x6065);
    #: the host heartbeat is the drives' 0x1016, command_delay_cycles unused (an RPDO takes
    #: effect at the next SYNC)
    can_profile: str = "classic"
    #: "cia402": node id of joint 1's drive; joint k's is first_node_id + k - 1
    first_node_id: int = 1

    def __post_init__(self) -> None:
        require(
            0.0005 <= self.cycle_period_s <= 0.05,
            "[controller].cycle_period_s",
            f"{self.cycle_period_s} outside 0.0005..0.05 s",
        )
        require(
            0 <= self.command_delay_cycles <= 10,
            "[controller].command_delay_cycles",
            f"{self.command_delay_cycles} outside 0..10",
        )
        require(
            self.can_profile in CAN_PROFILES,
            "[controller].can_profile",
            f"{self.can_profile!r} is neither 'classic', 'fd' nor 'cia402'",
        )
        require(
            1 <= self.first_node_id <= 127,
            "[controller].first_node_id",
            f"{self.first_node_id} outside 1..127",
        )


#: How the virtual controller can serve its CAN segment (``[endpoints].can_interface``).
CAN_ENDPOINT_INTERFACES = (
    # Unix SOCK_SEQPACKET hub (sim_bridge/can_hub.py): this machine only; lossless, ordered,
    # binary SocketCAN frames, CAN FD; serviced by the controller loop itself (no thread).
    "seqpacket",
    # socketcand-protocol TCP server (sim_bridge/can_endpoint.py): for a host on another
    # machine (HIL); classic frames only, ASCII, its own I/O thread.
    "socketcand",
)


@dataclass(frozen=True)
class Endpoints:
    """Where the virtual controller serves CAN and Modbus. The cell config's ``[can.transport]``
    and ``[modbus]`` must point at the same places."""

    can_interface: str = "seqpacket"  #: one of CAN_ENDPOINT_INTERFACES
    #: seqpacket: socket address, "@name" (Linux abstract namespace) or a file path
    can_channel: str = "@leadthrough-vcan0"
    can_fd: bool = False  #: seqpacket: the controller also takes and sends CAN FD frames
    can_host: str = "127.0.0.1"  #: socketcand: TCP address to listen on (channel "vcan0")
    can_port: int = 29536  #: socketcand: TCP port
    modbus_host: str = "127.0.0.1"
    modbus_port: int = 15020
    #: Probability that a frame on the CAN segment is lost, each frame and each way on its own
    #: (feedback and heartbeats to the host, commands and requests from it): a segment whose
    #: frames are corrupted past the CAN controller's retransmission (soak tests; 0: none).
    #: Drawn from the plant seed's own stream.
    can_frame_loss: float = 0.0

    def __post_init__(self) -> None:
        where = "[endpoints]"
        require(
            0.0 <= self.can_frame_loss < 0.5,
            f"{where}.can_frame_loss",
            f"{self.can_frame_loss!r} outside 0..0.5",
        )
        require(
            self.can_interface in CAN_ENDPOINT_INTERFACES,
            f"{where}.can_interface",
            f"{self.can_interface!r} not one of {CAN_ENDPOINT_INTERFACES}",
        )
        if self.can_interface == "seqpacket":
            problem = address_problem(self.can_channel)
            require(not problem, f"{where}.can_channel", problem)
        else:
            require(not self.can_fd, f"{where}.can_fd", "socketcand carries classic frames only")
            require(0 <= self.can_port < 65536, f"{where}.can_port", f"{self.can_port} not a port")
        require(
            0 <= self.modbus_port < 65536, f"{where}.modbus_port", f"{self.modbus_port} not a port"
        )


@dataclass(frozen=True)
class Scheduling:
    """OS scheduling of the controller loop's thread (real-time runs; a lock-step loop runs at
    normal priority) and of the virtual I/O module's process (both). Applied when the OS
    permits it; when it does not, they run anyway and the log and summary say so."""

    #: SCHED_FIFO priority 1..99 of the loop thread (needs CAP_SYS_NICE or an rtprio limit);
    #: 0: normal scheduling
    sched_fifo_priority: int = 0
    #: CPUs the loop thread may run on; empty: any
    cpu_affinity: tuple[int, ...] = ()

    def __post_init__(self) -> None:
        where = "[scheduling]"
        require(
            0 <= self.sched_fifo_priority <= 99,
            f"{where}.sched_fifo_priority",
            f"{self.sched_fifo_priority} outside 0..99 (0 = off)",
        )
        require(
            all(c >= 0 for c in self.cpu_affinity)
            and len(set(self.cpu_affinity)) == len(self.cpu_affinity),
            f"{where}.cpu_affinity",
            f"{list(self.cpu_affinity)}: CPU numbers must be >= 0 and distinct",
        )


@dataclass(frozen=True)
class OperatorScript:
    """The simulated operator. Times after ``onset`` are counted from teaching onset: the first
    control cycle in which the controller follows a non-hold command."""

    enabling_after_s: float = 0.0  #: sim time at which the enabling device is pressed
    release_after_s: float | None = None  #: after onset: enabling released (None: never)
    #: after onset: the operator hits the e-stop, which stays open (None: never)
    estop_after_s: float | None = None
    #: release_after_s and estop_after_s wait, once due, for a cycle in which the tool moves
    #: at least this fast [m/s]: a hand that lets go, or hits the e-stop, in motion (0: at the
    #: time; a tool that never gets this fast is never released)
    event_min_speed_m_s: float = 0.0
    #: after onset: the host's CAN interface goes bus-off for bus_off_s (its kernel then
    #: restarts it, restart-ms): error frames BUSOFF then RESTARTED reach the host, and no
    #: frame passes either way in between (None: never)
    bus_off_after_s: float | None = None
    bus_off_s: float = 0.1
    #: sim time from which the operator holds the brake-release switch (None: never). With
    #: the servo off the arm is then free: it moves under gravity, the cylinders, friction and
    #: the hand (the paper's baseline); the hand's onset is that moment.
    brake_release_after_s: float | None = None
    mode: str = "none"  #: none | force | path
    force_n: tuple[float, float, float] = (0.0, 0.0, 0.0)  #: world frame, mode force
    start_s: float = 0.5  #: after onset: the push starts
    duration_s: float = 2.0  #: push length (mode force)
    ramp_s: float = 0.2  #: force ramp in and out
    #: mode path: [t_s, dx_m, dy_m, dz_m] waypoints from the tool position at onset
    path: tuple[tuple[float, float, float, float], ...] = ()
    hand_stiffness_n_per_m: float = 600.0
    hand_damping_n_s_per_m: float = 80.0
    max_force_n: float = 60.0
    #: after onset: the hand lets go of the tool (the enabling device stays held; None: never)
    hand_off_after_s: float | None = None
    #: after onset: (start, end) windows in which the hand lets go and takes hold again (the
    #: soak benchmark's rests, sim_bridge/soak.py)
    hand_off_windows_s: tuple[tuple[float, float], ...] = ()
    #: after onset: times the teach handle's mark button is pressed, for ``mark_press_s`` each
    mark_at_s: tuple[float, ...] = ()
    mark_press_s: float = 0.2
    #: mode path: the hand's physiological tremor, amplitude per axis [m] and frequency [Hz]
    #: (the axes at 1, 1.13 and 0.87 times it, so the tremor traces no straight line)
    tremor_m: float = 0.0
    tremor_hz: float = 9.0

    def __post_init__(self) -> None:
        require(self.mode in ("none", "force", "path"), "[operator].mode", f"{self.mode!r}")
        require(
            0 <= self.event_min_speed_m_s <= 1.0,
            "[operator].event_min_speed_m_s",
            f"{self.event_min_speed_m_s} not in 0..1 m/s",
        )
        require(
            0 <= self.tremor_m <= 0.01, "[operator].tremor_m", f"{self.tremor_m} not in 0..0.01 m"
        )
        require(
            0 < self.tremor_hz <= 50, "[operator].tremor_hz", f"{self.tremor_hz} not in (0, 50] Hz"
        )
        if self.mode == "path":
            require(len(self.path) >= 2, "[operator].path", "needs at least 2 waypoints")
            times = [w[0] for w in self.path]
            require(times == sorted(times), "[operator].path", "times must increase")
        marks = list(self.mark_at_s)
        require(
            marks == sorted(marks) and all(m >= 0 for m in marks),
            "[operator].mark_at_s",
            f"{marks}: times after onset must be >= 0 and increase",
        )
        require(self.mark_press_s > 0, "[operator].mark_press_s", f"{self.mark_press_s} <= 0")


@dataclass(frozen=True)
class SimConfig:
    inner_loop: InnerLoopTruth
    friction: tuple[FrictionTruth, ...]
    drives: DrivesTruth
    #: the arm's MJCF: absolute, or a file beside this package
    arm_mjcf: str = "gr630st_arm.xml"
    #: 0: the truth as written; N > 0: a plant drawn around it (:mod:`sim_bridge.truth`)
    plant_seed: int = 0
    timestep_s: float = 0.0005  #: physics and inner-loop step [s]
    realtime: bool = True  #: False: lock-step, as fast as the command loop answers
    lockstep_timeout_s: float = 0.25  #: lock-step: wall time to wait for a command set
    #: lock-step: the plant's time runs at most this many times as fast as the wall clock. The
    #: Modbus driver polls the I/O (the cylinders' pressures) at its wall-clock rate, so a plant
    #: running S times as fast is sampled S times as sparsely in its own time: with the compiled
    #: CAN driver's faster answers, commissioning recorded pressures that stale and J3's
    #: cylinder torque came out wrong (held-out 1.37 against 0.69 N·m on seed 0). 1: a cell's
    #: own sampling; lock-step then only waits for a late answer instead of missing it.
    lockstep_max_speedup: float = 1.0
    initial_q_rad: tuple[float, ...] = (0.0,) * 6
    seed: int = 1
    #: dry friction as true stiction (a joint at rest holds up to its static level) instead
    #: of the smooth law that creeps under any torque (:mod:`sim_bridge.physics`)
    stiction: bool = False
    cylinders: CylinderTruth = field(default_factory=CylinderTruth)
    sensors: SensorTruth = field(default_factory=SensorTruth)
    brakes: BrakesTruth = field(default_factory=BrakesTruth)
    controller: ControllerSpec = field(default_factory=ControllerSpec)
    endpoints: Endpoints = field(default_factory=Endpoints)
    #: not ``[realtime]``: ``realtime`` above already chooses real time or lock-step
    scheduling: Scheduling = field(default_factory=Scheduling)
    operator: OperatorScript = field(default_factory=OperatorScript)
    effects: tuple[dict[str, Any], ...] = ()

    def __post_init__(self) -> None:
        n = len(self.inner_loop.kp_a_s_per_rad)
        require(
            len(self.friction) == n, "[[friction]]", f"need {n} joints, got {len(self.friction)}"
        )
        require(len(self.initial_q_rad) == n, "initial_q_rad", f"need {n} values")
        require(
            self.lockstep_max_speedup > 0,
            "lockstep_max_speedup",
            f"{self.lockstep_max_speedup} must be > 0",
        )
        require(
            len(self.drives.gain_nm_per_a) == n, "[drives]", f"need {n} joints like [inner_loop]"
        )
        require(
            len(self.sensors.current_offset_a) in (0, n),
            "[sensors].current_offset_a",
            f"need {n} joints like [inner_loop] (or none)",
        )
        require(
            len(self.brakes.torque_nm) in (0, n),
            "[brakes].torque_nm",
            f"need {n} joints like [inner_loop] (or none: ideal brakes)",
        )
        require(self.plant_seed >= 0, "plant_seed", f"{self.plant_seed} must be >= 0")
        for unit in self.cylinders.units:
            require(1 <= unit.joint <= n, "[[cylinders.units]].joint", f"{unit.joint} not 1..{n}")
        require(0 < self.timestep_s <= 0.002, "timestep_s", f"{self.timestep_s} not in (0, 2 ms]")
        last_node = self.controller.first_node_id + n - 1
        require(
            self.controller.can_profile != "cia402" or last_node <= 127,
            "[controller].first_node_id",
            f"{n} drives from node {self.controller.first_node_id} end at {last_node} > 127",
        )
        ratio = self.controller.cycle_period_s / self.timestep_s
        require(
            abs(ratio - round(ratio)) < 1e-6,
            "[controller].cycle_period_s",
            "must be a whole number of timesteps",
        )
        for i, eff in enumerate(self.effects):
            renamed = RENAMED_EFFECT_KINDS.get(str(eff.get("kind")))
            require(
                renamed is None,
                f"[[effects]][{i}].kind",
                f"{eff.get('kind')!r} is now {renamed!r} (the identification's name for it)",
            )
            require(
                eff.get("kind") in EFFECT_KINDS,
                f"[[effects]][{i}].kind",
                f"{eff.get('kind')!r} not one of {EFFECT_KINDS}",
            )


def arm_mjcf_path(cfg: SimConfig) -> Path:
    """The arm's MJCF file of ``cfg`` (``arm_mjcf``, relative to this package)."""
    p = Path(cfg.arm_mjcf)
    return p if p.is_absolute() else Path(__file__).parent / p


def _overlay(base: dict[str, Any], over: dict[str, Any]) -> dict[str, Any]:
    """``base`` with ``over``'s keys: tables merged key by key, anything else replaced."""
    out = dict(base)
    for key, value in over.items():
        both = isinstance(value, dict) and isinstance(base.get(key), dict)
        out[key] = _overlay(base[key], value) if both else value
    return out


def _load_truth(p: Path, seen: tuple[Path, ...] = ()) -> dict[str, Any]:
    """A truth file; one with ``extends = "other.toml"`` (absolute, or beside this package)
    is that file with its own keys laid over it (tables merged, anything else replaced)."""
    raw = load_toml(p)
    base = raw.pop("extends", None)
    if base is None:
        return raw
    require(isinstance(base, str), f"{p}: extends", f"{base!r} is not a file name")
    b = Path(base) if Path(base).is_absolute() else Path(__file__).parent / base
    require(b.resolve() not in seen, f"{p}: extends", f"{base} extends itself")
    return _overlay(_load_truth(b, (*seen, p.resolve())), raw)


def load_sim_config(
    path: str | Path | None = None, overrides: dict[str, Any] | None = None
) -> SimConfig:
    """Load the truth file (``extends``: see :func:`_load_truth`); ``overrides`` replace
    whole top-level keys (tests, scenarios)."""
    p = Path(path) if path else DEFAULT_TRUTH
    raw = _load_truth(p)
    if overrides:
        raw = {**raw, **overrides}
    return from_mapping(SimConfig, raw, str(p))
