"""How deploy/screenshots/live_view.png is made: `leadthrough view --http-port` in headless
Chromium, fed by a recording (`leadthrough demo`'s OUT/recording.mcap) replayed onto a local bus
at its recorded pace.

    .venv/bin/python deploy/screenshots/take_live_view.py DEMO_OUT/recording.mcap [--cell CELL]

A recording, not the live virtual cell: on a 2-core machine the virtual cell, the product and
Chromium together starved the CAN driver past the gateway's 0.1 s joint-state watchdog (the
cell faulted, three tries in three, 2026-11-28), which a cell PC avoids by running the product
with [realtime] and keeping browsers elsewhere. Needs Debian's chromium (/usr/bin/chromium).
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import threading
import time
from pathlib import Path

from gateway.bus import BusConfig, open_client, open_router
from gateway.recorder import iter_mcap
from sim_bridge.harness import free_port

HERE = Path(__file__).resolve().parent
CHROMIUM_FLAGS = [
    "--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
    "--disable-background-networking", "--disable-component-update", "--disable-sync",
    "--virtual-time-budget=300000", "--window-size=1280,800",
]  # fmt: skip


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("recording", type=Path)
    ap.add_argument("--cell", type=Path, default=HERE.parent / "config" / "sim_cell_cia402.toml")
    ap.add_argument("--skip-s", type=float, default=4.0, help="start this far into it [s]")
    ap.add_argument("--out", type=Path, default=HERE / "live_view.png")
    args = ap.parse_args()
    messages = list(iter_mcap(args.recording))
    start = messages[0][1] + int(args.skip_s * 1e9)
    messages = [m for m in messages if m[1] >= start]
    bus = BusConfig(endpoint=f"tcp/127.0.0.1:{free_port()}")
    router = open_router(bus)
    pub = open_client(bus)
    stop = threading.Event()

    def feed() -> None:
        wall0 = time.monotonic()
        for key, t_ns, payload in messages:
            if stop.is_set():
                return
            time.sleep(max(wall0 + (t_ns - start) * 1e-9 - time.monotonic(), 0.0))
            pub.put(key, payload)

    feeder = threading.Thread(target=feed, name="replay")
    feeder.start()
    ws, http = free_port(), free_port()
    view = subprocess.Popen(
        [sys.executable, "-m", "gateway.cli", "view", "--config", str(args.cell),
         "--bus", bus.endpoint, "--port", str(ws), "--http-port", str(http)]
    )  # fmt: skip
    try:
        time.sleep(1.5)
        profile = args.out.parent / ".chromium-profile"
        subprocess.run(["chromium", *CHROMIUM_FLAGS, f"--user-data-dir={profile}",
                        f"--screenshot={args.out}", f"http://127.0.0.1:{http}/"],
                       check=True, timeout=300, capture_output=True)  # fmt: skip
    finally:
        stop.set()
        feeder.join()
        view.terminate()
        view.wait(10)
        pub.close()
        router.close()
        subprocess.run(["rm", "-rf", str(args.out.parent / ".chromium-profile")], check=False)
    print(args.out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
