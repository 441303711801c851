"""Measurement files for identification: one CSV per recorded trajectory, read and written here.

Format
------
Plain-text CSV (ASCII, ``,`` separated, ``\\n`` or ``\\r\\n`` line ends), one header row of
column names, then one row per sample. Columns, by name (order free, names case-sensitive):

=================  ========  ==================================================================
name               unit      meaning
=================  ========  ==================================================================
``t``              s         sample time; strictly increasing (a repeated time is an error)
``q1`` .. ``qN``   rad       joint positions, joints numbered 1..N in the URDF's chain order
``dq1`` .. ``dqN`` rad/s     joint velocities; optional (derived from q when absent)
``tau1``..``tauN`` N·m       joint-side motor torques, or instead:
``i1`` .. ``iN``   A         motor currents, turned into joint torques ``tau = K i`` with the
                             drive gains K [N·m/A] of ``--drive-gains K1,K2,..`` or, failing
                             that, of a sidecar JSON file beside the CSV with the same stem
                             (``A.csv`` → ``A.json``): ``{"drive_gains_nm_per_a": [K1, ..]}``
``p2``, ``p3``     bar       optional assist-cylinder pressures; ``pK`` belongs to joint K
=================  ========  ==================================================================

Every other column is ignored (it may even hold text). When both ``tau`` and ``i`` columns are
present the torques are used and the currents ignored. Values are decimal numbers (``1``,
``-2.5``, ``3e-4``); NaN and infinities are refused.

Parquet
-------
A Parquet file (``.parquet``, or any name starting and ending with Parquet's ``PAR1`` magic)
holds the same columns by the same names, numbers as float or integer columns (no nulls), one
row per sample. It is read into the same arrays as a CSV and checked by the same code; errors
name the column and the data row (``row R (index R-1)``: rows counted from 1, and pandas'
0-based index) instead of a line. The file-level metadata may carry the sidecar's keys, each
value JSON (``drive_gains_nm_per_a``: ``[K1, ..]``, written by ``leadthrough export``); its
gains come before a sidecar's. :func:`gateway.parquet_file.write_parquet` writes one
(``leadthrough export``); pyarrow is imported only when a Parquet file is read or written.

Errors
------
A bad file raises :class:`~gateway.errors.DataFileError` whose message starts with
``FILE:LINE:`` (line 1 is the header; a Parquet file: ``FILE: row R (index R-1):`` or
``FILE:``): missing required columns, inconsistent joint counts
between q/dq/tau, a row with the wrong number of fields (an empty line, a truncated last
line), an empty or non-numeric value, NaN/inf, and time that does not increase. A last line
without its newline is accepted when its field count is right (a number cut short there cannot
be told from a shorter number).

Speed: the fast path validates the field count of every line with vectorised byte searches and
parses all numbers with one C-speed call; the line-by-line search that names the bad line runs
only once something is known to be wrong.
"""

from __future__ import annotations

import io
import json
import re
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from gateway.errors import ConfigError, DataFileError

SIDECAR_GAINS_KEY = "drive_gains_nm_per_a"
_COLUMN_RE = re.compile(r"^(q|dq|tau|i|p)([1-9][0-9]*)$")
_NUMBER_RE = re.compile(
    rb"^\s*[+-]?(?:\d+\.?\d*(?:[eE][+-]?\d+)?|\.\d+(?:[eE][+-]?\d+)?|nan|inf|infinity)\s*$",
    re.IGNORECASE,
)
_NEWLINE = 10
_COMMA = 44
#: Significant digits written by :func:`write_measurements` (relative precision 1e-12).
WRITE_DIGITS = 12
#: Parquet's magic, the first and the last four bytes of a Parquet file.
PARQUET_MAGIC = b"PAR1"
PARQUET_SUFFIXES = (".parquet", ".pq")


