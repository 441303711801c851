"""A joint-state publisher in a process of its own, for tests that hold their own GIL.

``python tests/transport/delayed_state_publisher.py ENDPOINT CYCLE DELAY_S`` opens a zenoh
client session to the router at ENDPOINT, prints ``ready`` once its declarations have had time
to reach every session, then waits for a line on stdin; DELAY_S after it, it publishes one
joint state of cycle CYCLE (stamped then, the pose of ``test_control_process.Q0``) and exits.
The test writes that line and at once holds its GIL: the state then arrives while the test
process's Python is held, whatever the machine's speed.
"""

from __future__ import annotations

import sys
import time

import numpy as np

from gateway.bus import BusConfig, open_client
from gateway.message_factories import make_joint_state
from gateway.messages import ControllerState

Q0 = np.array([0.0, 0.15, 0.25, 0.0, -0.4, 0.0])
#: Time for the session's declarations to reach the router and its peers [s].
DECLARE_S = 0.5
#: Time left for zenoh to send the state before the session closes [s].
FLUSH_S = 0.3


def main(endpoint: str, cycle: int, delay_s: float) -> int:
    bus = BusConfig(endpoint=endpoint)
    client = open_client(bus)
    try:
        time.sleep(DECLARE_S)
        print("ready", flush=True)
        if not sys.stdin.readline():
            return 1
        time.sleep(delay_s)
        st = make_joint_state(cycle, time.monotonic(), ControllerState.EXTERNAL, 2, Q0,
                              np.zeros(6), np.zeros(6), Q0, np.zeros(6), 0.008)  # fmt: skip
        client.put(bus.keys.joint_state, st.to_bytes())
        time.sleep(FLUSH_S)
    finally:
        client.close()
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1], int(sys.argv[2]), float(sys.argv[3])))
