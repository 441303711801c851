"""Round-trip latency of the control loop's two zenoh legs, measured between two processes.

``python -m gateway.zenoh_bench [--n 5000] [--payload 296]`` starts a zenoh router (as the
gateway hosts one) and an echo process (standing in for the control process: it answers each
message on the state key with one on the command key), then pings it from this process (the
CAN driver's role) in three set-ups:

* ``routed``: both peers connect only to the router, with gossip on (the product's set-up:
  after discovery the peers open a direct link to each other);
* ``direct``: the echo peer listens and the pinger connects to it explicitly;
* ``shm``: as ``routed``, with the payload written into zenoh shared memory.

It prints p50/p99/p99.9/max of the round trip in µs. Pings are paced (one per 2 ms, like a
500 Hz loop) so the figure is a latency, not a throughput.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import threading
import time

import numpy as np
import zenoh

from gateway.bus import BusConfig, declare_loop_publisher, open_peer, open_router
from gateway.bus_security import OPERATOR

STATE_KEY, CMD_KEY = "bench/state", "bench/cmd"


def _free_port() -> int:
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _peer_config(listen: list[str], connect: list[str]) -> zenoh.Config:
    cfg = zenoh.Config()
    cfg.insert_json5("mode", '"peer"')
    cfg.insert_json5("scouting/multicast/enabled", "false")
    cfg.insert_json5("listen/endpoints", json.dumps(listen))
    cfg.insert_json5("connect/endpoints", json.dumps(connect))
    return cfg


def echo(router: str, listen: str | None) -> None:
    """The echo process: answer every state with a command of the same size, until stdin
    closes."""
    if listen:
        session = zenoh.open(_peer_config([listen], []))
    else:
        session = open_peer(BusConfig(endpoint=router), OPERATOR)
    pub = declare_loop_publisher(session, CMD_KEY)

    def on_state(sample: zenoh.Sample) -> None:
        pub.put(sample.payload.to_bytes())

    sub = session.declare_subscriber(STATE_KEY, on_state)
    print("ready", flush=True)
    sys.stdin.read()
    sub.undeclare()
    pub.undeclare()
    session.close()


def ping(router: str, mode: str, n: int, payload: int, period_s: float) -> np.ndarray:
    listen = f"tcp/127.0.0.1:{_free_port()}" if mode == "direct" else ""
    child = subprocess.Popen(
        [sys.executable, "-m", "gateway.zenoh_bench", "--echo", router, "--listen", listen],
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        text=True,
    )
    try:
        assert child.stdout is not None and child.stdout.readline().strip() == "ready"
        if mode == "direct":
            session = zenoh.open(_peer_config([], [listen]))
        else:
            session = open_peer(BusConfig(endpoint=router), OPERATOR)
        got = threading.Event()
        rtts: list[float] = []
        sent_at = [0.0]

        def on_cmd(_sample: zenoh.Sample) -> None:
            rtts.append(time.perf_counter() - sent_at[0])
            got.set()

        sub = session.declare_subscriber(CMD_KEY, on_cmd)
        pub = declare_loop_publisher(session, STATE_KEY)
        data = bytes(payload)
        provider = None
        if mode == "shm":
            from zenoh.shm import ShmProvider

            provider = ShmProvider.default_backend(1 << 20)
        time.sleep(1.0)  # discovery, the direct link between the peers
        warmup = 200
        next_s = time.perf_counter()
        for k in range(n + warmup):
            got.clear()
            if provider is not None:
                buf = provider.alloc(payload)
                buf[:] = data
                sent_at[0] = time.perf_counter()
                pub.put(buf)
            else:
                sent_at[0] = time.perf_counter()
                pub.put(data)
            if not got.wait(0.5):
                raise TimeoutError(f"{mode}: no echo for ping {k}")
            if k == warmup - 1:
                rtts.clear()
            next_s += period_s
            time.sleep(max(next_s - time.perf_counter(), 0.0))
        sub.undeclare()
        pub.undeclare()
        session.close()
        return np.array(rtts)
    finally:
        if child.stdin is not None:
            child.stdin.close()
        child.wait(10)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m gateway.zenoh_bench", description=__doc__)
    p.add_argument("--n", type=int, default=5000, help="pings per set-up")
    p.add_argument("--payload", type=int, default=296, help="bytes (a 6-joint JointState)")
    p.add_argument("--modes", nargs="+", default=["routed", "direct", "shm"])
    p.add_argument("--echo", default=None, help=argparse.SUPPRESS)
    p.add_argument("--listen", default=None, help=argparse.SUPPRESS)
    args = p.parse_args(argv)
    if args.echo is not None:
        echo(args.echo, args.listen or None)
        return 0
    bus = BusConfig(endpoint=f"tcp/127.0.0.1:{_free_port()}")
    router = open_router(bus)
    try:
        print(f"{'mode':>8} {'n':>6} {'p50 µs':>8} {'p99 µs':>8} {'p99.9 µs':>9} {'max µs':>8}")
        for mode in args.modes:
            try:
                rtt = ping(bus.endpoint, mode, args.n, args.payload, 0.002) * 1e6
            except Exception as exc:  # a mode this zenoh build lacks (shm): say so, go on
                print(f"{mode:>8}: {type(exc).__name__}: {exc}")
                continue
            q = np.percentile(rtt, [50, 99, 99.9])
            print(f"{mode:>8} {rtt.size:>6} {q[0]:>8.0f} {q[1]:>8.0f} {q[2]:>9.0f} "
                  f"{rtt.max():>8.0f}")  # fmt: skip
    finally:
        router.close()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
