"""A virtual CiA 402 drive's heartbeats (CiA 301; :mod:`sim_bridge.cia402_drives`), run by the
cell loop on monotonic wall time: the producer ``0x700+n [state]`` every 0x1017 ms (0: off),
and the consumer of the host's, 0x1016 sub 1 = (producer id << 16) | time [ms], armed by the
producer's first heartbeat. The drive applies 0x6007 on a miss longer than the time while
operational or in Operation enabled.
"""

from __future__ import annotations

import math

from sim_bridge.cia402_profile import HEARTBEAT_BASE


class Heartbeats:
    """One drive's heartbeat producer and consumer (set from 0x1017 and 0x1016 sub 1)."""

    def __init__(self) -> None:
        self.set_producer(0)
        self.set_consumer(0)

    def set_producer(self, time_ms: int) -> None:
        """0x1017, the producer heartbeat time [ms]: the next heartbeat is due at once."""
        self._producer_period_s = time_ms / 1000.0
        self._next_heartbeat_wall = -math.inf

    def set_consumer(self, value: int) -> None:
        """0x1016 sub 1: (producer id << 16) | time [ms]; disarmed until its next heartbeat."""
        self._consumer_id = (value >> 16) & 0x7F
        self._consumer_time_s = (value & 0xFFFF) / 1000.0
        self._consumer_cob_id = HEARTBEAT_BASE + self._consumer_id
        self._consumer_last_wall: float | None = None  #: armed by the first heartbeat

    def received(self, can_id: int, wall_s: float) -> None:
        """A frame ``can_id`` at ``wall_s``: the consumed heartbeat (re)arms the consumer."""
        if can_id == self._consumer_cob_id and self._consumer_time_s > 0:
            self._consumer_last_wall = wall_s

    def due(self, wall_s: float) -> bool:
        """The producer's heartbeat is due at ``wall_s`` (then :meth:`sent`)."""
        return self._producer_period_s > 0 and wall_s >= self._next_heartbeat_wall

    def sent(self, wall_s: float) -> None:
        """The producer's heartbeat went at ``wall_s``: the next one is a period later (from
        now if this one was more than a period late)."""
        late = wall_s - self._next_heartbeat_wall > self._producer_period_s
        self._next_heartbeat_wall = (wall_s if late else self._next_heartbeat_wall) + (
            self._producer_period_s
        )

    def missed(self, wall_s: float) -> str | None:
        """Why the consumed heartbeat is missing at ``wall_s`` (it disarms the consumer until
        the next heartbeat); None while it is not."""
        last = self._consumer_last_wall
        if last is None or self._consumer_time_s <= 0 or wall_s - last <= self._consumer_time_s:
            return None
        self._consumer_last_wall = None
        return f"no heartbeat of node {self._consumer_id} for {wall_s - last:.3f} s"
