"""The vendor-agnostic port between the CAN driver and a robot controller's CAN protocol.

The driver (:mod:`drivers.can.driver`) speaks only this interface; a vendor protocol lives
behind one :class:`CanAdapter` subclass, chosen by name in the cell config (``[can].adapter``)
through :func:`drivers.registry.load_adapter` and the entry-point group :data:`ADAPTER_GROUP`.

Contract every adapter follows:

* A cycle has a clock, either the controller's or the host's:

  - *controller-clocked* (LTC-1): the controller runs a fixed-rate cycle and reports every
    joint, then a status that closes the cycle; :attr:`CanAdapter.clock_period_s` is ``None``;
  - *host-clocked* (CiA 402 drives over CANopen): the host is the SYNC producer. The driver
    sends :meth:`CanAdapter.clock_frames` every :attr:`CanAdapter.clock_period_s`; each drive
    answers every SYNC with its process data.

  Either way :meth:`CanAdapter.feed` returns one :class:`CycleFeedback` for a complete, valid
  cycle and ``None`` for everything else (frames mid-cycle, unknown frames, incomplete or
  corrupt cycles, which it counts in :attr:`CanAdapter.stats`), and the driver treats both
  alike: it answers each cycle with one command set (:meth:`CanAdapter.command_frames`), keyed
  by the cycle's wire counter, before the cycle's deadline.
* Servo power is requested explicitly (:class:`HostRequest`, :meth:`CanAdapter.request_frames`,
  repeated at the heartbeat period), and the host proves it is alive with
  :meth:`CanAdapter.heartbeat_frame`.
* :meth:`CanAdapter.start` brings the link up once the bus is open and before the cycle
  (CANopen: NMT start-up and the drives' configuration by SDO); it may block for seconds and
  raises :class:`~gateway.errors.LinkTimeoutError` or ConfigError naming the node that refused.
* Adapters are built by :meth:`CanAdapter.from_config` from the ``[can]`` section.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import asdict, dataclass
from enum import IntEnum
from typing import Any, ClassVar, NamedTuple

import can
import numpy as np

from gateway.messages import ControllerState

#: Entry-point group through which other packages can add adapters.
ADAPTER_GROUP = "leadthrough.can_adapters"


class HostRequest(IntEnum):
    """What the host asks of the controller's power stage (values are LTC-1's wire values)."""

    BRAKE = 0  #: servo off, brakes engaged (the safe default)
    SERVO_ON = 1  #: servo on; the controller holds position until it gets commands
    RESET_FAULT = 2  #: leave FAULT for BRAKED once the cause is gone


class CycleFeedback(NamedTuple):
    """One complete controller cycle, assembled from its frames."""

    counter: int  #: the cycle counter as on the wire (wraps at the adapter's counter modulus)
    q_rad: np.ndarray  #: measured joint positions [rad]
    dq_rad_s: np.ndarray  #: measured joint velocities [rad/s]
    current_a: np.ndarray  #: motor currents [A]
    controller_state: ControllerState
    estop_active: bool  #: the controller sees its e-stop input open
    servo_power: bool  #: drives powered
    fault: str  #: vendor fault name, "NONE" when there is no fault
    cycle_period_s: float  #: the controller's cycle period as it reports it [s]
    status: Any  #: the vendor's decoded status frame, for diagnostics


@dataclass
class AdapterStats:
    """Frame and cycle counters of one adapter instance (monotonic, never reset)."""

    frames: int = 0  #: frames fed
    unknown_frames: int = 0  #: frames of ids this protocol does not define (ignored)
    bad_frames: int = 0  #: frames that failed to decode (DLC, CRC, range, RTR, error frames)
    cycles: int = 0  #: complete cycles returned
    incomplete_cycles: int = 0  #: status frames whose cycle lacked a joint's feedback
    corrupt_cycles: int = 0  #: status frames whose cycle contained a bad frame
    last_error: str = ""  #: the most recent reason a frame or cycle was dropped

    def as_dict(self) -> dict[str, Any]:
        return asdict(self)


class CanAdapter(ABC):
    """One vendor's CAN protocol, seen from the host."""

    #: Registry name (``[can].adapter``).
    name: ClassVar[str]
    #: The cycle counter of :class:`CycleFeedback` wraps at this value.
    counter_modulus: ClassVar[int]
    #: The controller faults when the host heartbeat is silent this long [s].
    host_heartbeat_timeout_s: ClassVar[float]
    #: Most joints the protocol can carry.
    max_joints: ClassVar[int]

    #: Host-clocked protocols: the period at which the driver sends :meth:`clock_frames` [s];
    #: ``None``: the controller clocks the cycle.
    clock_period_s: float | None = None

    def __init__(self, n_joints: int) -> None:
        self.n_joints = n_joints
        self.stats = AdapterStats()

    @classmethod
    def from_config(cls, config: Any) -> CanAdapter:
        """The adapter for the ``[can]`` section ``config`` (a CanDriverConfig)."""
        return cls(n_joints=config.joints)

    def start(self, bus: can.BusABC) -> None:  # noqa: B027 (optional hook)
        """Bring the link up on the open ``bus`` before the cycle (nothing for LTC-1)."""

    def clock_frames(self) -> list[can.Message]:
        """The frames that start a host-clocked cycle (CANopen: SYNC); none otherwise."""
        return []

    @abstractmethod
    def feed(self, msg: can.Message) -> CycleFeedback | None:
        """Take one received frame; return the cycle it completes, if it completes a valid one.

        Never raises for a bad frame: it is counted in :attr:`stats` and its cycle dropped.
        """

    @abstractmethod
    def command_frames(
        self, counter: int, q_cmd_rad: np.ndarray, dq_cmd_rad_s: np.ndarray, hold: bool
    ) -> list[can.Message]:
        """Frames answering the cycle whose wire counter is ``counter``.

        ``hold`` asks the controller to hold ``q_cmd_rad`` with zero velocity. Raises
        :class:`~gateway.errors.FrameError` if a value does not fit the protocol; never clamps.
        """

    @abstractmethod
    def request_frames(self, request: HostRequest) -> list[can.Message]:
        """The frames that ask the controller for ``request`` (its power stage's state)."""

    @abstractmethod
    def heartbeat_frame(self) -> can.Message:
        """The host's "I am alive and operational" frame."""

    def is_cycle_frame(self, msg: can.Message) -> bool:
        """True if ``msg`` carries one of the controller's per-cycle frames (by id)."""
        return False
