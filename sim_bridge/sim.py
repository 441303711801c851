"""`leadthrough sim`: the virtual robot cell.

Runs the MuJoCo plant with the vendor's inner loop, and exposes the same endpoints as the real
cell: a CAN segment speaking LTC-1 and a Modbus TCP server for pressures, valves and safety
inputs. This kernel has no SocketCAN, so CAN is served (``[endpoints].can_interface``) either on
a Unix SOCK_SEQPACKET socket (``seqpacket``, the default: binary SocketCAN frames, lossless,
ordered, CAN FD capable, serviced by this loop) or as a socketcand TCP server (``socketcand``,
for a host on another machine).

Each controller cycle: apply the command set that arrived during the previous cycle, run the
physics substeps (inner loop at every substep), send JOINT_FB_J1..Jn then CTRL_STATUS, then wait:
in real time until the cycle's deadline, in lock-step until the command set for this cycle
has arrived (or ``lockstep_timeout_s``), which runs the whole product faster than real time.

Real time keeps absolute deadlines on CLOCK_MONOTONIC: cycle k starts at t0 + k·period. One
thread does everything; between cycles it waits for CAN input with ``select`` and the exact time
left (microseconds: epoll and poll round to whole milliseconds), so it neither spins nor
oversleeps, and it stamps each command set when it arrives.

The truth log (CSV, one row per cycle) records what no product process can see — the tool
position, the operator's force — for the demo and the tests to judge the product by.
"""

from __future__ import annotations

import json
import logging
import math
import threading
import time
from array import array
from pathlib import Path
from typing import Any, TextIO

import can
import numpy as np

from drivers.can.ltc_protocol import LtcProtocolBase
from drivers.can.seqpacket import wait_readable
from gateway.errors import ConfigError
from gateway.messages import ControllerState
from gateway.realtime import apply_scheduling as place
from sim_bridge.can_endpoint import SocketcandServerBus
from sim_bridge.can_hub import SeqpacketHubBus
from sim_bridge.config import Endpoints, Scheduling, SimConfig
from sim_bridge.controller import VirtualController, controller_protocol
from sim_bridge.lockstep_pace import LockstepPace
from sim_bridge.modbus_server import VirtualIoServer
from sim_bridge.operator import Operator
from sim_bridge.plant import Plant

log = logging.getLogger("leadthrough.sim")
#: error classes of an error frame's id, as the host's kernel reports them (linux/can/error.h)
CAN_ERR_BUSOFF, CAN_ERR_RESTARTED = 0x040, 0x100

HEARTBEAT_PERIOD_S = 0.1
# Feedback saturates at the protocol's range, as a real encoder interface would.
Q_FB_LIMIT_RAD = 8.388607
DQ_FB_LIMIT_RAD_S = 3.2767
I_FB_LIMIT_A = 327.67
#: the truth log is flushed every this many cycles
LOG_FLUSH_CYCLES = 25
#: numpy stream of the frame-loss draws, apart from the truth's streams (sim_bridge/truth.py)
FRAME_LOSS_STREAM = 101
#: after an overrun the next cycle still leaves the host at least this long to answer [s]
MIN_ANSWER_WINDOW_S = 0.5e-3


def open_can_endpoint(ep: Endpoints, fd: bool = False) -> can.BusABC:
    """The CAN segment the virtual controller serves, as ``[endpoints]`` chooses it; with CAN FD
    if ``fd`` (the controller's CAN profile needs it) or ``[endpoints].can_fd``."""
    if ep.can_interface == "seqpacket":
        return SeqpacketHubBus(ep.can_channel, fd=fd or ep.can_fd)
    if fd:
        raise ConfigError(
            "[endpoints].can_interface: socketcand carries classic frames only; the CAN FD "
            "profile needs 'seqpacket'"
        )
    return SocketcandServerBus(host=ep.can_host, port=ep.can_port)


def describe_can_endpoint(ep: Endpoints, fd: bool = False) -> str:
    if ep.can_interface == "seqpacket":
        return f"seqpacket {ep.can_channel}" + (" (CAN FD)" if fd or ep.can_fd else "")
    return f"socketcand {ep.can_host}:{ep.can_port}"


def apply_scheduling(sched: Scheduling) -> dict[str, Any]:
    """Apply ``[scheduling]`` to the calling thread; returns what took effect, or why not.

    Refusals are warnings: the loop still runs, with normal priority or on any CPU.
    """
    return place(sched.cpu_affinity, sched.sched_fifo_priority, False, "[scheduling] sim loop")


