"""The whole stack on a locked bus (``[bus] credentials_file``): it teaches as on an open bus,
and sessions without the right identity cannot reach a driver. Separate processes, as a user
runs them."""

from __future__ import annotations

import subprocess
import sys
import time

import numpy as np
import pytest

from gateway import bus_security as sec
from gateway.bus import BusConfig, open_client, open_peer
from gateway.errors import LinkTimeoutError
from gateway.messages import IoState, Lifecycle, LifecycleMsg
from sim_bridge.commission import commissioned_stack

pytestmark = pytest.mark.stack

#: each rogue session puts each of its three forgeries this many times, at most FORGE_HZ
#: times a second (a fixed count, not a fixed time: on a starved core the forger's own loop
#: slows, and a count over time then measured the forger, not the router: 110 puts in 1.5 s
#: under taskset -c 0 make test, session 73)
FORGE_N = 150
FORGE_HZ = 100.0


def _credentials(path):
    return sec.write_credentials(path)


def _forge(bus: BusConfig, identity: str) -> int:
    """Put, as ``identity``, what would end teaching if any of it reached a process: the
    lifecycle STOPPED, the enabling device released with the e-stop pressed, and a joint
    command, FORGE_N times each. Returns the number of puts."""
    session = open_peer(bus, identity)
    keys, n = bus.keys, 0
    try:
        time.sleep(0.3)
        seq = 10**9  # ahead of any real lifecycle sequence number
        for _ in range(FORGE_N):
            now = time.monotonic()
            session.put(
                keys.lifecycle, LifecycleMsg(Lifecycle.STOPPED, seq, now, "forged").to_bytes()
            )
            session.put(keys.io_state, IoState(now, 0.0, 0.0, 0.0, 0.0, False, False).to_bytes())
            session.put(keys.joint_command, b"LTJC forged command")
            seq, n = seq + 1, n + 3
            time.sleep(1.0 / FORGE_HZ)
    finally:
        session.close()
    return n


def test_a_locked_bus_teaches_and_no_other_identity_reaches_a_driver(tmp_path):
    creds = _credentials(tmp_path / "bus.credentials")
    with commissioned_stack(
        tmp_path, cell_overrides={"bus": {"credentials_file": str(creds)}}
    ) as stack:
        stack.start()
        stack.start_teaching()
        truth = stack.wait_teaching(1.0, 30.0)
        # the operator's identity (the harness's requests use it), then the observer's
        forging_s = time.monotonic()
        forged = sum(_forge(stack.bus, identity) for identity in (sec.OPERATOR, sec.OBSERVER))
        forging_s = time.monotonic() - forging_s
        status = stack.request("status")
        assert status["state"] == "teaching", status
        # every forged put was refused at the router, and counted there
        deadline = time.monotonic() + 5.0
        while status["bus_refused"]["total"] < forged and time.monotonic() < deadline:
            time.sleep(0.2)
            status = stack.request("status")
        refused = {(e["identity"], e["key"]): e["count"] for e in status["bus_refused"]["by"]}
        keys = stack.bus.keys
        for identity in (sec.OPERATOR, sec.OBSERVER):
            for key in (keys.lifecycle, keys.io_state, keys.joint_command):
                # zenoh drops a put it cannot send at once (congestion control "drop"): 80 %
                assert refused.get((identity, key), 0) > 0.8 * FORGE_N, refused
        # and a session without credentials does not get on the bus at all
        with pytest.raises(LinkTimeoutError):
            open_client(BusConfig(endpoint=stack.bus.endpoint), connect_timeout_s=1.0)
        # the command line, with the cell file, speaks as the operator
        cli = [sys.executable, "-m", "gateway.cli", "status", "--config", str(stack.cell_path)]
        out = subprocess.run(cli, capture_output=True, text=True, timeout=30)
        assert out.returncode == 0 and "state: teaching" in out.stdout, out.stdout + out.stderr
        assert "the bus refused" in out.stdout, out.stdout
        stack.request("stop")
        truth = stack.truth()
    assert forged == 3 * FORGE_N * 2
    rows = np.flatnonzero(truth["teaching"] > 0.5)
    t = truth["t_s"][rows]
    # teaching ran on without a gap through the forgeries (a gap: something stopped it)
    assert rows.size and np.max(np.diff(t)) < 0.1, np.max(np.diff(t))
    assert t[-1] - t[0] > forging_s
    # the router counted its decisions in memory: none of them, allowed or refused, went to
    # the gateway's output (the journal on a cell PC)
    assert "authorized" not in (tmp_path / "gateway.log").read_text(errors="replace")
