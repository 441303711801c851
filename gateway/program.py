"""Taught programs: what lead-through teaching leaves behind, one JSON object per line.

A program file (``NAME.jsonl``, UTF-8, one JSON object per line, format
``leadthrough-program`` version 1) is written by the gateway while it teaches and read by
``leadthrough program`` and ``leadthrough replay``::

    {"type": "header", "format": "leadthrough-program", "version": 1, "created_utc": "...",
     "joints": ["j1", ...], "units": {"t": "s", "q": "rad"}, "cell": "cell.toml"}
    {"type": "teach", "event": "start", "t": 12.3}            # the enabling device held
    {"type": "trace", "t": 12.31, "cycle": 3075, "q": [...]}  # joint positions while teaching
    {"type": "mark", "index": 1, "t": 14.0, "cycle": 3500, "q": [...], "label": "", "source":
     "cli"}                                                    # a waypoint the operator marked
    {"type": "teach", "event": "end", "t": 20.0, "reason": "enabling device released"}

``t`` is the CAN driver's monotonic clock of the joint state [s], ``cycle`` the controller's
cycle counter, ``q`` the measured joint positions [rad]. The trace is the newest joint state of
each of the CAN driver's state windows (``[can] state_window_s``, 50 Hz by default), taken at
the gateway's tick only while TEACHING; a gap between an ``end`` and the next ``start`` is not
part of the path. Marks are numbered from 1 in the order made.

Durability: every mark is written, flushed and ``fsync``-ed before the operator's command is
answered, so killing any process afterwards loses no mark. Trace lines are flushed and
``fsync``-ed at least every :data:`TRACE_SYNC_S`: a crash loses at most that much trace. A
crash mid-write leaves at most one incomplete last line, which :func:`read_program` drops with
a warning; any other malformed line is an error that names the line.
"""

from __future__ import annotations

import contextlib
import json
import math
import os
import time
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path
from typing import IO, Any

import numpy as np

from gateway.errors import LeadthroughError

#: default tool speed of a replay [mm/s] (the paper's spray path: 100 mm/s)
DEFAULT_SPEED_MM_S = 100.0
#: highest tool speed a replay may ask for [mm/s] (ISO 10218-1 reduced speed)
MAX_SPEED_MM_S = 250.0
#: no joint of a replay (its approaches included) moves faster [rad/s]: ~17 °/s, 0.3 m/s at
#: 1 m from the axis; a taught segment that would need more is slowed down as a whole
MAX_JOINT_SPEED_RAD_S = 0.3

FORMAT = "leadthrough-program"
VERSION = 1
#: trace lines reach the disk at least this often [s]
TRACE_SYNC_S = 1.0
#: longest mark label [characters]
MAX_LABEL = 200


class ProgramError(LeadthroughError):
    """A program file that cannot be read or written as asked."""


@dataclass(frozen=True)
class Mark:
    index: int  #: 1-based, in the order made
    t_s: float
    cycle: int
    q_rad: np.ndarray
    label: str = ""
    source: str = "cli"  #: "cli" (operator command) or "handle" (teach handle button)


@dataclass
class Program:
    """A program as read back: the trace in teaching segments, and the marks."""

    path: Path
    header: dict[str, Any]
    t_s: np.ndarray  #: (T,) trace times [s]
    cycle: np.ndarray  #: (T,) controller cycles
    q_rad: np.ndarray  #: (T, n) trace positions [rad]
    segment: np.ndarray  #: (T,) teaching segment of each trace sample, 0-based
    marks: list[Mark] = field(default_factory=list)
    #: why the file was not complete (e.g. a cut last line); empty when it was
    warnings: list[str] = field(default_factory=list)

    @property
    def joints(self) -> list[str]:
        return list(self.header["joints"])

    @property
    def n_segments(self) -> int:
        return int(self.segment.max()) + 1 if self.segment.size else 0

    def segments(self) -> list[tuple[np.ndarray, np.ndarray]]:
        """(t, q) of each teaching segment that has trace samples, in order."""
        return [
            (self.t_s[self.segment == k], self.q_rad[self.segment == k])
            for k in range(self.n_segments)
            if np.any(self.segment == k)
        ]


def _vector(value: Any, n: int, where: str) -> np.ndarray:
    if not isinstance(value, list) or len(value) != n:
        raise ProgramError(f"{where}: 'q' must be a list of {n} numbers, got {value!r:.80}")
    try:
        arr = np.array(value, dtype=float)
    except (TypeError, ValueError) as exc:
        raise ProgramError(f"{where}: 'q' must be numbers: {exc}") from None
    if not np.all(np.isfinite(arr)):
        raise ProgramError(f"{where}: 'q' has a non-finite value {value}")
    return arr


