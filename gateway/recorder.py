"""Record everything the zenoh bus carries into an MCAP file, and export it to CSV.

MCAP layout: one channel per key expression and message kind (topic = the key), every message
JSON with a JSON Schema (gateway/mcap_json.py): Foxglove, PlotJuggler or any JSON reader opens
and plots a recording without this project's code. Log time = receive time on the recorder,
wall-clock [ns] (the recording's start in CLOCK_REALTIME, advanced by CLOCK_MONOTONIC, so it
never steps); each message keeps the monotonic receive time as ``rx_monotonic_ns``. The readers
here (:func:`iter_mcap`) hand back the bus's own payloads, and read the recordings of earlier
versions (raw payloads, monotonic log times) as well. Zenoh callbacks only
enqueue; a writer thread owns the file, so a slow disk never stalls the bus. The writer closes
its chunk, flushes and fsyncs at least every :data:`FLUSH_PERIOD_S`, so a crash, a power cut or
``kill -9`` loses at most that much: :func:`iter_mcap` reads a cut file (no summary, a partial
last record) up to its last complete record and says so.

CSV export (the measurement format of control/identification/datafile.py): one row per
JointState, ``t`` counted from the first exported cycle in controller time
(cycle × cycle period, so lock-step recordings keep their true time base), ``q``, ``dq``, motor
currents ``i`` (interpolated to the instant of ``q``), and the latest cylinder pressures ``p2``,
``p3``; a sidecar ``<stem>.json`` carries the drive gains that turn currents into torques.
Cycles disturbed by a hold or coast of the CAN driver are left out (:func:`export_csv`,
gateway/disturbed_cycles.py).
"""

from __future__ import annotations

import argparse
import contextlib
import json
import logging
import os
import queue
import threading
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from mcap.reader import make_reader
from mcap.records import Channel, Message, Schema
from mcap.stream_reader import StreamReader
from mcap.writer import CompressionType, Writer

from gateway import mcap_json
from gateway.bus import BusConfig, bus_config_from, open_client, undeclare_all
from gateway.bus_security import OBSERVER
from gateway.config import load_toml
from gateway.disturbed_cycles import disturbed_cycles
from gateway.errors import ConfigError, DataFileError, MessageError
from gateway.messages import IoState, JointState, Keys
from gateway.signals import StopSignals

log = logging.getLogger("leadthrough.recorder")

_STOP = object()
#: the longest a received message waits in memory before it is on disk [s]
FLUSH_PERIOD_S = 1.0
#: niceness of the writer thread (its own, Linux keeps one per thread): turning each message
#: into JSON costs ~0.4 ms, half of `make demo`'s observer process and more CPU than the CAN
#: driver (2026-11-30); on a slow cell PC whose cores the cycle needs, the writer waits and the
#: queue holds the messages (10: half of the 0..19 range, as control/plan_builder.py's worker)
WRITER_NICENESS = 10
#: stop() gives the writer up when it has written nothing for so long [s]: a message costs
#: ~0.4 ms and an fsync of a slow disk well under a second, so only a hung disk or a dead
#: thread is this quiet
WRITER_STALL_S = 30.0


