"""CAN bus errors as the interface reports them, and the fault they latch (issue 10).

SocketCAN delivers the CAN controller's problems as *error frames* (``linux/can/error.h``):
the frame's id holds the error class bits, its data the details. python-can gives them as
messages with ``is_error_frame`` set and the class in ``arbitration_id``; the seqpacket
transport of the tests carries the same. :class:`BusErrors` reads them:

- **bus-off** (``CAN_ERR_BUSOFF``): the host's CAN controller has taken itself off the bus
  (its transmit error counter passed 255). Nothing the host sends reaches the controller any
  more; the kernel restarts the interface after ``restart-ms`` (``deploy/systemd``'s
  ``ip link set can0 type can restart-ms 100``) and reports ``CAN_ERR_RESTARTED``. A bus-off
  latches a fault;
- **a burst of bus errors**: ``[can] bus_error_limit`` error frames of any class within
  ``bus_error_window_s`` latch a fault (a wiring or termination problem that corrupts the
  cycle's frames faster than one lost cycle explains);
- **error passive** (``CAN_ERR_CRTL`` with ``CAN_ERR_CRTL_RX_PASSIVE``/``TX_PASSIVE``):
  counted and reported, the warning before bus-off.

The latched fault blocks forwarding (``blocked_bus``), makes the driver ask for the brakes,
goes to the gateway in the health (``bus_fault``) and faults the cell. It clears only when
both hold: the bus works again (no error frame for ``bus_error_window_s`` and a complete
cycle received since the last), and the gateway has stopped the cell (lifecycle STOPPED or
FAULT): the operator then re-arms with ``reset`` and ``start``, never the bus by itself.
"""

from __future__ import annotations

from collections import deque

import can

#: error classes of the error frame's id (linux/can/error.h)
CAN_ERR_TX_TIMEOUT = 0x001
CAN_ERR_LOSTARB = 0x002
CAN_ERR_CRTL = 0x004
CAN_ERR_PROT = 0x008
CAN_ERR_TRX = 0x010
CAN_ERR_ACK = 0x020
CAN_ERR_BUSOFF = 0x040
CAN_ERR_BUSERROR = 0x080
CAN_ERR_RESTARTED = 0x100
#: data[1] of a CAN_ERR_CRTL frame
CAN_ERR_CRTL_RX_PASSIVE = 0x10
CAN_ERR_CRTL_TX_PASSIVE = 0x20

_NAMES = (
    (CAN_ERR_TX_TIMEOUT, "tx timeout"),
    (CAN_ERR_LOSTARB, "lost arbitration"),
    (CAN_ERR_CRTL, "controller problem"),
    (CAN_ERR_PROT, "protocol violation"),
    (CAN_ERR_TRX, "transceiver problem"),
    (CAN_ERR_ACK, "no acknowledge"),
    (CAN_ERR_BUSOFF, "bus-off"),
    (CAN_ERR_BUSERROR, "bus error"),
    (CAN_ERR_RESTARTED, "restarted"),
)


def describe(error_class: int) -> str:
    """The error classes set in ``error_class``, in words."""
    names = [name for bit, name in _NAMES if error_class & bit]
    return ", ".join(names) or f"class 0x{error_class:X}"


class BusErrors:
    """The error frames seen and the fault they latched (module docstring)."""

    def __init__(self, limit: int, window_s: float) -> None:
        self.limit = int(limit)
        self.window_s = float(window_s)
        self.fault: str | None = None
        self.error_frames = 0
        self.bus_off = 0
        self.restarts = 0
        self.error_passive = 0
        self._recent: deque[float] = deque()
        self._last_error_s = -float("inf")
        self._cycle_since_error = True

    def on_error_frame(self, msg: can.Message, now: float) -> str | None:
        """Take one error frame; the fault it latches (once), else None."""
        cls = int(msg.arbitration_id)
        self.error_frames += 1
        self._last_error_s, self._cycle_since_error = now, False
        recent = self._recent
        recent.append(now)
        while recent and now - recent[0] > self.window_s:
            recent.popleft()
        data = bytes(msg.data)
        passive = CAN_ERR_CRTL_RX_PASSIVE | CAN_ERR_CRTL_TX_PASSIVE
        if cls & CAN_ERR_CRTL and len(data) > 1 and data[1] & passive:
            self.error_passive += 1
        if cls & CAN_ERR_RESTARTED:
            self.restarts += 1
        if self.fault is not None:
            return None
        if cls & CAN_ERR_BUSOFF:
            self.bus_off += 1
            self.fault = "the CAN interface went bus-off (the host's controller left the bus)"
        elif len(recent) >= self.limit:
            self.fault = (
                f"{len(recent)} CAN error frames within {self.window_s:g} s (last: {describe(cls)})"
            )
        return self.fault

    def on_cycle(self) -> None:
        """A complete controller cycle arrived: the bus carries frames again."""
        self._cycle_since_error = True

    def recovered(self, now: float) -> bool:
        """The bus works again: no error frame for the window, a cycle since the last."""
        return self._cycle_since_error and now - self._last_error_s >= self.window_s

    def clear(self, now: float) -> bool:
        """Clear the fault if the bus has recovered (the caller knows the cell is stopped);
        True if it was cleared."""
        if self.fault is None or not self.recovered(now):
            return False
        self.fault = None
        return True

    def health(self) -> dict[str, object]:
        return {
            "bus_fault": self.fault,
            "bus_error_frames": self.error_frames,
            "bus_off": self.bus_off,
            "bus_restarts": self.restarts,
            "bus_error_passive": self.error_passive,
        }
