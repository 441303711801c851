"""The virtual cell with CiA 402 joint drives instead of the LTC-1 vendor controller.

Chosen by ``[controller].can_profile = "cia402"`` (``sim_bridge/gr630st_truth_cia402.toml``;
:func:`sim_bridge.sim_cli.make_virtual_cell`). The plant, the Modbus I/O, the operator, the
e-stop chain, the CAN endpoint and the truth log are :class:`~sim_bridge.sim.VirtualCell`'s;
the drives (:mod:`sim_bridge.cia402_drive_set` of :mod:`sim_bridge.cia402_drives`) replace the
vendor controller's protocol and state machine.

The host clocks the communication cycle with SYNC; the cell keeps its own servo cycle
(``[controller].cycle_period_s``, a whole number of physics steps). Each servo cycle the
drives step (state machine, watchdogs, reference), the plant runs the cycle, and the drives
take its measurements; a SYNC is answered as it arrives, with the TPDOs sampled then. So the
loop reads the segment as frames come, not once per cycle. In lock-step a SYNC starts the
next servo cycle (one per SYNC, or one per ``lockstep_timeout_s`` without).

What the loop needs from the vendor controller, the drive set gives: servo power (some drive
in Operation enabled or Quick stop active), the brakes' command (the power off by a fault: a
stop category 0 cut), the reference, a state for the truth log (:func:`controller_state`).
The plant brakes all joints or none, so while only some drives are powered the unpowered
joints are held by their servo where they lost power.
"""

from __future__ import annotations

import math
import time
from typing import Any

import can
import numpy as np

from gateway.messages import ControllerState
from sim_bridge.cia402_drive_set import Cia402DriveSet
from sim_bridge.cia402_parameters import AxisParameters, DriveLimits
from sim_bridge.config import SimConfig
from sim_bridge.sim import LOG_FLUSH_CYCLES, VirtualCell, reference_at

#: the motor encoder the drives report when the plant's is exact ([sensors] encoder_bits 0)
NOMINAL_ENCODER_BITS = 20


def axis_parameters(cfg: SimConfig) -> list[AxisParameters]:
    """Each drive's commissioning parameters from the truth as written (the datasheet: a
    drawn plant's torque constants differ from it, as a real motor's from its nameplate): the
    gear ratio, the current limit as the rated current, and the motor encoder."""
    drives = cfg.drives
    bits = cfg.sensors.encoder_bits or NOMINAL_ENCODER_BITS
    return [
        AxisParameters.for_joint(ratio, current, k, bits)
        for ratio, current, k in zip(
            drives.gear_ratio, drives.max_current_a, drives.gain_nm_per_a, strict=True
        )
    ]


def controller_state(drives: Cia402DriveSet) -> ControllerState:
    """The drive set's state in the truth log's terms: FAULT if a drive faulted, EXTERNAL when
    every drive follows the host, HOLD while some are powered, else BRAKED."""
    if drives.faulted:
        return ControllerState.FAULT
    if drives.following:
        return ControllerState.EXTERNAL
    return ControllerState.HOLD if drives.servo_on else ControllerState.BRAKED


class Cia402Cell(VirtualCell):
    """:class:`~sim_bridge.sim.VirtualCell` with a :class:`Cia402DriveSet` as ``ctrl``."""

    ctrl: Cia402DriveSet  # type: ignore[assignment]

    def _make_controller(self) -> tuple[None, Cia402DriveSet]:  # type: ignore[override]
        spec = self.cfg.controller
        limits = DriveLimits(
            max_following_error_rad=spec.max_following_error_rad,
            sync_timeout_cycles=spec.max_missed_cycles,
        )
        drives = Cia402DriveSet(
            axis_parameters(self.cfg),
            limits,
            self._send_frame,
            lambda: self.plant.t_s,
            first_node_id=spec.first_node_id,
        )
        return None, drives

    def _send_frame(self, msg: can.Message) -> None:
        """A drive's frame onto the segment (lost with the host's interface off the bus)."""
        if not self.bus_off:
            self._send(msg)

    def open(self) -> None:
        super().open()
        self.ctrl.power_on()  # boot-up of every drive

    def _input_waits_for_cycle(self) -> bool:
        return False  # a SYNC is answered when it arrives

    def _heartbeat(self, now_s: float) -> None:
        self.ctrl.heartbeats(now_s)

    def _cycle(self) -> None:
        assert self.can is not None and self.io is not None
        self._bus_off_step()
        plant, drives, op = self.plant, self.ctrl, self.operator
        self.estop_open = self.estop_open or op.estop_pressed(plant.t_s)
        drives.estop = self.estop_open
        drives.begin_cycle(plant.t_s, plant.q_rad, time.monotonic())
        teaching = drives.following
        reference = drives.reference(plant.t_s)
        q_ref = reference_at(reference, plant.t_s, self.n)  # as the servo cycle begins
        p_meas, enabling, q_m, dq_m, i_m = self._advance_plant(
            teaching, drives.servo_on, reference, drives.power_cut
        )
        drives.sample(q_m, dq_m, i_m)
        latencies = drives.take_latencies()
        self.latencies_s += latencies
        self.teaching_cycles = drives.stats.following_syncs
        self.teaching_missed = drives.stats.missed_cycles
        if self._log:
            self._log_row(teaching, enabling, q_m, dq_m, i_m, p_meas, latencies, q_ref)

    def _log_row(
        self,
        teaching: bool,
        enabling: bool,
        q_m: np.ndarray,
        dq_m: np.ndarray,
        i_m: np.ndarray,
        p_meas: np.ndarray,
        latencies: list[float],
        q_ref: np.ndarray,
    ) -> None:
        """One truth-log row, the LTC cell's columns (``latency_s``: the cycle's last,
        ``q_ref``: the drives' reference as the servo cycle began)."""
        assert self._log is not None
        plant = self.plant
        values = np.concatenate(
            (q_m, dq_m, i_m, plant.tool_position_m(), plant.hand_force_n, p_meas,
             plant.pressure_set_bar)
        ).tolist()  # fmt: skip
        state = int(controller_state(self.ctrl))
        latency = latencies[-1] if latencies else math.nan
        # "cycle": the command cycle, as the LTC controller's counter: here the host's SYNCs
        # (a row is one servo cycle of the drives, several to a SYNC)
        self._log.write(
            self._row_format
            % (plant.t_s, time.monotonic(), self.ctrl.stats.syncs & 0xFFFF, state, int(teaching),
               int(enabling), *values, latency, *q_ref.tolist())
        )  # fmt: skip
        if self.ctrl.cycle % LOG_FLUSH_CYCLES == 0:
            self._log.flush()

    def summary(self) -> dict[str, Any]:
        out = super().summary()
        stats = self.ctrl.stats
        out.update(
            can_profile="cia402",
            syncs=stats.syncs,
            drives=self.ctrl.describe(),
        )
        return out
