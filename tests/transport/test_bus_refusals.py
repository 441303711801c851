"""Counting the locked bus's refusals (gateway/bus_refusals.py): zenoh's access-control log
line parsed, and a real router's refusals counted in a process of their own (the tap takes
over file descriptor 1, which pytest's capture must keep)."""

from __future__ import annotations

import json
import subprocess
import sys
import textwrap
from pathlib import Path

from gateway.bus_refusals import UNNAMED, BusRefusals
from gateway.cli import refusal_line

REPO = Path(__file__).resolve().parents[2]

#: a line as zenoh 1.10.2 writes it (colours and all), from a run on 2026-11-28
LINE = (
    "\x1b[2m2026-11-28T12:27:53.894711Z\x1b[0m \x1b[35mTRACE\x1b[0m rx-1 ThreadId(09) "
    "\x1b[2mzenoh::net::routing::interceptor::access_control\x1b[0m\x1b[2m:\x1b[0m "
    "94bd50868f0f281995fa9eca926fef7c on Interface(lo)+Username(operator)+Transport(Tcp)+"
    "94bd50868f0f281995fa9eca926fef7c is unauthorized to Put (ingress) on lt/cmd/joints"
)


def test_a_refusal_line_is_counted_by_identity_action_and_key():
    refusals = BusRefusals(clock=lambda: 0.0)
    assert refusals.feed(LINE) and refusals.feed(LINE)
    assert refusals.feed(LINE.replace("lt/cmd/joints", "lt/state/io").replace("Put", "Query"))
    assert refusals.feed(LINE.replace("+Username(operator)", ""))
    assert not refusals.feed("... access_control: Access control is enabled")
    assert not refusals.feed("")
    summary = refusals.summary()
    assert summary["total"] == 4
    assert {"identity": "operator", "action": "Put", "key": "lt/cmd/joints", "count": 2} in (
        summary["by"]
    )
    assert any(e["identity"] == UNNAMED for e in summary["by"])
    line = refusal_line(summary)
    assert line.startswith("the bus refused 4: operator Put on lt/cmd/joints x2, "), line


SCRIPT = textwrap.dedent(
    """
    import json, socket, sys, time
    from pathlib import Path
    from gateway import bus_security as sec
    from gateway.bus import BusConfig, open_peer, open_router
    from gateway.bus_refusals import count_bus_refusals

    refusals, tap = count_bus_refusals()
    s = socket.socket(); s.bind(("127.0.0.1", 0)); port = s.getsockname()[1]; s.close()
    creds = sec.write_credentials(Path(sys.argv[1]) / "bus.credentials", sec.IDENTITIES)
    bus = BusConfig(endpoint=f"tcp/127.0.0.1:{port}", credentials_file=str(creds))
    router = open_router(bus)
    print("a line of the process's own", flush=True)
    forger = open_peer(bus, sec.OBSERVER)
    declared = forger.declare_publisher(bus.keys.io_state)
    time.sleep(0.3)
    for _ in range(50):
        forger.put(bus.keys.joint_command, b"forged")
        declared.put(b"forged")
    owner = open_peer(bus, sec.CONTROL)
    time.sleep(0.3)
    owner.put(bus.keys.joint_command, b"allowed")
    deadline = time.monotonic() + 5.0
    while refusals.total < 50 and time.monotonic() < deadline:
        time.sleep(0.05)
    forger.close(); owner.close(); router.close()
    sys.stderr.write(json.dumps(refusals.summary()) + "\\n")
    """
)


def test_a_real_routers_refusals_are_counted_and_other_output_passes(tmp_path):
    out = subprocess.run(
        [sys.executable, "-c", SCRIPT, str(tmp_path)],
        capture_output=True, text=True, timeout=60, cwd=REPO,
    )  # fmt: skip
    assert out.returncode == 0, out.stderr
    summary = json.loads(out.stderr.strip().splitlines()[-1])
    counts = {(e["identity"], e["action"], e["key"]): e["count"] for e in summary["by"]}
    # put by put on a key the forger did not declare ...
    assert counts[("observer", "Put", "lt/cmd/joints")] == 50, summary
    # ... once, at its declaration, for a declared publisher: zenoh decides it then and drops
    # its later puts without a line (bus_refusals.py's docstring)
    assert counts[("observer", "Put", "lt/state/io")] == 1, summary
    assert "a line of the process's own" in out.stdout  # passed on, not swallowed
    assert "unauthorized" not in out.stdout  # counted, not printed