def truth_log_columns(n: int) -> list[str]:
    cols = ["t_s", "wall_s", "cycle", "ctrl_state", "teaching", "enabling"]
    for name in ("q", "dq", "i"):
        cols += [f"{name}{j + 1}" for j in range(n)]
    cols += ["tool_x", "tool_y", "tool_z", "f_x", "f_y", "f_z", "p2", "p3"]
    cols += ["p2_set", "p3_set", "latency_s"]  # the valves' set-points as received [bar]
    # the position each joint's servo is set to as the row's cycle begins [rad]: the host's
    # command as the controller applies it (NaN with the servo off); at the first row of a
    # command cycle, exactly the position the host sent (within a CiA 402 SYNC the drives'
    # extrapolation of it). What the host sent, not what it says it sent.
    cols += [f"q_ref{j + 1}" for j in range(n)]
    return cols


def reference_at(
    reference: tuple[np.ndarray, np.ndarray, float] | None, now_s: float, n: int
) -> np.ndarray:
    """The truth log's ``q_ref`` [rad]: a servo reference ``(q_r, dq_r, t_r)`` extrapolated to
    ``now_s`` as the inner loop follows it; NaN with no reference (servo off)."""
    if reference is None:
        return np.full(n, np.nan)
    q_r, dq_r, t_r = reference
    return q_r + dq_r * (now_s - t_r)


