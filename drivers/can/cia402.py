"""CiA 402 servo drives over CANopen: ``[can] adapter = "cia402"``, settings in ``[can.cia402]``.

The other shape of a closed velocity loop on CAN: one CANopen node per joint, speaking the CiA 402
drive profile in cyclic synchronous position (CSP) or velocity (CSV) mode, each drive closing its
own PI velocity loop with gains the host never sees (the paper's situation). Here the *host*
clocks the cycle: it is the SYNC producer and the NMT master.

Start-up (:meth:`Cia402Adapter.start`, the ``canopen`` library's SDO client and PDO maps, on the
driver's bus before its loop reads it): NMT reset communication and every drive's boot-up; the
device type (402) and the units (0x608F encoder, 0x6091 gear ratio, 0x6075 rated current)
checked against ``[can.cia402]``; heartbeats both ways (0x1017 producer, 0x1016 consumer of the
host's), 0x6007 abort connection option (3: quick stop when the host goes silent), 0x1006
cycle period, 0x6060 mode; the process data mapped by SDO:

========  ==============  ======================================================  ==========
PDO       COB-ID          mapped objects                                          direction
========  ==============  ======================================================  ==========
RPDO1     0x200 + node    0x6040 controlword, 0x607A target position              host→drive
RPDO2     0x300 + node    0x60B1 velocity offset (CSP) / 0x60FF target velocity   host→drive
TPDO1     0x180 + node    0x6041 statusword, 0x6064 position actual               drive→host
TPDO2     0x280 + node    0x606C velocity actual, 0x6078 current, 0x6077 torque   drive→host
========  ==============  ======================================================  ==========

all synchronous (transmission type 1); then ``[can.cia402].startup_sdo``, the writes the drive's
vendor documents in the manufacturer-specific area (the virtual drives': 0x2010 = 1, the
current as the communication cycle's mean, which the laws' inner-loop model reads it as); then
NMT start. In CSP the standard's feed-forward for
the drive's position loop is the velocity offset 0x60B1, which is what the paper's eq. (19)
takes besides the position; 0x60FF is the target of CSV.

Each cycle: the driver sends SYNC (:meth:`Cia402Adapter.clock_frames`); every drive answers
with its two TPDOs, sampled at the SYNC; once all joints' have come :meth:`Cia402Adapter.feed`
returns the cycle; the host's RPDOs answer it and take effect at the next SYNC. The controlword
in RPDO1 walks each drive through the standard's state machine towards what the host requested
(:func:`~drivers.can.cia402_states.controlword_for`, transition numbers as in the standard);
requests that cannot move the arm (BRAKE, a drive in fault or quick stop) win over commands.
"""

from __future__ import annotations

import logging
import math
import struct
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, ClassVar

import can
import numpy as np

from drivers.can.adapter import CanAdapter, CycleFeedback, HostRequest
from drivers.can.cia402_states import DriveState, controlword_for, decode_state
from drivers.can.config import Cia402Config
from drivers.can.ltc import command_arrays
from gateway.errors import ConfigError, FrameError, LinkTimeoutError
from gateway.messages import ControllerState

log = logging.getLogger(__name__)
S = DriveState

SYNC_COB_ID = 0x080
DEVICE_TYPE_402 = 402  #: the low word of 0x1000 of a CiA 402 drive
MODES = {"csp": 8, "csv": 9}  #: 0x6060 modes of operation
NMT_OPERATIONAL = 0x05  #: the state byte of an operational node's heartbeat
#: a drive whose heartbeat is this many of its periods (0x1017) late is lost (the host's side
#: of the heartbeat watch; the drives watch the host's with 0x1016)
HEARTBEAT_LATE_FACTOR = 3.0
#: Completed cycles after a request that takes the drives out of operation (BRAKE,
#: RESET_FAULT) in which a drive leaving operation enabled is obeying it, not dropping out on
#: its own: the request's controlword goes out at once, the drive acts on it at the next SYNC
#: and that cycle's TPDO1 reports it (one cycle; two when the RPDO1 missed its SYNC; a third
#: for a late TPDO1). Without it an operator's stop and start within a cycle (a BRAKE, then a
#: SERVO_ON before the drives' answer to the BRAKE came in) read that answer as a drop-out
#: and latched a controller FAULT (seen on the CiA 402 demo on one loaded core, 2026-11-29).
HOST_DISABLE_CYCLES = 3