@dataclass(frozen=True)
class Measurements:
    """One recorded trajectory, in SI units; T samples of N joints.

    ``t`` (T,) [s], ``q`` (T, N) [rad], ``dq`` (T, N) [rad/s] or None, ``tau`` (T, N) [N·m]
    joint-side motor torque, ``p`` (T, k) [bar] or None with ``p_joints`` the 1-based joint
    number of each pressure column (``p2`` → 2), ``source`` the file it came from.
    """

    t: np.ndarray
    q: np.ndarray
    dq: np.ndarray | None
    tau: np.ndarray
    p: np.ndarray | None
    source: str
    p_joints: tuple[int, ...] = ()

    def __post_init__(self) -> None:
        t, q, tau = np.asarray(self.t), np.asarray(self.q), np.asarray(self.tau)
        if t.ndim != 1 or q.ndim != 2 or q.shape[0] != t.size or tau.shape != q.shape:
            raise ValueError(f"inconsistent shapes t {t.shape}, q {q.shape}, tau {tau.shape}")
        if self.dq is not None and np.shape(self.dq) != q.shape:
            raise ValueError(f"dq shape {np.shape(self.dq)} != q shape {q.shape}")
        if self.p is None:
            if self.p_joints:
                raise ValueError("p_joints given without pressures")
        elif np.shape(self.p) != (t.size, len(self.p_joints)):
            raise ValueError(f"p shape {np.shape(self.p)} needs one column per p_joints")

    @property
    def n_joints(self) -> int:
        return int(self.q.shape[1])

    @property
    def n_samples(self) -> int:
        return int(self.t.size)


@dataclass(frozen=True)
class _Layout:
    """Column indices of one file's header."""

    names: tuple[str, ...]
    t: int
    q: tuple[int, ...]
    dq: tuple[int, ...]
    tau: tuple[int, ...]
    current: tuple[int, ...]
    p: tuple[int, ...]
    p_joints: tuple[int, ...]

    @property
    def used(self) -> tuple[int, ...]:
        torque = self.tau if self.tau else self.current
        return (self.t, *self.q, *self.dq, *torque, *self.p)


def _fail(path: Path, line: int, message: str) -> DataFileError:
    return DataFileError(f"{path}:{line}: {message}")


@dataclass(frozen=True)
class _Where:
    """How an error names its place: a CSV's line (line 1 the header), a Parquet file's row."""

    path: Path
    parquet: bool = False

    def header(self, message: str) -> DataFileError:
        """An error of the columns (the CSV's header line)."""
        if self.parquet:
            return DataFileError(f"{self.path}: {message}")
        return _fail(self.path, 1, message)

    def row(self, k: int, message: str) -> DataFileError:
        """An error of data row ``k`` (0-based)."""
        if self.parquet:
            return DataFileError(f"{self.path}: row {k + 1} (index {k}): {message}")
        return _fail(self.path, k + 2, message)


def _parse_header(where: _Where, names: Sequence[str]) -> _Layout:
    seen: dict[str, int] = {}
    for k, name in enumerate(names):
        if name == "":
            continue  # unnamed column: ignored like any other unknown one
        if name in seen:
            raise where.header(f"column {name!r} appears twice (columns {seen[name] + 1}, {k + 1})")
        seen[name] = k
    if "t" not in seen:
        raise where.header("missing required column 't' (time [s])")
    groups: dict[str, dict[int, int]] = {g: {} for g in ("q", "dq", "tau", "i", "p")}
    for name, k in seen.items():
        m = _COLUMN_RE.match(name)
        if m:
            groups[m.group(1)][int(m.group(2))] = k
    q = groups["q"]
    if not q:
        raise where.header("missing required columns q1..qN (joint positions [rad])")
    n = max(q)

    def complete(group: str, what: str) -> tuple[int, ...]:
        idx = groups[group]
        if not idx:
            return ()
        if set(idx) != set(range(1, n + 1)):
            have = ", ".join(f"{group}{j}" for j in sorted(idx))
            raise where.header(
                f"inconsistent joint count: q1..q{n} give {n} joints but {what} columns are "
                f"{have} (need {group}1..{group}{n})"
            )
        return tuple(idx[j] for j in range(1, n + 1))

    if set(q) != set(range(1, n + 1)):
        missing = sorted(set(range(1, n + 1)) - set(q))
        raise where.header(f"joint position columns {['q' + str(j) for j in missing]} missing")
    dq = complete("dq", "velocity")
    tau = complete("tau", "torque")
    current = () if tau else complete("i", "current")
    if not tau and not current:
        raise where.header(
            f"missing torque columns: need tau1..tau{n} [N·m] or currents i1..i{n} [A]"
        )
    p_numbers = tuple(sorted(groups["p"]))
    for j in p_numbers:
        if j > n:
            raise where.header(f"pressure column p{j} names joint {j}, but there are {n} joints")
    return _Layout(
        names=tuple(names),
        t=seen["t"],
        q=tuple(q[j] for j in range(1, n + 1)),
        dq=dq,
        tau=tau,
        current=current,
        p=tuple(groups["p"][j] for j in p_numbers),
        p_joints=p_numbers,
    )