class BusRecorder:
    """Subscribe to ``<prefix>/**`` and write every sample to ``path`` (MCAP)."""

    def __init__(
        self,
        bus: BusConfig,
        path: Path,
        metadata: dict[str, str] | None = None,
        rotate_bytes: int = 0,
        keep: int = 0,
    ):
        self.bus = bus
        self.path = Path(path)
        self.metadata = metadata or {}
        #: start a new file once the current one has this many bytes on disk (0: one file)
        self.rotate_bytes = int(rotate_bytes)
        #: files kept when rotating: the oldest beyond it are deleted (0: all kept)
        self.keep = int(keep)
        #: the files written (the kept ones when rotating), the last being written
        self.files: list[Path] = []
        self._parts = 0
        self._queue: queue.SimpleQueue[Any] = queue.SimpleQueue()
        self._thread = threading.Thread(target=self._write_loop, name="mcap-writer")
        self._session = None
        self._sub = None
        self.count = 0
        self.error: BaseException | None = None

    def start(self) -> None:
        """Subscribe, then start the writer (a bus that refuses us leaves no thread behind)."""
        self._session = open_client(self.bus, identity=OBSERVER)
        try:
            self._sub = self._session.declare_subscriber(
                f"{self.bus.key_prefix}/**", self._on_sample
            )
        except BaseException:
            self._session.close()
            self._session = None
            raise
        self._thread.start()

    def _on_sample(self, sample: Any) -> None:
        self._queue.put((str(sample.key_expr), time.monotonic_ns(), sample.payload.to_bytes()))

    def _write_loop(self) -> None:
        with contextlib.suppress(OSError, AttributeError):  # not Linux, or not permitted
            os.setpriority(os.PRIO_PROCESS, threading.get_native_id(), WRITER_NICENESS)
        #: wall-clock of the recording's start, advanced by the monotonic clock [ns]
        wall0_ns, mono0_ns = time.time_ns(), time.monotonic_ns()
        out: _McapFile | None = None
        try:
            out = self._open_next(wall0_ns, mono0_ns)
            due: float | None = None  #: when the oldest message not on disk must be
            while True:
                wait = None if due is None else max(due - time.monotonic(), 0.0)
                try:
                    item = self._queue.get(timeout=wait)
                except queue.Empty:
                    item = None
                if item is _STOP:
                    break
                if item is not None:
                    key, mono_ns, payload = item
                    out.add(key, wall0_ns + (mono_ns - mono0_ns), mono_ns, payload, self.count)
                    self.count += 1
                    if due is None:
                        due = time.monotonic() + FLUSH_PERIOD_S
                if due is not None and time.monotonic() >= due:
                    out.to_disk()
                    due = None
                    if self.rotate_bytes and out.size() >= self.rotate_bytes:
                        out.close()
                        out = self._open_next(wall0_ns, mono0_ns)
            out.close()
        except BaseException as exc:  # keep the recording error for stop() to report
            self.error = exc
            log.exception("recording to %s failed", self.path)
            if out is not None:
                with contextlib.suppress(Exception):
                    out.close()

    def _open_next(self, wall0_ns: int, mono0_ns: int) -> _McapFile:
        """The next file: ``path`` itself, or with rotation ``<stem>-0001<suffix>``, ... (the
        oldest beyond ``keep`` deleted)."""
        self._parts += 1
        if not self.rotate_bytes:
            path = self.path
        else:
            path = self.path.with_name(f"{self.path.stem}-{self._parts:04d}.mcap")
        self.files.append(path)
        if self.keep and len(self.files) > self.keep:
            for old in self.files[: -self.keep]:
                with contextlib.suppress(FileNotFoundError):
                    old.unlink()
                    log.info("recording rotated: %s deleted (keeping %d files)", old, self.keep)
            self.files = self.files[-self.keep :]
        metadata = {**self.metadata, "start_wall_ns": str(wall0_ns),
                    "start_monotonic_ns": str(mono0_ns), "part": str(self._parts)}  # fmt: skip
        return _McapFile(path, metadata)

    def stop(self, stall_s: float = WRITER_STALL_S) -> None:
        """Undeclare, close the session, then wait until the writer has put every queued
        message on disk and closed the file (never loses queued data, and never returns while
        the file is still being written: a reader would find it cut). A writer that writes
        nothing for ``stall_s`` is given up on: :attr:`error` says so."""
        try:
            undeclare_all([self._sub])
            self._sub = None
            if self._session is not None:
                self._session.close()
                self._session = None
        finally:
            self._queue.put(_STOP)
            self._join_writer(stall_s)

    def _join_writer(self, stall_s: float) -> None:
        """Wait for the writer while it makes progress (a backlog of a lock-step run on a busy
        machine takes minutes to write: session 88's CI lost a plan's end to a 30 s join)."""
        if not self._thread.ident:
            return  # never started
        written, since = self.count, time.monotonic()
        while self._thread.is_alive():
            self._thread.join(min(1.0, stall_s))
            if self.count != written:
                written, since = self.count, time.monotonic()
            elif self._thread.is_alive() and time.monotonic() - since > stall_s:
                self.error = self.error or RuntimeError(
                    f"the MCAP writer of {self.path} wrote nothing for {stall_s:.0f} s with "
                    f"{self._queue.qsize()} messages queued; the file is incomplete"
                )
                log.error("%s", self.error)
                return