def _number(obj: dict, key: str, where: str) -> float:
    v = obj.get(key)
    if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v):
        raise ProgramError(f"{where}: {key!r} must be a finite number, got {v!r}")
    return float(v)


def _integer(obj: dict, key: str, where: str) -> int:
    v = obj.get(key)
    if isinstance(v, bool) or not isinstance(v, int):
        raise ProgramError(f"{where}: {key!r} must be a whole number, got {v!r}")
    return v


def read_program(path: str | Path) -> Program:
    """Read a program file (module docstring). Raises :class:`ProgramError` naming the file
    and line of the first problem; an incomplete *last* line (a crash mid-write) is dropped
    and reported in ``Program.warnings``."""
    path = Path(path)
    try:
        raw = path.read_bytes()
    except OSError as exc:
        raise ProgramError(f"{path}: cannot read program: {exc.strerror or exc}") from None
    lines = raw.split(b"\n")
    warnings = []
    if lines and lines[-1] == b"":
        lines.pop()
    elif lines:
        warnings.append(
            f"{path}: line {len(lines)} is incomplete (the writer stopped mid-line) and was dropped"
        )
        lines.pop()
    if not lines:
        raise ProgramError(f"{path}: empty program (no header line)")
    header: dict[str, Any] | None = None
    n = 0
    t, cyc, q, seg, marks = [], [], [], [], []
    segment, open_ = -1, False
    for no, line in enumerate(lines, 1):
        where = f"{path}:{no}"
        try:
            obj = json.loads(line.decode("utf-8"))
        except (UnicodeDecodeError, json.JSONDecodeError) as exc:
            raise ProgramError(f"{where}: not a JSON object: {exc}") from None
        if not isinstance(obj, dict):
            raise ProgramError(f"{where}: not a JSON object")
        kind = obj.get("type")
        if header is None:
            if kind != "header" or obj.get("format") != FORMAT:
                raise ProgramError(f"{where}: the first line must be a {FORMAT!r} header")
            if obj.get("version") != VERSION:
                raise ProgramError(
                    f"{where}: format version {obj.get('version')!r}; this reader knows {VERSION}"
                )
            joints = obj.get("joints")
            if not isinstance(joints, list) or not joints:
                raise ProgramError(f"{where}: header 'joints' must be a non-empty list")
            header, n = obj, len(joints)
        elif kind == "teach":
            event = obj.get("event")
            if event == "start":
                segment, open_ = segment + 1, True
            elif event == "end":
                open_ = False
            else:
                raise ProgramError(f"{where}: teach event {event!r} must be 'start' or 'end'")
        elif kind == "trace":
            if not open_:
                raise ProgramError(f"{where}: trace sample outside a teach start/end")
            t.append(_number(obj, "t", where))
            cyc.append(_integer(obj, "cycle", where))
            q.append(_vector(obj.get("q"), n, where))
            seg.append(segment)
        elif kind == "mark":
            index = _integer(obj, "index", where)
            if index != len(marks) + 1:
                raise ProgramError(f"{where}: mark {index} follows mark {len(marks)}")
            marks.append(
                Mark(
                    index,
                    _number(obj, "t", where),
                    _integer(obj, "cycle", where),
                    _vector(obj.get("q"), n, where),
                    str(obj.get("label", "")),
                    str(obj.get("source", "cli")),
                )
            )
        else:
            raise ProgramError(f"{where}: unknown line type {kind!r}")
    assert header is not None
    t_arr = np.array(t, dtype=float)
    if t_arr.size > 1 and np.any(np.diff(t_arr) <= 0):
        bad = int(np.flatnonzero(np.diff(t_arr) <= 0)[0]) + 1
        raise ProgramError(f"{path}: trace time does not increase at sample {bad + 1}")
    return Program(
        path,
        header,
        t_arr,
        np.array(cyc, dtype=np.int64),
        np.array(q, dtype=float).reshape(-1, n),
        np.array(seg, dtype=np.int64),
        marks,
        warnings,
    )


def write_csv(program: Program, out: str | Path) -> Path:
    """The trace as CSV (``t_s, segment, cycle, <joint>_rad..., mark``: the mark index on the
    trace sample nearest to each mark, else empty) for a spreadsheet or ``analyze``."""
    out = Path(out)
    mark_at: dict[int, int] = {}
    if program.t_s.size:
        for m in program.marks:
            mark_at[int(np.argmin(np.abs(program.t_s - m.t_s)))] = m.index
    with out.open("w", encoding="utf-8") as f:
        f.write(",".join(["t_s", "segment", "cycle", *(f"{j}_rad" for j in program.joints)]))
        f.write(",mark\n")
        for k in range(program.t_s.size):
            row = [f"{program.t_s[k]:.6f}", str(program.segment[k]), str(program.cycle[k])]
            row += [f"{v:.9g}" for v in program.q_rad[k]]
            row.append(str(mark_at.get(k, "")))
            f.write(",".join(row) + "\n")
    return out