def _lines_well_formed(body: bytes, n_fields: int) -> tuple[bool, int]:
    """Vectorised check that every line of ``body`` has ``n_fields`` fields; also row count."""
    buf = np.frombuffer(body, dtype=np.uint8)
    newlines = np.flatnonzero(buf == _NEWLINE)
    rows = newlines.size + 1
    commas = np.flatnonzero(buf == _COMMA)
    per_line = n_fields - 1
    if commas.size != rows * per_line:
        return False, rows
    if per_line == 0:
        return True, rows
    starts = np.concatenate(([0], newlines + 1))
    ends = np.concatenate((newlines, [buf.size]))
    c = commas.reshape(rows, per_line)
    # With the total right and commas sorted, each line holds exactly its share of commas iff
    # its first assigned comma starts after the line start and the last ends before its end.
    ok = bool(np.all(c[:, 0] >= starts) and np.all(c[:, -1] < ends))
    return ok, rows


def _locate_error(
    path: Path, body: bytes, layout: _Layout, ends_with_newline: bool, columns: Sequence[int]
) -> DataFileError:
    """Slow path: find the first malformed line / value and name it."""
    n_fields = len(layout.names)
    lines = body.split(b"\n")
    wanted = set(columns)
    for row, line in enumerate(lines):
        lineno = row + 2
        fields = line.split(b",")
        if len(fields) != n_fields:
            if not line.strip():
                return _fail(path, lineno, f"empty line (expected {n_fields} fields)")
            if row == len(lines) - 1 and not ends_with_newline and len(fields) < n_fields:
                return _fail(
                    path,
                    lineno,
                    f"truncated last line: {len(fields)} of {n_fields} fields and no line end",
                )
            return _fail(
                path, lineno, f"wrong column count: {len(fields)} fields, header has {n_fields}"
            )
        for k, field in enumerate(fields):
            if k not in wanted:
                continue
            name = layout.names[k]
            if not field.strip():
                return _fail(path, lineno, f"empty value in column {name!r}")
            if not _NUMBER_RE.match(field):
                text = field.decode("ascii", errors="replace").strip()
                return _fail(path, lineno, f"non-numeric value {text!r} in column {name!r}")
    return DataFileError(f"{path}: could not parse the numbers (no single bad line found)")


def _parse_body(path: Path, body: bytes, layout: _Layout, ends_with_newline: bool) -> np.ndarray:
    """Numbers of the used columns, shape (rows, len(layout.used))."""
    n_fields = len(layout.names)
    ok, rows = _lines_well_formed(body, n_fields)
    if not ok:
        raise _locate_error(path, body, layout, ends_with_newline, range(n_fields))
    values: np.ndarray | None
    try:
        values = np.fromstring(body.replace(b"\n", b",").decode("ascii"), dtype=float, sep=",")
    except (ValueError, UnicodeDecodeError):
        values = None
    if values is not None and values.size == rows * n_fields:
        return values.reshape(rows, n_fields)[:, list(layout.used)]
    # Something is not a number. If it is only in ignored columns, parse the used ones alone.
    try:
        used = np.loadtxt(
            io.StringIO(body.decode("ascii")),
            delimiter=",",
            usecols=layout.used,
            comments=None,
            dtype=float,
            ndmin=2,
        )
    except (ValueError, UnicodeDecodeError):
        raise _locate_error(path, body, layout, ends_with_newline, layout.used) from None
    if used.shape != (rows, len(layout.used)):
        raise _locate_error(path, body, layout, ends_with_newline, layout.used)
    return used


def _gains_array(source: str, gains: Any) -> np.ndarray:
    """``gains`` of a sidecar or a Parquet file's metadata (``source`` names it) as an array."""
    try:
        arr = np.asarray(gains, dtype=float)
    except (TypeError, ValueError):
        raise DataFileError(f"{source}: {SIDECAR_GAINS_KEY} {gains!r} is not numbers") from None
    if arr.ndim != 1 or not np.all(np.isfinite(arr)) or np.any(arr == 0):
        raise DataFileError(
            f"{source}: {SIDECAR_GAINS_KEY} {gains!r} must be a list of finite non-zero numbers"
        )
    return arr