@dataclass
class _Pdo:
    """One mapped PDO: its COB-ID and the struct its mapped objects pack into."""

    cob_id: int
    layout: struct.Struct
    objects: tuple[int, ...]


def _layout(pdo_map: Any, what: str) -> _Pdo:
    """The packing of a canopen PDO map (byte-aligned objects, in map order)."""
    fmt = "<"
    objects = []
    for var in pdo_map.map:
        if var.length % 8 or (var.offset or 0) % 8:
            raise ConfigError(f"{what}: object 0x{var.index:04X} is not byte-aligned")
        fmt += var.od.STRUCT_TYPES[var.od.data_type].format[-1]
        objects.append(int(var.index))
    layout = struct.Struct(fmt)
    if layout.size > 8:
        raise ConfigError(f"{what}: {layout.size} bytes do not fit a classic CAN frame")
    return _Pdo(int(pdo_map.cob_id), layout, tuple(objects))


@dataclass
class _Joint:
    """What the host knows of one drive."""

    node_id: int
    inc_per_rad: float  #: position increments per joint radian
    amps_per_mille: float  #: current of one per mille of the rated current [A]
    rpdo1: _Pdo
    rpdo2: _Pdo
    tpdo1: _Pdo
    tpdo2: _Pdo
    state: DriveState = S.NOT_READY_TO_SWITCH_ON
    nmt_state: int = -1  #: state byte of its newest heartbeat (-1: none yet)
    heartbeat_s: float | None = None  #: when its newest heartbeat came (monotonic) [s]
    emergency: str = ""  #: the newest EMCY error code, as text
    last_target_inc: int | None = None  #: the target position it was last sent
    position_inc: int = 0  #: its newest position actual value


def _write_startup_sdo(node: Any, where: str, index: int, subindex: int, value: int) -> None:
    """One ``[can.cia402].startup_sdo`` write to ``node`` (a canopen RemoteNode), typed by its
    EDS; ConfigError naming the entry when the EDS lacks it, its type cannot hold the value or
    the drive refuses it."""
    from canopen.objectdictionary import ODVariable
    from canopen.sdo import SdoAbortedError

    entry = f"{where}: [can.cia402].startup_sdo 0x{index:04X} sub {subindex} = {value}"
    try:
        obj = node.object_dictionary[index]
        if isinstance(obj, ODVariable):
            if subindex != 0:
                raise KeyError(subindex)
            variable = node.sdo[index]
        else:
            obj[subindex]  # KeyError when the EDS has no such sub-index
            variable = node.sdo[index][subindex]
    except KeyError:
        raise ConfigError(f"{entry}: the drive's EDS has no such object") from None
    try:
        variable.raw = value
    except (struct.error, ValueError, TypeError) as exc:
        raise ConfigError(f"{entry}: not a value of the object's type ({exc})") from None
    except SdoAbortedError as exc:
        raise ConfigError(f"{entry}: the drive refused it: {exc}") from None


