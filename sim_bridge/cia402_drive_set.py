"""The virtual cell's CiA 402 drive set: the drives of every joint on one CAN segment
(:class:`~sim_bridge.cia402_drives.Cia402Drive`, one per joint), driven by the cell loop like
the LTC controller: frames in, one servo cycle of every drive, the plant's reference out,
the joints' measurements back, and the counters of the cell's summary.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import can
import numpy as np

from sim_bridge.cia402_dictionary import EDS_PATH
from sim_bridge.cia402_drives import Cia402Drive
from sim_bridge.cia402_parameters import AxisParameters, DriveLimits
from sim_bridge.cia402_profile import NMT_COB_ID, SDO_RX_BASE, DriveState, NmtState


@dataclass
class DriveSetStats:
    """Counters of the drive set, named as the LTC controller's (the cell's summary)."""

    command_sets: int = 0  #: SYNCs in Operation enabled with an RPDO from every drive
    hold_sets: int = 0  #: (CiA 402 has no hold flag: always 0)
    missed_cycles: int = 0  #: SYNCs in Operation enabled missing some drive's RPDOs
    #: SYNCs in Operation enabled that came more than half a period late (sim time): a host
    #: clock that skipped a slot (CiA 402 has no cycle counter to tell a late RPDO by)
    late_frames: int = 0
    bad_frames: int = 0  #: PDOs shorter than their mapping
    syncs: int = 0  #: SYNC frames received
    following_syncs: int = 0  #: SYNCs with every drive operational, in Operation enabled
    faults: list[str] = field(default_factory=list)


class Cia402DriveSet:
    """The drives of every joint on one CAN segment (node ids ``first_node_id`` ..), driven by
    the cell loop like :class:`~sim_bridge.controller.VirtualController`: frames in
    (:meth:`on_frame`), one :meth:`begin_cycle` per servo cycle, the plant's reference out
    (:meth:`reference`), measurements back (:meth:`sample`). ``sim_clock`` gives simulated
    time [s] when a frame arrives.

    ``cycle`` counts servo cycles; a SYNC sets ``complete_for_cycle`` to it, so a lock-step
    loop that waits for ``complete_for_cycle == cycle`` runs one servo cycle per SYNC.
    """

    def __init__(
        self,
        axes: Sequence[AxisParameters],
        limits: DriveLimits,
        send: Callable[[can.Message], None],
        sim_clock: Callable[[], float],
        first_node_id: int = 1,
        eds: Path = EDS_PATH,
    ) -> None:
        # canopen's SDO server logs every expedited transfer at INFO: hundreds per start-up.
        logging.getLogger("canopen").setLevel(logging.WARNING)
        self.drives = [
            Cia402Drive(first_node_id + j, axis, limits, send, eds) for j, axis in enumerate(axes)
        ]
        self.n = len(self.drives)
        self._by_sdo = {SDO_RX_BASE + d.node_id: d for d in self.drives}
        self._clock = sim_clock
        self.cycle = 0
        self.complete_for_cycle: int | None = None
        self.stats = DriveSetStats()
        self.estop = False  #: the cell's e-stop chain is open
        #: where each unpowered joint is held while others are powered [rad]
        self._hold_q = np.zeros(self.n)
        self._was_powered = [False] * self.n
        self._tpdo_sent_stamp: float | None = None
        self._last_sync_s: float | None = None  #: simulated time of the last SYNC [s]
        self.latencies_s: list[float] = []  #: TPDOs sent → the set's last RPDO arriving [s]

    def power_on(self) -> None:
        """Every drive boots: boot-up frames, pre-operational."""
        for drive in self.drives:
            drive.boot()

    def on_frame(self, msg: can.Message, wall_s: float) -> None:
        """A frame from the segment, handled at monotonic ``wall_s``."""
        if msg.is_error_frame or msg.is_remote_frame or msg.is_extended_id:
            return
        can_id, data, stamp = msg.arbitration_id, bytes(msg.data), msg.timestamp
        if can_id == NMT_COB_ID:
            for drive in self.drives:
                drive.on_nmt(data)
            return
        now_s = self._clock()
        if (drive := self._by_sdo.get(can_id)) is not None:
            drive.on_frame(can_id, data, wall_s, now_s, stamp)
            return
        for drive in self.drives:
            drive.on_frame(can_id, data, wall_s, now_s, stamp)
        if any(can_id == d.sync_cob_id for d in self.drives):
            self._on_sync()

    def _on_sync(self) -> None:
        stats = self.stats
        stats.syncs += 1
        now_s, last_s = self._clock(), self._last_sync_s
        self._last_sync_s = now_s
        if self.following:
            stats.following_syncs += 1
            period_s = self.drives[0].cycle_period_s
            if last_s is not None and period_s > 0 and now_s - last_s > 1.5 * period_s:
                stats.late_frames += 1
            stamps = [d.rpdo_stamp_s for d in self.drives]
            if all(s is not None for s in stamps):
                stats.command_sets += 1
                if self._tpdo_sent_stamp is not None:
                    self.latencies_s.append(max(stamps) - self._tpdo_sent_stamp)  # type: ignore[type-var]
            else:
                stats.missed_cycles += 1
        for d in self.drives:
            d.rpdo_stamp_s = None
        self._tpdo_sent_stamp = time.time()  # the clock of the frames' arrival stamps
        self.complete_for_cycle = self.cycle

    def begin_cycle(self, now_s: float, q_rad: np.ndarray, wall_s: float) -> None:
        """One servo cycle of every drive at simulated time ``now_s``, the joints at
        ``q_rad`` [rad], at monotonic ``wall_s``."""
        q = np.asarray(q_rad, dtype=float)
        for j, drive in enumerate(self.drives):
            before = len(drive.faults)
            drive.step(now_s, float(q[j]), wall_s, self.estop)
            self.stats.faults += drive.faults[before:]
        self.stats.bad_frames = sum(d.bad_frames for d in self.drives)
        powered = [d.powered for d in self.drives]
        anyone_was = any(self._was_powered)
        for j in range(self.n):
            if not powered[j] and (self._was_powered[j] or not anyone_was):
                self._hold_q[j] = q[j]
        self._was_powered = powered
        self.cycle = (self.cycle + 1) & 0xFFFF

    def reference(self, now_s: float) -> tuple[np.ndarray, np.ndarray, float] | None:
        """What the plant's inner loop follows from ``now_s``: (q_r [rad], dq_r [rad/s], t_r
        [s]) for :meth:`~sim_bridge.plant.Plant.run`, or None with every drive unpowered.

        The plant brakes all joints or none: while some drives are powered, an unpowered joint
        is held where it lost power, standing in for its brake."""
        if not self.servo_on:
            return None
        q, dq = self._hold_q.copy(), np.zeros(self.n)
        for j, drive in enumerate(self.drives):
            if (ref := drive.reference(now_s)) is not None:
                q[j], dq[j] = ref
        return q, dq, now_s

    def sample(self, q_rad: np.ndarray, dq_rad_s: np.ndarray, current_a: np.ndarray) -> None:
        """The joints' measurements after a servo cycle (encoders, current sensors)."""
        rows = zip(
            self.drives,
            np.asarray(q_rad, dtype=float).tolist(),
            np.asarray(dq_rad_s, dtype=float).tolist(),
            np.asarray(current_a, dtype=float).tolist(),
            strict=True,
        )
        for drive, q, dq, i in rows:
            drive.sample(q, dq, i)

    def heartbeats(self, wall_s: float) -> None:
        """Each drive's producer heartbeat, when due."""
        for drive in self.drives:
            drive.heartbeat(wall_s)

    def take_latencies(self) -> list[float]:
        out, self.latencies_s = self.latencies_s, []
        return out

    @property
    def servo_on(self) -> bool:
        """Some drive's power stage is on (its brake released)."""
        return any(d.powered for d in self.drives)

    @property
    def power_cut(self) -> bool:
        """An unpowered drive's power went off by a fault (stop category 0)."""
        return any(d.power_cut for d in self.drives if not d.powered)

    @property
    def following(self) -> bool:
        """Every drive operational and in Operation enabled, and the host moving a setpoint
        (a target that changed within :data:`~sim_bridge.cia402_drives.MOVED_WITHIN_SYNCS`
        SYNCs, or a velocity): the arm follows the host's commands, as the LTC controller's
        EXTERNAL without its hold flag. A host that repeats one target holds the arm: that is
        not following."""
        return all(
            d.state == DriveState.OPERATION_ENABLED and d.nmt_state == NmtState.OPERATIONAL
            for d in self.drives
        ) and any(d.setpoint_moving for d in self.drives)

    @property
    def faulted(self) -> bool:
        faults = (DriveState.FAULT, DriveState.FAULT_REACTION_ACTIVE)
        return any(d.state in faults for d in self.drives)

    def describe(self) -> list[dict[str, object]]:
        """Each drive's NMT and CiA 402 state and error code (the cell's summary)."""
        return [
            {
                "node_id": d.node_id,
                "nmt": d.nmt_state.name,
                "state": d.state.name,
                "statusword": f"0x{d.statusword:04X}",
                "error_code": f"0x{d.error_code:04X}",
                "transitions": len(d.transitions),
            }
            for d in self.drives
        ]