class VirtualCell:
    def __init__(
        self,
        cfg: SimConfig,
        truth_log: Path | None = None,
        summary_path: Path | None = None,
    ) -> None:
        self.cfg = cfg
        self.plant = Plant(cfg)
        self.n = self.plant.n
        self.proto, self.ctrl = self._make_controller()
        self.operator = Operator(cfg.operator)
        self.plant.hand = self.operator.hand
        self.period_s = cfg.controller.cycle_period_s
        self.substeps = round(self.period_s / cfg.timestep_s)
        self.truth_log_path = truth_log
        self.summary_path = summary_path
        self.stop_event = threading.Event()
        self.estop_open = False  #: scripted e-stop (tests)
        self.bus_off = False  #: scripted bus-off of the host's interface (tests)
        #: [endpoints] can_frame_loss: each frame lost on its own, from the seed's own stream
        self.frame_loss = cfg.endpoints.can_frame_loss
        self._loss_rng = np.random.default_rng([cfg.plant_seed, FRAME_LOSS_STREAM])
        self.frames_lost = {"to_host": 0, "from_host": 0}
        self.latencies_s: list[float] = []
        self.teaching_cycles = 0
        self.teaching_missed = 0
        self.overruns = 0  #: real time: cycles that started late
        self.pace: LockstepPace | None = None  #: lock-step: the plant's pace, once running
        #: real time: how late each cycle started after its deadline [s]
        self.wake_late_s = array("d")
        self.scheduling: dict[str, Any] = {}  #: what [scheduling] achieved
        self._next_heartbeat_s = -math.inf  #: monotonic [s]
        self._fb_sent_wall: float | None = None
        self._set_arrival_wall: float | None = None
        self.can: can.BusABC | None = None
        self.io: VirtualIoServer | None = None
        self._can_fd = cfg.controller.can_profile == "fd"  #: the segment must carry CAN FD
        self._log: TextIO | None = None
        self._row_format = ",".join(["%.9g"] * len(truth_log_columns(self.n))) + "\n"
        #: the feedback frame's range of q, dq and i, (3n,)
        self._fb_limit = np.repeat([Q_FB_LIMIT_RAD, DQ_FB_LIMIT_RAD_S, I_FB_LIMIT_A], self.n)

    def _make_controller(self) -> tuple[LtcProtocolBase, VirtualController]:
        """The vendor controller and the LTC-1 profile it speaks. (The CiA 402 cell,
        sim_bridge/cia402_cell.py, builds its drives instead: see
        :func:`sim_bridge.sim_cli.make_virtual_cell`.)"""
        spec = self.cfg.controller
        if spec.can_profile == "cia402":
            raise ConfigError(
                "[controller].can_profile 'cia402' has no LTC-1 controller: build the cell "
                "with sim_bridge.sim_cli.make_virtual_cell()"
            )
        proto = controller_protocol(spec, self.n)
        return proto, VirtualController(spec, proto, self.plant.lower_rad, self.plant.upper_rad)

    # --- endpoints ----------------------------------------------------------------------
    def open(self) -> None:
        # first: the CAN hub's thread and the I/O module's threads started below inherit it.
        # Lock-step too: its loop waits for the product's every answer, but the product's
        # wall-clock watchdogs do not wait for it, and a loop at normal priority beside a busy
        # machine stalled 1.06 s between two cycles (the gateway faulted on "no fresh joint
        # state from the CAN driver": 3 of 3 identifications beside two busy processes,
        # session 88). The controller it stands for is a computer of its own.
        self.scheduling = apply_scheduling(self.cfg.scheduling)
        ep = self.cfg.endpoints
        self.can = open_can_endpoint(ep, fd=self._can_fd)
        # The valves power up holding the initial pressures: a 0 bar set-point would let the arm
        # sag onto its brakes before the first set-point arrives.
        p2_set, p3_set = self.cfg.cylinders.initial_bar
        self.io = VirtualIoServer(ep.modbus_host, ep.modbus_port, p2_set_bar=p2_set,
                                  p3_set_bar=p3_set)  # fmt: skip
        self.io.start()
        p = self.plant.pressure_bar
        self.io.set_inputs(float(p[0]), float(p[1]), False, True)
        if self.truth_log_path:
            self._log = self.truth_log_path.open("w", buffering=1 << 16)
            self._log.write(",".join(truth_log_columns(self.n)) + "\n")
        log.info(
            "virtual controller up: CAN %s, Modbus %s:%d, %s, cycle %.1f ms",
            describe_can_endpoint(ep, self._can_fd),
            ep.modbus_host,
            ep.modbus_port,
            "real time" if self.cfg.realtime else "lock-step",
            self.period_s * 1e3,
        )

    def close(self) -> None:
        try:
            if self._log:
                self._log.close()
                self._log = None
        finally:
            try:
                if self.can:
                    self.can.shutdown()
            finally:
                if self.io:
                    self.io.close()
        self.write_summary()

    # --- one cycle ----------------------------------------------------------------------
    def _receive(self, timeout_s: float) -> None:
        """Wait up to ``timeout_s`` [s] for CAN input, then take every frame there is."""
        bus = self.can
        assert bus is not None
        # The hub is serviced by this loop and its fileno() says when; the socketcand server
        # has its own I/O thread and queue, so there the loop waits in recv().
        if isinstance(bus, SeqpacketHubBus):  # the hub's queue in one call
            if timeout_s > 0:
                wait_readable(bus.fileno(), timeout_s)
            for msg in bus.drain():
                self._on_frame(msg)
            return
        msg = bus.recv(max(timeout_s, 0.0))
        while msg is not None:
            self._on_frame(msg)
            msg = bus.recv(0.0)

    def _input_waits_for_cycle(self) -> bool:
        """True if the loop may sleep to the next cycle and read the CAN input only then.

        The controller acts on a cycle's commands at the next cycle's start, whenever they
        arrived, and the latency figure uses each frame's arrival stamp (the kernel's, on the
        hub); so with the host's driver the only client of the hub, nothing needs the input
        earlier, and the loop wakes once per cycle instead of once per arriving frame. With
        more clients (a bus monitor, a second node) the hub must forward each frame as it
        comes; the socketcand server reads in its own thread and wakes nobody.
        """
        bus = self.can
        return isinstance(bus, SeqpacketHubBus) and not bus.forwards

    def _lost(self, way: str) -> bool:
        """Whether the segment loses this frame ([endpoints] can_frame_loss); counts it."""
        if self.frame_loss and self._loss_rng.random() < self.frame_loss:
            self.frames_lost[way] += 1
            return True
        return False

    def _send(self, msg: can.Message) -> None:
        assert self.can is not None
        if not self._lost("to_host"):
            self.can.send(msg)

    def _on_frame(self, msg: can.Message) -> None:
        if self.bus_off:
            return  # the host's controller is off the bus: nothing it sends arrives
        if self._lost("from_host"):
            return
        ctrl = self.ctrl
        ctrl.on_frame(msg, time.monotonic())
        if self._set_arrival_wall is None and ctrl.complete_for_cycle == ctrl.cycle:
            self._set_arrival_wall = msg.timestamp  # wall clock, stamped on arrival

    def _bus_off_step(self) -> None:
        """The scripted bus-off (``[operator] bus_off_after_s``): what the host's kernel
        reports, as error frames, when its interface leaves the bus and when it is back."""
        assert self.can is not None
        off = self.operator.bus_off(self.plant.t_s)
        if off != self.bus_off:
            error_class = CAN_ERR_BUSOFF if off else CAN_ERR_RESTARTED
            self.can.send(can.Message(arbitration_id=error_class, is_error_frame=True,
                                      is_extended_id=False, data=bytes(8)))  # fmt: skip
            log.warning("scripted CAN bus-off %s", "begins" if off else "ends (restarted)")
            self.bus_off = off

    def _cycle(self) -> None:
        assert self.can is not None and self.io is not None
        self._bus_off_step()
        plant, ctrl, op = self.plant, self.ctrl, self.operator
        got_set = ctrl.complete_for_cycle == ctrl.cycle and ctrl._new_set is not None
        was_hold = ctrl.complete_hold
        latency = math.nan
        if got_set and not was_hold and self._fb_sent_wall and self._set_arrival_wall:
            latency = self._set_arrival_wall - self._fb_sent_wall
            self.latencies_s.append(latency)
        following = ctrl.state == ControllerState.EXTERNAL and not ctrl.ref_is_hold
        if following:
            self.teaching_cycles += 1
            if not got_set or was_hold:
                self.teaching_missed += 1
        self.estop_open = self.estop_open or op.estop_pressed(plant.t_s)
        ctrl.estop = self.estop_open
        ctrl.begin_cycle(plant.t_s, plant.q_rad, time.monotonic())
        teaching = ctrl.state == ControllerState.EXTERNAL and not ctrl.ref_is_hold
        reference = (ctrl.q_ref, ctrl.dq_ref, ctrl.t_ref) if ctrl.servo_on else None
        q_ref = reference_at(reference, plant.t_s, self.n)  # as the cycle begins
        p_meas, enabling, q_m, dq_m, i_m = self._advance_plant(
            teaching, ctrl.servo_on, reference, ctrl.power_cut
        )
        # what the frame's signals can carry (q, dq, i in one clip)
        fb = np.clip(np.concatenate((q_m, dq_m, i_m)), -self._fb_limit, self._fb_limit)
        n = self.n
        frames = self.proto.feedback_frames(ctrl.status(), fb[:n], fb[n : 2 * n], fb[2 * n :])
        self._set_arrival_wall = None
        for msg in frames if not self.bus_off else ():
            self._send(msg)
        # Wire-to-wire latency runs from the cycle's last feedback frame leaving.
        self._fb_sent_wall = time.time()  # the clock of the frames' arrival stamps
        if self._log:
            # One %-format of plain floats: a third of the cost of formatting each value.
            values = np.concatenate(
                (
                    q_m,
                    dq_m,
                    i_m,
                    plant.tool_position_m(),
                    plant.hand_force_n,
                    p_meas,
                    plant.pressure_set_bar,
                )
            ).tolist()
            self._log.write(
                self._row_format
                % (
                    plant.t_s,
                    time.monotonic(),
                    ctrl.cycle,
                    int(ctrl.state),
                    int(teaching),
                    int(enabling),
                    *values,
                    latency,
                    *q_ref.tolist(),
                )
            )
            if ctrl.cycle % LOG_FLUSH_CYCLES == 0:
                self._log.flush()  # readers (demo, tests) follow the run as it happens

    def _advance_plant(
        self,
        teaching: bool,
        servo_on: bool,
        reference: tuple[np.ndarray, np.ndarray, float] | None,
        power_cut: bool,
    ) -> tuple[np.ndarray, bool, np.ndarray, np.ndarray, np.ndarray]:
        """One cycle of the plant and the I/O module, whatever controller drives it: the
        operator's onset, the plant run towards ``reference`` (None: servo off), the I/O
        module's inputs and set-points. Returns the measured pressures, the enabling device,
        and the measured q, dq and motor currents."""
        assert self.io is not None
        plant, op = self.plant, self.operator
        if teaching:
            op.mark_onset(plant.t_s, plant.tool_position_m())
            if plant.effects.onset_s is None:
                plant.effects.onset_s = plant.t_s
        released = not servo_on and op.brakes_released(plant.t_s)
        if released:
            op.mark_onset(plant.t_s, plant.tool_position_m())
        plant.run(self.substeps, reference, brakes_released=released, power_cut=power_cut)
        if op.s.event_min_speed_m_s > 0:
            op.observe(plant.t_s, plant.tool_position_m())
        p_meas = plant.measured_pressure_bar()
        enabling = op.enabling(plant.t_s)
        self.io.set_inputs(
            float(p_meas[0]), float(p_meas[1]), enabling, not self.estop_open,
            op.mark_pressed(plant.t_s),
        )  # fmt: skip
        plant.pressure_set_bar[:] = self.io.setpoints()
        q_m, dq_m = plant.effects.measured_kinematics(plant.sample_q_rad, plant.sample_dq_rad_s)
        return p_meas, enabling, q_m, dq_m, plant.measured_current_a()

    def _heartbeat(self, now_s: float) -> None:
        assert self.can is not None
        if now_s >= self._next_heartbeat_s and not self.bus_off:
            self._send(self.proto.encode_heartbeat("CTRL", 5))
            self._next_heartbeat_s = now_s + HEARTBEAT_PERIOD_S

    def run(self, duration_s: float | None = None) -> None:
        """Run cycles until ``duration_s`` of simulated time or :meth:`stop`, on the thread
        that called :meth:`open` (which applied ``[scheduling]`` to it)."""
        assert self.can is not None
        self._next_heartbeat_s = -math.inf
        if self.cfg.realtime:
            self._run_realtime(duration_s)
        else:
            self._run_lockstep(duration_s)

    def _run_realtime(self, duration_s: float | None) -> None:
        clock = time.monotonic  # CLOCK_MONOTONIC
        period_s = self.period_s
        late = self.wake_late_s
        t0 = clock()  # cycle k is due at t0 + k·period
        k = 0
        while not self.stop_event.is_set():
            if duration_s is not None and self.plant.t_s >= duration_s:
                break
            self._cycle()
            self._heartbeat(clock())
            k += 1
            deadline = t0 + k * period_s
            now = clock()
            if now > deadline - MIN_ANSWER_WINDOW_S:
                # Overrun. A controller never runs cycles back to back to catch up (the host
                # could not answer them): restart the schedule from now.
                self.overruns += 1
                t0 = now + MIN_ANSWER_WINDOW_S - k * period_s
                deadline = t0 + k * period_s
            if self._input_waits_for_cycle():
                if (left := deadline - clock()) > 0:
                    time.sleep(left)
                self._receive(0.0)
            else:
                while (left := deadline - clock()) > 0:
                    self._receive(left)
            late.append(clock() - deadline)

    def _run_lockstep(self, duration_s: float | None) -> None:
        clock = time.monotonic
        ctrl = self.ctrl
        speedup = self.cfg.lockstep_max_speedup
        # no faster than lockstep_max_speedup × real time (the I/O's sampling, config.py)
        self.pace = LockstepPace(speedup, self.period_s / speedup, clock(), self.plant.t_s)
        while not self.stop_event.is_set():
            if duration_s is not None and self.plant.t_s >= duration_s:
                break
            if (wait := self.pace.wait_s(self.plant.t_s, clock())) > 0:
                self.stop_event.wait(wait)
            self._cycle()
            self._heartbeat(clock())
            deadline = clock() + self.cfg.lockstep_timeout_s
            while (
                ctrl.complete_for_cycle != ctrl.cycle
                and (left := deadline - clock()) > 0
                and not self.stop_event.is_set()
            ):
                self._receive(min(left, 0.01))
            self._receive(0.0)

    def stop(self) -> None:
        self.stop_event.set()

    def summary(self) -> dict:
        lat = np.array(self.latencies_s)
        late = np.array(self.wake_late_s)
        st = self.ctrl.stats

        def pct(p: float, values: np.ndarray = lat) -> float | None:
            return float(np.percentile(values, p)) if values.size else None

        return {
            "sim_time_s": self.plant.t_s,
            "cycles": self.ctrl.cycle,
            "cycle_period_s": self.period_s,
            "command_sets": st.command_sets,
            "hold_sets": st.hold_sets,
            "controller_missed_cycles": st.missed_cycles,
            "late_frames": st.late_frames,
            "bad_frames": st.bad_frames,
            "faults": st.faults,
            "teaching_cycles": self.teaching_cycles,
            "teaching_missed_cycles": self.teaching_missed,
            "overruns": self.overruns,
            "lockstep_pace_restarts": None if self.pace is None else self.pace.restarts,
            "latency_p50_s": pct(50),
            "latency_p99_s": pct(99),
            "latency_p999_s": pct(99.9),
            "latency_max_s": pct(100),
            "latency_samples": len(self.latencies_s),
            "wake_late_p50_s": pct(50, late),
            "wake_late_p99_s": pct(99, late),
            "wake_late_max_s": pct(100, late),
            "plant_seed": self.cfg.plant_seed,
            "can_frame_loss": self.frame_loss,
            "can_frames_lost": dict(self.frames_lost),
            "can_endpoint": describe_can_endpoint(self.cfg.endpoints, self._can_fd),
            "scheduling": self.scheduling,
        }

    def write_summary(self) -> None:
        if self.summary_path:
            self.summary_path.write_text(json.dumps(self.summary(), indent=2))
