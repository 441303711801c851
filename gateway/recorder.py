"""Record everything the zenoh bus carries into an MCAP file, and export it to CSV.

MCAP layout: one channel per key expression (topic = the key), message encoding
``leadthrough/<Type>`` for the binary layouts of gateway/messages.py and ``json`` for the JSON
ones; log time = receive time on the recorder [ns, monotonic clock]. Zenoh callbacks only
enqueue; a writer thread owns the file, so a slow disk never stalls the bus.

CSV export (the measurement format of control/identification/datafile.py): one row per
JointState, ``t`` counted from the first exported cycle in controller time
(cycle × cycle period, so lock-step recordings keep their true time base), ``q``, ``dq``, motor
currents ``i``, and the latest cylinder pressures ``p2``, ``p3``; a sidecar ``<stem>.json``
carries the drive gains that turn currents into torques.
"""

from __future__ import annotations

import argparse
import json
import logging
import queue
import signal
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
from mcap.reader import make_reader
from mcap.writer import CompressionType, Writer

from gateway.bus import BusConfig, bus_config_from, open_client, undeclare_all
from gateway.config import load_toml
from gateway.errors import DataFileError, MessageError
from gateway.messages import IoState, JointCommand, JointState, Keys, PressureSetpoint

log = logging.getLogger("leadthrough.recorder")

_BINARY = {
    JointState.MAGIC: "JointState",
    JointCommand.MAGIC: "JointCommand",
    IoState.MAGIC: "IoState",
    PressureSetpoint.MAGIC: "PressureSetpoint",
}
_STOP = object()


def _encoding(payload: bytes) -> str:
    kind = _BINARY.get(payload[:4])
    return f"leadthrough/{kind}" if kind else "json"


class BusRecorder:
    """Subscribe to ``<prefix>/**`` and write every sample to ``path`` (MCAP)."""

    def __init__(self, bus: BusConfig, path: Path, metadata: dict[str, str] | None = None):
        self.bus = bus
        self.path = Path(path)
        self.metadata = metadata or {}
        self._queue: queue.SimpleQueue[Any] = queue.SimpleQueue()
        self._thread = threading.Thread(target=self._write_loop, name="mcap-writer")
        self._session = None
        self._sub = None
        self.count = 0
        self.error: BaseException | None = None

    def start(self) -> None:
        self._thread.start()
        self._session = open_client(self.bus)
        self._sub = self._session.declare_subscriber(f"{self.bus.key_prefix}/**", self._on_sample)

    def _on_sample(self, sample: Any) -> None:
        self._queue.put((str(sample.key_expr), time.monotonic_ns(), sample.payload.to_bytes()))

    def _write_loop(self) -> None:
        channels: dict[tuple[str, str], int] = {}
        try:
            with self.path.open("wb") as fh:
                writer = Writer(fh, compression=CompressionType.LZ4)
                writer.start(profile="", library="leadthrough")
                if self.metadata:
                    writer.add_metadata("leadthrough", self.metadata)
                schema = writer.register_schema("leadthrough", "", b"")
                while (item := self._queue.get()) is not _STOP:
                    key, t_ns, payload = item
                    enc = _encoding(payload)
                    ch = channels.get((key, enc))
                    if ch is None:
                        ch = writer.register_channel(key, enc, schema)
                        channels[(key, enc)] = ch
                    writer.add_message(ch, t_ns, payload, t_ns, self.count)
                    self.count += 1
                writer.finish()
        except BaseException as exc:  # keep the recording error for stop() to report
            self.error = exc
            log.exception("recording to %s failed", self.path)

    def stop(self) -> None:
        """Undeclare, close the session, flush and close the file (never loses queued data)."""
        try:
            undeclare_all([self._sub])
            self._sub = None
            if self._session is not None:
                self._session.close()
                self._session = None
        finally:
            self._queue.put(_STOP)
            if self._thread.is_alive():
                self._thread.join(30.0)