class _McapFile:
    """One MCAP file being written: its channels and schemas, flushed on request."""

    def __init__(self, path: Path, metadata: dict[str, str]) -> None:
        self.path = path
        self.fh = path.open("wb")
        self.writer = Writer(self.fh, compression=CompressionType.LZ4)
        self.writer.start(profile="", library="leadthrough")
        self.writer.add_metadata("leadthrough", metadata)
        self.channels: dict[tuple[str, str], int] = {}
        self.schemas: dict[str, int] = {}

    def add(self, key: str, t_ns: int, mono_ns: int, payload: bytes, sequence: int) -> None:
        kind, data = mcap_json.to_record(payload, mono_ns)
        ch = self.channels.get((key, kind))
        if ch is None:
            if kind not in self.schemas:
                self.schemas[kind] = self.writer.register_schema(
                    mcap_json.PREFIX + kind, mcap_json.SCHEMA_ENCODING, mcap_json.schema_bytes(kind)
                )
            ch = self.writer.register_channel(key, mcap_json.MESSAGE_ENCODING, self.schemas[kind])
            self.channels[(key, kind)] = ch
        self.writer.add_message(ch, t_ns, data, t_ns, sequence)

    def to_disk(self) -> None:
        _to_disk(self.writer, self.fh)

    def size(self) -> int:
        return self.fh.tell()

    def close(self) -> None:
        try:
            self.writer.finish()
            self.fh.flush()
            os.fsync(self.fh.fileno())
        finally:
            self.fh.close()


def _to_disk(writer: Writer, fh: Any) -> None:
    """Close the open chunk (mcap 1.6 has no public call for it; without it a chunk is written
    only when it is full, ~1 MiB or ~14 s of a 250 Hz cell), flush and fsync."""
    finalize = getattr(writer, "_Writer__finalize_chunk", None)
    if finalize is not None:
        finalize()
    fh.flush()
    os.fsync(fh.fileno())


def iter_mcap(path: Path, topics: list[str] | None = None) -> Iterator[tuple[str, int, bytes]]:
    """(key, log_time_ns, payload) of every message (of ``topics`` only, when given), in
    log-time order. A recording cut short (the recorder killed: no summary, the last record
    partial) is read up to its last complete record, with a warning."""
    path = Path(path)
    try:
        with path.open("rb") as fh:
            try:
                reader = make_reader(fh)
                messages = reader.iter_messages(topics, log_time_order=True)
                first = next(messages, None)
            except Exception as exc:  # no footer/summary: read it as a stream
                log.warning("%s: recording was cut short (%s); reading what is complete",
                            path, exc)  # fmt: skip
                fh.seek(0)
                yield from _iter_cut(fh, path, topics)
                return
            if first is not None:
                yield first[1].topic, first[2].log_time, _payload(first[0], first[1], first[2])
            for schema, channel, message in messages:
                yield channel.topic, message.log_time, _payload(schema, channel, message)
    except FileNotFoundError:
        raise DataFileError(f"{path}: recording not found") from None
    except DataFileError:
        raise
    except Exception as exc:
        raise DataFileError(f"{path}: not a readable MCAP recording: {exc}") from exc