class ProgramWriter:
    """Appends a teaching session to a program file (module docstring); one per session.

    ``open`` creates the file (refuses an existing one: a program is never overwritten) and
    syncs its header and directory entry to disk. Not thread-safe: the gateway calls it from
    the one thread that owns the file (gateway/program_thread.py).
    """

    def __init__(self, path: str | Path, joints: list[str], cell: str = "") -> None:
        self.path = Path(path)
        self.joints = list(joints)
        self.cell = cell
        self.n_marks = 0
        self.n_trace = 0
        self.teaching = False
        self._f: IO[str] | None = None
        self._synced_s = 0.0
        self._last_cycle: int | None = None
        self._last_t = -math.inf

    @property
    def is_open(self) -> bool:
        return self._f is not None

    def open(self) -> None:
        self.path.parent.mkdir(parents=True, exist_ok=True)
        try:
            self._f = self.path.open("x", encoding="utf-8")
        except FileExistsError:
            raise ProgramError(f"{self.path}: a program of that name exists") from None
        except OSError as exc:
            raise ProgramError(f"{self.path}: cannot create program: {exc.strerror}") from None
        header = {
            "type": "header",
            "format": FORMAT,
            "version": VERSION,
            "created_utc": datetime.now(UTC).isoformat(timespec="seconds"),
            "joints": self.joints,
            "units": {"t": "s", "q": "rad"},
            "cell": self.cell,
        }
        self._line(header)
        self._sync()
        try:
            fd = os.open(self.path.parent, os.O_RDONLY)
        except OSError:
            return
        try:
            os.fsync(fd)
        finally:
            os.close(fd)

    def _line(self, obj: dict) -> None:
        if self._f is None:
            raise ProgramError(f"{self.path}: program is not open")
        try:
            self._f.write(json.dumps(obj, separators=(",", ":"), allow_nan=False) + "\n")
        except OSError as exc:
            self._broken(exc)

    def _sync(self) -> None:
        assert self._f is not None
        try:
            self._f.flush()
            os.fsync(self._f.fileno())
        except OSError as exc:
            self._broken(exc)
        self._synced_s = time.monotonic()

    def _broken(self, exc: OSError) -> None:
        """The disk refused a write: the program ends here (what is on disk stays readable,
        at most its last line cut), and the caller learns why."""
        f, self._f = self._f, None
        if f is not None:
            with contextlib.suppress(OSError):
                f.close()
        raise ProgramError(f"{self.path}: writing the program failed: {exc}") from None

    def teach(self, start: bool, t_s: float, reason: str = "") -> None:
        """A teaching segment starts (the enabling device held) or ends."""
        if start == self.teaching:
            return
        self.teaching = start
        obj: dict[str, Any] = {"type": "teach", "event": "start" if start else "end", "t": t_s}
        if reason:
            obj["reason"] = reason
        self._line(obj)
        self._last_cycle = None
        self._sync()

    def trace(self, t_s: float, cycle: int, q_rad: np.ndarray) -> None:
        """One trace sample while teaching (a cycle already traced is skipped); synced to disk
        at least every :data:`TRACE_SYNC_S`."""
        if not self.teaching or cycle == self._last_cycle or t_s <= self._last_t:
            return
        q = np.asarray(q_rad, dtype=float)
        if q.shape != (len(self.joints),) or not (np.all(np.isfinite(q)) and math.isfinite(t_s)):
            raise ProgramError(
                f"trace sample t={t_s} q={q!r} is not {len(self.joints)} finite values"
            )
        self._last_cycle, self._last_t = cycle, t_s
        self._line({"type": "trace", "t": t_s, "cycle": cycle, "q": _rounded(q_rad)})
        self.n_trace += 1
        if time.monotonic() - self._synced_s >= TRACE_SYNC_S:
            self._sync()

    def mark(self, t_s: float, cycle: int, q_rad: np.ndarray, label: str, source: str) -> Mark:
        """Record a waypoint; on disk (fsync-ed) when this returns."""
        if len(label) > MAX_LABEL or not label.isprintable():
            raise ProgramError(f"mark label must be at most {MAX_LABEL} printable characters")
        q = np.asarray(q_rad, dtype=float)
        if q.shape != (len(self.joints),) or not np.all(np.isfinite(q)):
            raise ProgramError(f"mark position {q!r} is not {len(self.joints)} finite values")
        m = Mark(self.n_marks + 1, float(t_s), int(cycle), q.copy(), label, source)
        self._line(
            {"type": "mark", "index": m.index, "t": m.t_s, "cycle": m.cycle,
             "q": _rounded(q), "label": label, "source": source}
        )  # fmt: skip
        self._sync()
        self.n_marks += 1
        return m

    def close(self, t_s: float | None = None, reason: str = "") -> None:
        if self._f is None:
            return
        try:
            if self.teaching and t_s is not None:
                self.teach(False, t_s, reason)
            self._sync()
        finally:
            self._f.close()
            self._f = None