def iter_mcap(path: Path) -> Iterator[tuple[str, int, bytes]]:
    """(key, log_time_ns, payload) of every message, in log-time order."""
    try:
        with Path(path).open("rb") as fh:
            for _schema, channel, message in make_reader(fh).iter_messages(log_time_order=True):
                yield channel.topic, message.log_time, message.data
    except FileNotFoundError:
        raise DataFileError(f"{path}: recording not found") from None
    except Exception as exc:
        raise DataFileError(f"{path}: not a readable MCAP recording: {exc}") from exc


def export_csv(
    mcap_path: Path,
    csv_path: Path,
    drive_gains_nm_per_a: list[float],
    keys: Keys | None = None,
    cycle_range: tuple[int, int] | None = None,
) -> int:
    """Export joint states (+ latest pressures) to the measurement CSV; returns rows written.

    ``cycle_range`` keeps only the controller cycles ``first..last`` (inclusive).
    Malformed messages are counted and skipped with a warning, never exported.
    """
    keys = keys or Keys()
    rows: list[np.ndarray] = []
    p = np.array([np.nan, np.nan])
    cycle0: int | None = None
    bad = 0
    n = None
    for key, _t_ns, payload in iter_mcap(mcap_path):
        try:
            if key == keys.io_state:
                io = IoState.from_bytes(payload)
                p = np.array([io.p2_bar, io.p3_bar])
            elif key == keys.joint_state:
                st = JointState.from_bytes(payload)
                if n is None:
                    n = st.n
                if st.n != n or st.cycle_period_s <= 0 or np.isnan(p).any():
                    continue
                if cycle_range and not cycle_range[0] <= st.cycle <= cycle_range[1]:
                    continue
                cycle0 = st.cycle if cycle0 is None else cycle0
                t = (st.cycle - cycle0) * st.cycle_period_s
                rows.append(np.concatenate([[t], st.q_rad, st.dq_rad_s, st.current_a, p]))
        except MessageError as exc:
            bad += 1
            log.warning("skipped a malformed message on %s: %s", key, exc)
    if not rows or n is None:
        raise DataFileError(f"{mcap_path}: no joint states with pressures to export")
    if len(drive_gains_nm_per_a) != n:
        raise DataFileError(f"{n} joints recorded but {len(drive_gains_nm_per_a)} drive gains")
    data = np.array(rows)
    header = ["t"] + [f"{c}{j + 1}" for c in ("q", "dq", "i") for j in range(n)] + ["p2", "p3"]
    csv_path = Path(csv_path)
    with csv_path.open("w") as fh:
        fh.write(",".join(header) + "\n")
        np.savetxt(fh, data, delimiter=",", fmt="%.9g")
    csv_path.with_suffix(".json").write_text(
        json.dumps({"drive_gains_nm_per_a": list(drive_gains_nm_per_a), "source": str(mcap_path)})
    )
    if bad:
        log.warning("%d malformed messages skipped", bad)
    return len(rows)


def configure_parser(p: argparse.ArgumentParser) -> None:
    p.description = "Record everything on the zenoh bus into an MCAP file until Ctrl-C."
    p.add_argument("--out", type=Path, required=True, help="MCAP file to write")
    p.add_argument("--config", type=Path, default=None, help="cell config TOML (for [bus])")
    p.add_argument("--bus", default=None, help="zenoh endpoint of the gateway")
    p.add_argument("--duration", type=float, default=None, help="stop after this many seconds")


def cli_main(args: argparse.Namespace) -> int:
    bus = BusConfig()
    if args.config:
        bus = bus_config_from(load_toml(args.config), str(args.config))
    rec = BusRecorder(bus.with_overrides(args.bus), args.out)
    stop = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: stop.set())
    signal.signal(signal.SIGINT, lambda *_: stop.set())
    rec.start()
    try:
        stop.wait(args.duration)
    finally:
        rec.stop()
    log.info("%d messages written to %s", rec.count, args.out)
    return 1 if rec.error else 0