def _payload(schema: Schema | None, channel: Channel, message: Message) -> bytes:
    """The bus payload of a recorded message: decoded from its JSON (this version's
    recordings), or as it was stored (earlier versions' raw payloads). A JSON message that
    does not fit its schema comes back as its JSON text, which no bus decoder accepts (the
    readers count it as malformed)."""
    name = schema.name if schema is not None else ""
    if channel.message_encoding != mcap_json.MESSAGE_ENCODING or not name.startswith(
        mcap_json.PREFIX
    ):
        return message.data
    try:
        return mcap_json.to_payload(name.removeprefix(mcap_json.PREFIX), message.data)
    except MessageError as exc:
        log.warning("%s at %d: %s", channel.topic, message.log_time, exc)
        return message.data


def _iter_cut(fh: Any, path: Path, topics: list[str] | None) -> Iterator[tuple[str, int, bytes]]:
    """The complete messages of a cut recording, in log-time order."""
    schema_of: dict[int, Schema] = {}
    channel_of: dict[int, Channel] = {}
    out: list[tuple[int, int, str, bytes]] = []
    try:
        for record in StreamReader(fh, emit_chunks=False).records:
            if isinstance(record, Schema):
                schema_of[record.id] = record
            elif isinstance(record, Channel):
                channel_of[record.id] = record
            elif isinstance(record, Message):
                channel = channel_of.get(record.channel_id)
                if channel is not None and (topics is None or channel.topic in topics):
                    data = _payload(schema_of.get(channel.schema_id), channel, record)
                    out.append((record.log_time, len(out), channel.topic, data))
    except Exception as exc:  # the cut: a partial record, or a chunk that was never closed
        if not out and not channel_of:
            raise DataFileError(f"{path}: not a readable MCAP recording: {exc}") from exc
    out.sort()
    for t_ns, _, topic, data in out:
        yield topic, t_ns, data


#: After a cycle the CAN driver's answer disturbed (a hold, or a coast that resumed with a step
#: the law does not take: gateway/disturbed_cycles.py, PROTOCOL.md §3), the vendor loop answers
#: with a current transient the kinematics sampled once per cycle cannot follow; so many seconds
#: of cycles are left out of the export [s] (the inner loop of eq. 19 settles in
#: ~4/(ζ ω_n) ≈ 0.08 s).
DISTURBANCE_SETTLE_S = 0.15
#: How far the motor current of a JointState lags its q and dq [cycles]: LTC-1 drives report
#: the current averaged over the cycle (PROTOCOL.md §2.1), centred half a cycle earlier.
CURRENT_LAG_CYCLES = 0.5


@dataclass(frozen=True)
class RecordedStates:
    """The joint states of a recording, each with the latest pressures [bar] before it."""

    states: list[tuple[JointState, np.ndarray]]
    n: int | None  #: joints (None: no state)
    bad: int  #: malformed messages skipped


def read_states(mcap_path: Path, keys: Keys | None = None) -> RecordedStates:
    """Read a recording's joint states once (:func:`export_csv` can then cut many files from
    it). States of another joint count, without a cycle period or before the first pressures
    are left out; malformed messages are counted and skipped with a warning."""
    keys = keys or Keys()
    states: list[tuple[JointState, np.ndarray]] = []
    p = np.array([np.nan, np.nan])
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
                states.append((st, p))
        except MessageError as exc:
            bad += 1
            log.warning("skipped a malformed message on %s: %s", key, exc)
    return RecordedStates(states, n, bad)