def _rounded(q: np.ndarray) -> list[float]:
    # 1e-9 rad is far below any encoder count; keeps lines short and exact on read-back
    return [round(float(v), 9) for v in q]


#: program names the operator may give: no path separators, no leading dot
_NAME_CHARS = set("abcdefghijklmnopqrstuvwxyzABCDEFGHIJKLMNOPQRSTUVWXYZ0123456789._-")


def program_path(program_dir: str | Path, name: str | None) -> Path:
    """Where program ``name`` lives (``program_dir/NAME.jsonl``; None: a name from the UTC time).
    Raises :class:`ProgramError` for a name that is not 1-64 of ``[A-Za-z0-9._-]`` starting
    with a letter or digit, or a program that exists already."""
    if name is None:
        name = "teach-" + datetime.now(UTC).strftime("%Y%m%d-%H%M%S")
    if name.endswith(".jsonl"):
        name = name[: -len(".jsonl")]
    if not (0 < len(name) <= 64 and set(name) <= _NAME_CHARS and name[0].isalnum()):
        raise ProgramError(
            f"program name {name!r}: use 1-64 letters, digits, '.', '_' or '-', starting with a "
            "letter or digit"
        )
    path = Path(program_dir) / f"{name}.jsonl"
    if path.exists():
        raise ProgramError(f"program {path} exists; choose another name")
    return path


class TeachRecorder:
    """The gateway's side of a taught program: one program per start → stop session, created
    when teaching first begins (a session that never taught leaves no file), a teaching segment
    per stretch of TEACHING, the newest joint state each gateway tick as the trace, and the
    operator's marks. Not thread-safe: the gateway calls it from the one thread that owns the
    file (gateway/program_thread.py), never from its tick."""

    def __init__(self, cell: str = "") -> None:
        self.cell = cell
        self.pending: Path | None = None  #: the session's program, before teaching began
        self.writer: ProgramWriter | None = None
        self.last: Path | None = None  #: the last program closed

    def prepare(self, path: Path) -> None:
        """A session starts (operator `start`): its program will be ``path``."""
        if self.writer is None:
            self.pending = path

    @property
    def path(self) -> Path | None:
        return self.writer.path if self.writer is not None else self.pending

    def follow(self, teaching: bool, session: bool, reason: str, t_s: float | None,
               cycle: int | None, q_rad: np.ndarray | None) -> None:  # fmt: skip
        """One gateway tick: ``teaching`` (lifecycle TEACHING), ``session`` (not STOPPED or
        FAULT), and the newest joint state (None: none yet)."""
        w = self.writer
        if not session:
            if w is not None:
                w.close(t_s, reason)
                self.last, self.writer = w.path, None
            self.pending = None
            return
        if teaching and w is None and self.pending is not None and q_rad is not None:
            w = ProgramWriter(self.pending, [f"j{k + 1}" for k in range(len(q_rad))], self.cell)
            w.open()
            self.writer, self.pending = w, None
        if w is None or t_s is None:
            return
        w.teach(teaching, t_s, "" if teaching else reason)
        if teaching and cycle is not None and q_rad is not None:
            w.trace(t_s, cycle, q_rad)

    def mark(self, t_s: float, cycle: int, q_rad: np.ndarray, label: str, source: str) -> Mark:
        if self.writer is None:
            raise ProgramError(
                "no program is being taught: `leadthrough start`, hold the enabling device, "
                "then mark"
            )
        return self.writer.mark(t_s, cycle, q_rad, label, source)

    def status(self) -> dict[str, Any]:
        w = self.writer
        return {
            "path": None if self.path is None else str(self.path),
            "open": w is not None,
            "marks": 0 if w is None else w.n_marks,
            "trace_samples": 0 if w is None else w.n_trace,
            "last_closed": None if self.last is None else str(self.last),
        }

    def close(self, t_s: float | None, reason: str) -> None:
        self.follow(False, False, reason, t_s, None, None)