def _sidecar_gains(path: Path) -> np.ndarray | None:
    sidecar = path.with_suffix(".json")
    if not sidecar.is_file():
        return None
    try:
        doc = json.loads(sidecar.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise DataFileError(f"{sidecar}: not readable JSON: {exc}") from None
    gains = doc.get(SIDECAR_GAINS_KEY) if isinstance(doc, dict) else None
    if gains is None:
        raise DataFileError(f"{sidecar}: missing key {SIDECAR_GAINS_KEY!r} (list of N·m/A)")
    return _gains_array(str(sidecar), gains)


def _drive_gains(
    where: _Where, n: int, drive_gains: Sequence[float] | None, embedded: np.ndarray | None
) -> np.ndarray:
    """The drive gains [N·m/A]: ``--drive-gains``, else the file's own (Parquet metadata,
    ``embedded``), else the sidecar JSON's."""
    path = where.path
    if drive_gains is not None:
        gains = np.asarray(drive_gains, dtype=float)
        if gains.shape != (n,) or not np.all(np.isfinite(gains)) or np.any(gains == 0):
            raise ConfigError(
                f"--drive-gains: {list(drive_gains)} must be {n} finite non-zero values "
                f"[N·m/A] for the {n} joints of {path}"
            )
        return gains
    if embedded is not None:
        if embedded.shape != (n,):
            raise where.header(
                f"metadata {SIDECAR_GAINS_KEY} has {embedded.size} values for {n} joints"
            )
        return embedded
    gains = _sidecar_gains(path)
    if gains is None:
        raise where.header(
            f"has motor currents i1..i{n} but no drive gains: give --drive-gains "
            f"K1,..,K{n} or write {path.with_suffix('.json').name} with "
            f'{{"{SIDECAR_GAINS_KEY}": [..]}}'
        )
    if gains.shape != (n,):
        raise DataFileError(
            f"{path.with_suffix('.json')}: {SIDECAR_GAINS_KEY} has {gains.size} values, "
            f"{path} has {n} joints"
        )
    return gains


def is_parquet(path: str | Path, head: bytes = b"", tail: bytes = b"") -> bool:
    """True when ``path`` is to be read as Parquet: by its suffix, or by the magic of its
    first and last bytes (``head``, ``tail``) whatever its name."""
    if Path(path).suffix.lower() in PARQUET_SUFFIXES:
        return True
    return head.startswith(PARQUET_MAGIC) and tail.endswith(PARQUET_MAGIC)


def read_measurements(path: str | Path, drive_gains: Sequence[float] | None = None) -> Measurements:
    """Read and validate one measurement file, CSV or Parquet (format in the module docstring).

    ``drive_gains`` [N·m/A], one per joint, turn ``i`` columns into torques; without it a
    Parquet file's own metadata, then the sidecar ``<stem>.json`` is used. Raises
    :class:`DataFileError` (file and line, or row, in the message) for a bad file,
    :class:`ConfigError` for unusable ``drive_gains``.
    """
    path = Path(path)
    try:
        raw = path.read_bytes()
    except OSError as exc:
        raise DataFileError(f"{path}: cannot read: {exc.strerror or exc}") from None
    if is_parquet(path, raw[:4], raw[-4:]):
        where = _Where(path, parquet=True)
        layout, data, embedded = _read_parquet(where, raw)
        return _measurements(where, layout, data, drive_gains, embedded)
    if raw.startswith(b"\xef\xbb\xbf"):
        raw = raw[3:]
    if b"\r" in raw:
        raw = raw.replace(b"\r\n", b"\n")
        if b"\r" in raw:
            line = raw[: raw.index(b"\r")].count(b"\n") + 1
            raise _fail(path, line, "stray carriage return (\\r) inside a line")
    if not raw.strip():
        raise _fail(path, 1, "empty file: no header")
    header_end = raw.find(b"\n")
    if header_end < 0 or not raw[header_end + 1 :].strip(b"\n"):
        raise _fail(path, 1, "no data rows after the header")
    try:
        header = raw[:header_end].decode("ascii")
    except UnicodeDecodeError:
        raise _fail(path, 1, "header is not ASCII text") from None
    where = _Where(path)
    layout = _parse_header(where, [c.strip() for c in header.split(",")])
    body = raw[header_end + 1 :]
    ends_with_newline = body.endswith(b"\n")
    if ends_with_newline:
        body = body[:-1]
    data = _parse_body(path, body, layout, ends_with_newline)
    return _measurements(where, layout, data, drive_gains, None)


def _measurements(
    where: _Where,
    layout: _Layout,
    data: np.ndarray,
    drive_gains: Sequence[float] | None,
    embedded_gains: np.ndarray | None,
) -> Measurements:
    """The checks every file passes, CSV or Parquet, on ``data`` (rows, ``layout.used``)."""
    finite = np.isfinite(data)
    if not finite.all():
        row, col = np.argwhere(~finite)[0]
        name = layout.names[layout.used[col]]
        value = float(data[row, col])
        raise where.row(int(row), f"value {value!r} in column {name!r} not finite")
    n_q = len(layout.q)
    t = data[:, 0].copy()
    bad = np.flatnonzero(np.diff(t) <= 0)
    if bad.size:
        k = int(bad[0]) + 1
        kind = "repeated" if t[k] == t[k - 1] else "non-monotonic (going back)"
        now, before = float(t[k]), float(t[k - 1])
        raise where.row(k, f"time t={now!r} s {kind}: previous row has t={before!r} s")
    col = 1
    q = data[:, col : col + n_q].copy()
    col += n_q
    dq = None
    if layout.dq:
        dq = data[:, col : col + n_q].copy()
        col += n_q
    torque = data[:, col : col + n_q].copy()
    col += n_q
    if not layout.tau:
        torque = torque * _drive_gains(where, n_q, drive_gains, embedded_gains)
    p = data[:, col:].copy() if layout.p else None
    return Measurements(
        t=t, q=q, dq=dq, tau=torque, p=p, source=str(where.path), p_joints=layout.p_joints
    )


def _read_parquet(where: _Where, raw: bytes) -> tuple[_Layout, np.ndarray, np.ndarray | None]:
    """A Parquet file's used columns as the CSV reader's array (rows, ``layout.used``), its
    layout, and the drive gains of its metadata (None when it has none)."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    try:
        pf = pq.ParquetFile(pa.BufferReader(raw))
        names = pf.schema_arrow.names
    except (pa.ArrowException, OSError, ValueError) as exc:
        raise where.header(f"not a readable Parquet file: {exc}") from None
    layout = _parse_header(where, names)
    if pf.metadata.num_rows == 0:
        raise where.header("no data rows")
    try:
        table = pf.read(columns=[names[k] for k in layout.used])
    except (pa.ArrowException, OSError, ValueError) as exc:
        raise where.header(f"cannot read its columns: {exc}") from None
    columns = []
    for name, column in zip(table.column_names, table.columns, strict=True):
        kind = column.type
        if not (pa.types.is_floating(kind) or pa.types.is_integer(kind)):
            raise where.header(f"column {name!r} holds {kind}, not numbers")
        if column.null_count:
            nulls = column.is_null().to_numpy(zero_copy_only=False)
            raise where.row(int(np.flatnonzero(nulls)[0]), f"empty value in column {name!r}")
        columns.append(np.asarray(column.to_numpy(), dtype=np.float64))
    metadata = pf.schema_arrow.metadata or {}
    gains = metadata.get(SIDECAR_GAINS_KEY.encode())
    embedded = None
    if gains is not None:
        try:
            value = json.loads(gains)
        except (UnicodeDecodeError, json.JSONDecodeError):
            raise where.header(f"metadata {SIDECAR_GAINS_KEY} {gains!r} is not JSON") from None
        embedded = _gains_array(f"{where.path}: metadata", value)
    return layout, np.column_stack(columns), embedded


def write_measurements(path: str | Path, m: Measurements, digits: int = WRITE_DIGITS) -> None:
    """Write ``m`` in the format of the module docstring (torques as ``tau`` columns).

    Numbers carry ``digits`` significant digits; :func:`read_measurements` reads the file back
    to that relative precision.
    """
    n = m.n_joints
    names = ["t", *(f"q{j}" for j in range(1, n + 1))]
    blocks = [m.t[:, None], m.q]
    if m.dq is not None:
        names += [f"dq{j}" for j in range(1, n + 1)]
        blocks.append(m.dq)
    names += [f"tau{j}" for j in range(1, n + 1)]
    blocks.append(m.tau)
    if m.p is not None:
        names += [f"p{j}" for j in m.p_joints]
        blocks.append(m.p)
    data = np.hstack([np.asarray(b, dtype=float) for b in blocks])
    row_fmt = ",".join([f"%.{digits}g"] * data.shape[1])
    chunk = 50_000
    with Path(path).open("w", encoding="ascii", newline="\n") as fh:
        fh.write(",".join(names) + "\n")
        for start in range(0, data.shape[0], chunk):
            rows = map(tuple, data[start : start + chunk].tolist())
            fh.write("\n".join(map(row_fmt.__mod__, rows)) + "\n")