def export_csv(
    mcap_path: Path,
    csv_path: Path,
    drive_gains_nm_per_a: list[float],
    keys: Keys | None = None,
    cycle_range: tuple[int, int] | None = None,
    settle_s: float = DISTURBANCE_SETTLE_S,
    current_lag_cycles: float = CURRENT_LAG_CYCLES,
    recorded: RecordedStates | None = None,
) -> int:
    """Export joint states (+ latest pressures) to the measurement CSV; returns rows written.
    ``recorded``: the recording as :func:`read_states` read it (else it is read here).

    ``cycle_range`` keeps only the controller cycles ``first..last`` (inclusive). Cycles the
    CAN driver answered with a hold, or with a coast the law's next command stepped away from
    (the next JointState's flags and echoed command say so:
    :func:`gateway.disturbed_cycles.disturbed_cycles`), are *disturbed*: they and the cycles up
    to ``settle_s`` after them are left out, which leaves a time gap that the analysis treats
    as a segment boundary; the sidecar lists them.

    The reported current describes ``current_lag_cycles`` of a cycle before the kinematics
    (LTC-1 reports its mean over the cycle: 0.5, PROTOCOL.md §2.1); each row gets the current
    interpolated to its own instant from the next cycle's, so a row whose next cycle was not
    recorded is not exported. Malformed messages are counted and skipped with a warning,
    never exported.
    """
    rec = recorded if recorded is not None else read_states(mcap_path, keys)
    states, n, bad = rec.states, rec.n, rec.bad
    disturbed = disturbed_cycles([st for st, _ in states], cycle_range)
    excluded: set[int] = set()
    for cycle, period in disturbed:
        excluded.update(range(cycle, cycle + 1 + int(np.ceil(settle_s / period))))
    by_cycle = {st.cycle: st for st, _ in states}
    rows: list[np.ndarray] = []
    cycle0: int | None = None
    for st, pressure in states:
        if cycle_range and not cycle_range[0] <= st.cycle <= cycle_range[1]:
            continue
        cycle0 = st.cycle if cycle0 is None else cycle0
        if st.cycle in excluded:
            continue
        current = st.current_a
        if current_lag_cycles:
            nxt = by_cycle.get(st.cycle + 1)
            if nxt is None:
                continue  # the current of this instant is not known
            current = (1 - current_lag_cycles) * current + current_lag_cycles * nxt.current_a
        t = (st.cycle - cycle0) * st.cycle_period_s
        rows.append(np.concatenate([[t], st.q_rad, st.dq_rad_s, current, pressure]))
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
    sidecar = {
        "drive_gains_nm_per_a": list(drive_gains_nm_per_a),
        "source": str(mcap_path),
        "disturbed_cycles": [c for c, _ in disturbed],
        "settle_s": settle_s,
        "current_lag_cycles": current_lag_cycles,
    }
    csv_path.with_suffix(".json").write_text(json.dumps(sidecar))
    if disturbed:
        log.info(
            "%s: %d cycles answered with a hold, or a coast the command stepped away from; "
            "%d cycles after them left out",
            csv_path,
            len(disturbed),
            len(excluded),
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
    p.add_argument(
        "--rotate-mb",
        type=float,
        default=0.0,
        help="start a new file (OUT-0001.mcap, OUT-0002.mcap, ...) every this many MB",
    )
    p.add_argument(
        "--keep", type=int, default=0, help="with --rotate-mb: delete all but the newest N files"
    )


def cli_main(args: argparse.Namespace) -> int:
    if args.rotate_mb < 0 or args.keep < 0 or (args.keep and not args.rotate_mb):
        raise ConfigError("--rotate-mb and --keep: not negative; --keep needs --rotate-mb")
    bus = BusConfig()
    if args.config:
        bus = bus_config_from(load_toml(args.config), str(args.config))
    rotate = int(args.rotate_mb * 1e6)
    rec = BusRecorder(bus.with_overrides(args.bus), args.out, rotate_bytes=rotate, keep=args.keep)
    stop = threading.Event()
    with StopSignals(stop):
        rec.start()
        try:
            stop.wait(args.duration)
        finally:
            rec.stop()
    log.info("%d messages written to %s", rec.count, args.out)
    return 1 if rec.error else 0