class Cia402Adapter(CanAdapter):
    """CiA 402 drives (one CANopen node per joint), host-clocked by SYNC."""

    name: ClassVar[str] = "cia402"
    counter_modulus: ClassVar[int] = 1 << 16
    max_joints: ClassVar[int] = 16
    #: the drives' consumer heartbeat time of the host; per instance (from the config)
    host_heartbeat_timeout_s: float = 0.1

    def __init__(
        self, n_joints: int, config: Cia402Config, clock: Callable[[], float] = time.monotonic
    ) -> None:
        super().__init__(n_joints)
        self._clock = clock
        if not 1 <= n_joints <= self.max_joints:
            raise ConfigError(f"[can].joints: CiA 402 adapter carries 1..16 joints, not {n_joints}")
        config.check_joints(n_joints)
        self.config = config
        self.node_ids = config.ids(n_joints)
        self.clock_period_s = config.cycle_period_s
        self.host_heartbeat_timeout_s = config.consumer_heartbeat_s
        self._joints: list[_Joint] = []
        self._by_cob: dict[int, tuple[int, str]] = {}
        self._request = HostRequest.BRAKE
        #: why a drive left operation enabled on its own (a quick stop on a lost heartbeat,
        #: a fault): latched, reported as a controller FAULT, never undone by SERVO_ON (only
        #: by an explicit RESET_FAULT, the operator's reset)
        self._dropped = ""
        #: ``stats.cycles`` when the last request other than SERVO_ON was made
        #: (:data:`HOST_DISABLE_CYCLES`); None before any
        self._disabled_at_cycle: int | None = None
        self._sync_count = 0
        self._tp1: list[tuple[int, ...] | None] = [None] * n_joints
        self._tp2: list[tuple[int, ...] | None] = [None] * n_joints
        self._corrupt = False

    @classmethod
    def from_config(cls, config: Any) -> Cia402Adapter:
        return cls(n_joints=config.joints, config=config.cia402)

    # --- start-up ------------------------------------------------------------------------

    def start(self, bus: can.BusABC) -> None:
        """NMT start-up and the drives' configuration by SDO (module docstring)."""
        import canopen
        from canopen.sdo import SdoAbortedError, SdoCommunicationError

        cfg = self.config
        # canopen logs every SDO and PDO map entry at INFO: hundreds of lines per start-up.
        logging.getLogger("canopen").setLevel(logging.WARNING)
        network = canopen.Network(bus)
        booted: set[int] = set()
        booted_changed = threading.Condition()

        def on_boot_up(cob_id: int, data: bytearray, _stamp: float) -> None:
            if bytes(data) == b"\x00":
                with booted_changed:
                    booted.add(cob_id - 0x700)
                    booted_changed.notify_all()

        notifier = can.Notifier(bus, network.listeners, 0.05)
        try:
            nodes = []
            for nid in self.node_ids:
                node = canopen.RemoteNode(nid, cfg.eds)
                node.sdo.RESPONSE_TIMEOUT = cfg.sdo_timeout_s
                network.add_node(node)
                network.subscribe(0x700 + nid, on_boot_up)
                nodes.append(node)
            network.nmt.send_command(0x82)  # reset communication: every drive boots up again
            with booted_changed:
                booted_changed.wait_for(
                    lambda: booted >= set(self.node_ids), timeout=cfg.boot_timeout_s
                )
                missing = sorted(set(self.node_ids) - booted)
            if missing:
                raise LinkTimeoutError(
                    f"CiA 402 drive node(s) {missing} did not boot up within "
                    f"{cfg.boot_timeout_s:g} s after NMT reset communication"
                )
            joints = [self._configure(k, node) for k, node in enumerate(nodes)]
            network.nmt.send_command(0x01)  # start remote node: process data flows
        except SdoCommunicationError as exc:
            raise LinkTimeoutError(f"CiA 402 start-up: an SDO went unanswered: {exc}") from None
        except SdoAbortedError as exc:
            raise ConfigError(f"CiA 402 start-up: a drive refused an SDO: {exc}") from None
        finally:
            notifier.stop(0.5)
            for nid in self.node_ids:
                network.unsubscribe(0x700 + nid, on_boot_up)
        self._attach(joints)
        log.info(
            "CiA 402 drives %s operational: %s, SYNC every %.1f ms, heartbeat watch %.0f ms",
            list(self.node_ids),
            cfg.mode.upper(),
            cfg.cycle_period_s * 1e3,
            cfg.consumer_heartbeat_s * 1e3,
        )

    def _attach(self, joints: list[_Joint]) -> None:
        """Take the configured drives: their PDOs' COB-IDs route the frames :meth:`feed` gets."""
        self._joints = joints
        self._by_cob = {}
        for k, j in enumerate(self._joints):
            self._by_cob[j.tpdo1.cob_id] = (k, "tpdo1")
            self._by_cob[j.tpdo2.cob_id] = (k, "tpdo2")
            self._by_cob[0x700 + j.node_id] = (k, "heartbeat")
            self._by_cob[0x080 + j.node_id] = (k, "emcy")

    def _configure(self, k: int, node: Any) -> _Joint:
        cfg, nid = self.config, node.id
        where = f"CiA 402 drive node {nid} (J{k + 1})"
        device_type = int(node.sdo[0x1000].raw)
        if device_type & 0xFFFF != DEVICE_TYPE_402:
            raise ConfigError(f"{where}: device type 0x{device_type:08X} is not a CiA 402 drive")
        enc = node.sdo[0x608F]
        increments = int(enc[1].raw) / max(int(enc[2].raw), 1)
        gear = node.sdo[0x6091]
        ratio = int(gear[1].raw) / max(int(gear[2].raw), 1)
        rated_a = int(node.sdo[0x6075].raw) / 1000.0
        for what, got, want in (
            ("0x608F encoder increments per motor revolution", increments, cfg.encoder_increments),
            ("0x6091 gear ratio", ratio, cfg.gear_ratio[k]),
            ("0x6075 rated current [A]", rated_a, cfg.rated_current_a[k]),
        ):
            if not math.isclose(got, want, rel_tol=1e-6):
                raise ConfigError(
                    f"{where}: {what} is {got:g} on the drive but {want:g} in [can.cia402]: "
                    "the units would be wrong; fix the config or the drive's parameters"
                )
        node.sdo[0x6007].raw = cfg.abort_connection_option
        node.sdo[0x1017].raw = round(cfg.producer_heartbeat_s * 1e3)
        node.sdo[0x1016][1].raw = (cfg.host_node_id << 16) | round(cfg.consumer_heartbeat_s * 1e3)
        node.sdo[0x1006].raw = round(cfg.cycle_period_s * 1e6)
        node.sdo[0x6060].raw = MODES[cfg.mode]
        node.rpdo.read()
        node.tpdo.read()
        velocity_object = 0x60B1 if cfg.mode == "csp" else 0x60FF
        layouts = {
            ("rpdo", 1): (0x200, (0x6040, 0x607A)),
            ("rpdo", 2): (0x300, (velocity_object,)),
            ("tpdo", 1): (0x180, (0x6041, 0x6064)),
            ("tpdo", 2): (0x280, (0x606C, 0x6078, 0x6077)),
        }
        for kind, maps in (("rpdo", node.rpdo), ("tpdo", node.tpdo)):
            for number, pdo_map in maps.map.items():
                pdo_map.clear()
                if (kind, number) in layouts:
                    base, objects = layouts[(kind, number)]
                    for index in objects:
                        pdo_map.add_variable(index)
                    pdo_map.cob_id = base + nid
                    pdo_map.trans_type = 1
                    pdo_map.enabled = True
                else:
                    pdo_map.enabled = False
            maps.save()
        for index, subindex, value in cfg.startup_sdo:
            _write_startup_sdo(node, where, index, subindex, value)
        mode_shown = int(node.sdo[0x6061].raw)
        if mode_shown != MODES[cfg.mode]:
            raise ConfigError(f"{where}: 0x6061 shows mode {mode_shown}, not {cfg.mode}")
        inc_per_rad = cfg.encoder_increments * cfg.gear_ratio[k] / (2.0 * math.pi)
        return _Joint(
            node_id=nid,
            inc_per_rad=inc_per_rad,
            amps_per_mille=cfg.rated_current_a[k] / 1000.0,
            rpdo1=_layout(node.rpdo[1], f"{where} RPDO1"),
            rpdo2=_layout(node.rpdo[2], f"{where} RPDO2"),
            tpdo1=_layout(node.tpdo[1], f"{where} TPDO1"),
            tpdo2=_layout(node.tpdo[2], f"{where} TPDO2"),
        )

    # --- the cycle -----------------------------------------------------------------------

    def clock_frames(self) -> list[can.Message]:
        if any(t is not None for t in self._tp1) or any(t is not None for t in self._tp2):
            self.stats.incomplete_cycles += 1
            self.stats.last_error = "a SYNC went out before every drive had answered the last"
        self._tp1 = [None] * self.n_joints
        self._tp2 = [None] * self.n_joints
        self._corrupt = False
        self._sync_count = (self._sync_count + 1) % self.counter_modulus
        return [can.Message(arbitration_id=SYNC_COB_ID, data=b"", is_extended_id=False)]

    def feed(self, msg: can.Message) -> CycleFeedback | None:
        self.stats.frames += 1
        if msg.is_error_frame or msg.is_remote_frame or msg.is_extended_id:
            self.stats.bad_frames += 1
            self.stats.last_error = "error, remote or extended frame"
            return None
        slot = self._by_cob.get(msg.arbitration_id)
        if slot is None:
            self.stats.unknown_frames += 1
            return None
        k, kind = slot
        joint = self._joints[k]
        data = bytes(msg.data)
        if kind == "heartbeat":
            joint.nmt_state = data[0] & 0x7F if data else -1
            joint.heartbeat_s = self._clock()
            return None
        if kind == "emcy":
            code = int.from_bytes(data[:2], "little") if len(data) >= 2 else 0
            joint.emergency = f"EMCY 0x{code:04X}" if code else ""
            return None
        pdo = joint.tpdo1 if kind == "tpdo1" else joint.tpdo2
        if len(data) != pdo.layout.size:
            self.stats.bad_frames += 1
            self.stats.last_error = (
                f"{kind.upper()} of node {joint.node_id}: {len(data)} bytes, "
                f"expected {pdo.layout.size}"
            )
            self._corrupt = True
            return None
        values = pdo.layout.unpack(data)
        if kind == "tpdo1":
            self._tp1[k] = values
        else:
            self._tp2[k] = values
        if any(t is None for t in self._tp1) or any(t is None for t in self._tp2):
            return None
        return self._complete()

    def _complete(self) -> CycleFeedback | None:
        tp1, tp2 = self._tp1, self._tp2
        self._tp1 = [None] * self.n_joints
        self._tp2 = [None] * self.n_joints
        if self._corrupt:
            self.stats.corrupt_cycles += 1
            self._corrupt = False
            return None
        n = self.n_joints
        q, dq, amps = np.empty(n), np.empty(n), np.empty(n)
        faults = []
        now = self._clock()
        #: a drive's heartbeat (0x1017) is late past this: the host's consumer side
        heartbeat_limit_s = HEARTBEAT_LATE_FACTOR * self.config.producer_heartbeat_s
        for k, j in enumerate(self._joints):
            statusword, position = tp1[k]  # type: ignore[misc]
            velocity, current, _torque = tp2[k]  # type: ignore[misc]
            was, j.state = j.state, decode_state(statusword)
            if (
                was == S.OPERATION_ENABLED
                and j.state != S.OPERATION_ENABLED
                and self._request == HostRequest.SERVO_ON
                and not self._dropped
                and (
                    self._disabled_at_cycle is None
                    or self.stats.cycles - self._disabled_at_cycle >= HOST_DISABLE_CYCLES
                )
            ):
                self._dropped = f"J{k + 1} left operation enabled on its own ({j.state.value})"
                log.error("CiA 402: %s; latched until a fault reset", self._dropped)
            j.position_inc = position
            q[k] = position / j.inc_per_rad
            dq[k] = velocity / j.inc_per_rad
            amps[k] = current * j.amps_per_mille
            if j.state in (S.FAULT, S.FAULT_REACTION_ACTIVE):
                faults.append(f"J{k + 1} {j.state.value}{' ' + j.emergency if j.emergency else ''}")
            elif j.state == S.QUICK_STOP_ACTIVE:
                faults.append(f"J{k + 1} quick stop")
            elif j.nmt_state not in (-1, NMT_OPERATIONAL):
                faults.append(f"J{k + 1} NMT state 0x{j.nmt_state:02X}")
            elif j.heartbeat_s is not None and now - j.heartbeat_s > heartbeat_limit_s:
                faults.append(f"J{k + 1} heartbeat lost ({now - j.heartbeat_s:.2f} s)")
        states = [j.state for j in self._joints]
        enabled = all(s == S.OPERATION_ENABLED for s in states)
        if self._dropped:
            faults.insert(0, self._dropped)
        if faults:
            controller_state = ControllerState.FAULT
        elif enabled:
            controller_state = ControllerState.EXTERNAL
        else:
            controller_state = ControllerState.BRAKED
        self.stats.cycles += 1
        return CycleFeedback(
            counter=self._sync_count,
            q_rad=q,
            dq_rad_s=dq,
            current_a=amps,
            controller_state=controller_state,
            estop_active=False,
            servo_power=enabled or any(s == S.QUICK_STOP_ACTIVE for s in states),
            fault="; ".join(faults) if faults else "NONE",
            cycle_period_s=self.config.cycle_period_s,
            status={f"J{k + 1}": s.value for k, s in enumerate(states)},
        )

    def _controlword(self, k: int) -> int:
        request = self._request
        if request == HostRequest.SERVO_ON and self._dropped:
            request = HostRequest.BRAKE
        if request == HostRequest.SERVO_ON and any(
            j.state in (S.FAULT, S.FAULT_REACTION_ACTIVE, S.QUICK_STOP_ACTIVE) for j in self._joints
        ):
            request = HostRequest.BRAKE  # one axis stopping stops them all
        return controlword_for(self._joints[k].state, request)[0]

    def _rpdo1(self, k: int, target_inc: int) -> can.Message:
        j = self._joints[k]
        j.last_target_inc = target_inc
        return can.Message(
            arbitration_id=j.rpdo1.cob_id,
            data=j.rpdo1.layout.pack(self._controlword(k), target_inc),
            is_extended_id=False,
        )

    def command_frames(
        self, counter: int, q_cmd_rad: np.ndarray, dq_cmd_rad_s: np.ndarray, hold: bool
    ) -> list[can.Message]:
        q, dq = command_arrays(q_cmd_rad, dq_cmd_rad_s, self.n_joints, "CiA 402 RPDO set")
        if hold:
            dq = np.zeros(self.n_joints)
        frames = []
        for k, j in enumerate(self._joints):
            pos, vel = q[k] * j.inc_per_rad, dq[k] * j.inc_per_rad
            if not (math.isfinite(pos) and math.isfinite(vel)) or max(abs(pos), abs(vel)) >= 2**31:
                raise FrameError(
                    f"CiA 402 J{k + 1}: command {q[k]:g} rad, {dq[k]:g} rad/s does not fit int32"
                )
            frames.append(self._rpdo1(k, round(pos)))
            frames.append(
                can.Message(
                    arbitration_id=j.rpdo2.cob_id,
                    data=j.rpdo2.layout.pack(round(vel)),
                    is_extended_id=False,
                )
            )
        return frames

    def request_frames(self, request: HostRequest) -> list[can.Message]:
        """Remember ``request`` (every RPDO1 carries the controlword towards it) and send each
        drive its controlword now, with the target it was last sent (its position, if none):
        a request never moves the setpoint."""
        if request == HostRequest.RESET_FAULT and self._dropped:
            log.info("CiA 402: fault reset clears: %s", self._dropped)
            self._dropped = ""
        if request != HostRequest.SERVO_ON:
            self._disabled_at_cycle = self.stats.cycles
        self._request = request
        frames = []
        for k, j in enumerate(self._joints):
            target = j.position_inc if j.last_target_inc is None else j.last_target_inc
            frames.append(self._rpdo1(k, target))
        return frames

    def heartbeat_frame(self) -> can.Message:
        return can.Message(
            arbitration_id=0x700 + self.config.host_node_id,
            data=bytes([NMT_OPERATIONAL]),
            is_extended_id=False,
        )

    def is_cycle_frame(self, msg: can.Message) -> bool:
        slot = self._by_cob.get(msg.arbitration_id)
        return slot is not None and slot[1].startswith("tpdo")
