"""Register maps as data: which value lives where, in which encoding, in which unit.

A :class:`Point` is one row of a device manual's register table. ``[[modbus.points]]`` tables in
the cell config become Points, so a new I/O module needs a new table, not new code.

Conventions
-----------
* ``address`` is the **protocol address**: the 0-based number sent on the wire, as in "input
  register 0". The legacy 1-based notation (30001, 40001) is *not* accepted here: subtract
  30001/40001 (input/holding) or 10001/1 (discrete inputs/coils) when copying from such a manual.
* engineering value = raw * ``scale`` + ``offset`` (e.g. a uint16 in mbar with scale 0.001
  gives bar).
* 32-bit values take two consecutive registers. The value's four bytes, most significant first,
  are ``A B C D``:

  ==========  ==========  =================  ===================
  byte_order  word_order  registers [n, n+1]  common name
  ==========  ==========  =================  ===================
  big         big         ``AB``, ``CD``     "ABCD", big-endian
  big         little      ``CD``, ``AB``     "CDAB", word swap
  little      big         ``BA``, ``DC``     "BADC", byte swap
  little      little      ``DC``, ``BA``     "DCBA", little-endian
  ==========  ==========  =================  ===================

  ``byte_order`` is the order of the two bytes inside each 16-bit register; ``word_order`` says
  which register holds the high word (``big``: the first). 16-bit types use ``byte_order`` only.
* ``min``/``max`` are an engineering plausibility range: a decoded value outside it (a broken
  transmitter, a wrong map) raises :class:`~gateway.errors.ModbusReplyError` instead of reaching
  the controller.
"""

from __future__ import annotations

import itertools
import math
import struct
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from typing import NamedTuple, Protocol

from gateway.config import require
from gateway.errors import ConfigError, ModbusReplyError

TABLES = ("input_registers", "holding_registers", "discrete_inputs", "coils")
BIT_TABLES = ("discrete_inputs", "coils")
WRITABLE_TABLES = ("holding_registers", "coils")
#: type → (struct code, number of 16-bit registers)
TYPES: dict[str, tuple[str, int]] = {
    "int16": ("h", 1),
    "uint16": ("H", 1),
    "int32": ("i", 2),
    "uint32": ("I", 2),
    "float32": ("f", 2),
    "bool": ("?", 1),
}
ORDERS = ("big", "little")
_INT_RANGE = {
    "int16": (-(2**15), 2**15 - 1),
    "uint16": (0, 2**16 - 1),
    "int32": (-(2**31), 2**31 - 1),
    "uint32": (0, 2**32 - 1),
}
_FLOAT32_MAX = 3.4028234663852886e38

#: Largest request a read group may grow to (protocol limits: 125 registers, 2000 bits).
MAX_GROUP = {
    "input_registers": 125,
    "holding_registers": 125,
    "discrete_inputs": 2000,
    "coils": 2000,
}
#: Largest register write (function 0x10 takes at most 123 registers).
MAX_WRITE_GROUP = 123


@dataclass(frozen=True)
class Point:
    """One value in a device's Modbus tables (a ``[[modbus.points]]`` entry)."""

    #: Name the adapter looks it up by, e.g. ``p2_bar``.
    name: str
    #: ``input_registers``, ``holding_registers``, ``discrete_inputs`` or ``coils``.
    table: str
    #: Protocol address (0-based, as on the wire) of the first register or bit.
    address: int
    #: ``int16``, ``uint16``, ``int32``, ``uint32``, ``float32`` or ``bool``. ``bool`` is the only
    #: type in bit tables; in a register table it means "register != 0".
    type: str
    #: engineering = raw * scale + offset
    scale: float = 1.0
    offset: float = 0.0
    #: Order of the two bytes inside each register.
    byte_order: str = "big"
    #: Which register of a 32-bit value holds the high word (``big``: the first one).
    word_order: str = "big"
    #: Plausibility range in engineering units; a decoded value outside it is an error.
    min: float | None = None
    max: float | None = None

    def __post_init__(self) -> None:
        where = f"point {self.name!r}"
        require(
            bool(self.name) and self.name.isidentifier(),
            f"{where}.name",
            "must be a non-empty identifier like 'p2_bar'",
        )
        require(self.table in TABLES, f"{where}.table", f"{self.table!r} is not one of {TABLES}")
        require(self.type in TYPES, f"{where}.type", f"{self.type!r} is not one of {list(TYPES)}")
        require(
            self.byte_order in ORDERS, f"{where}.byte_order", f"{self.byte_order!r} not in {ORDERS}"
        )
        require(
            self.word_order in ORDERS, f"{where}.word_order", f"{self.word_order!r} not in {ORDERS}"
        )
        require(
            isinstance(self.address, int)
            and self.address >= 0
            and self.address + self.count - 1 <= 0xFFFF,
            f"{where}.address",
            f"{self.address!r} (+{self.count} registers) is outside 0..65535",
        )
        if self.table in BIT_TABLES:
            require(
                self.type == "bool",
                f"{where}.type",
                f"{self.type!r} in {self.table}: bit tables hold only 'bool'",
            )
        if self.type == "bool":
            require(
                self.scale == 1.0 and self.offset == 0.0 and self.min is None and self.max is None,
                where,
                "a bool point takes no scale, offset, min or max",
            )
            return
        require(
            math.isfinite(self.scale) and self.scale != 0.0,
            f"{where}.scale",
            f"{self.scale!r} must be finite and non-zero",
        )
        require(math.isfinite(self.offset), f"{where}.offset", f"{self.offset!r} must be finite")
        for label, bound in (("min", self.min), ("max", self.max)):
            require(
                bound is None or math.isfinite(bound), f"{where}.{label}", f"{bound!r} not finite"
            )
        if self.min is not None and self.max is not None:
            require(self.min <= self.max, where, f"min {self.min} is greater than max {self.max}")

    @property
    def count(self) -> int:
        """Number of registers (or bits) the point occupies."""
        return 1 if self.table in BIT_TABLES else TYPES[self.type][1]

    @property
    def end(self) -> int:
        """One past the last address the point occupies."""
        return self.address + self.count


def _range(point: Point) -> str:
    lo = "-inf" if point.min is None else f"{point.min:g}"
    hi = "inf" if point.max is None else f"{point.max:g}"
    return f"[{lo}, {hi}]"


def _hex(regs: Iterable[int | bool]) -> str:
    return "[" + ", ".join(f"0x{int(r):04X}" for r in regs) + "]"


def _regs_to_bytes(point: Point, regs: list[int]) -> bytes:
    """Registers → the value's bytes, most significant first (undoes byte and word order)."""
    words = list(regs)
    if point.word_order == "little":
        words.reverse()
    data = b"".join(w.to_bytes(2, "big") for w in words)
    if point.byte_order == "little":
        data = b"".join(data[i : i + 2][::-1] for i in range(0, len(data), 2))
    return data


def _bytes_to_regs(point: Point, data: bytes) -> list[int]:
    """The value's bytes, most significant first → registers in the point's order."""
    if point.byte_order == "little":
        data = b"".join(data[i : i + 2][::-1] for i in range(0, len(data), 2))
    words = [int.from_bytes(data[i : i + 2], "big") for i in range(0, len(data), 2)]
    if point.word_order == "little":
        words.reverse()
    return words


def decode_point(point: Point, regs: list[int] | list[bool]) -> float | bool:
    """Decode one point from its raw registers (or bits) into engineering units.

    :raises ModbusReplyError: wrong number of registers, a register outside 0..65535, NaN or
        infinity, or a value outside the point's ``min``/``max``; the message names the point and
        the raw registers.
    """
    raw = list(regs)
    if len(raw) != point.count:
        raise ModbusReplyError(
            f"point {point.name!r}: got {len(raw)} values {_hex(raw)}, expected {point.count}"
        )
    if point.table in BIT_TABLES:
        return bool(raw[0])
    if any(isinstance(r, bool) or not 0 <= int(r) <= 0xFFFF for r in raw):
        raise ModbusReplyError(f"point {point.name!r}: registers {raw!r} are not 16-bit words")
    if point.type == "bool":
        return raw[0] != 0
    code = TYPES[point.type][0]
    (value,) = struct.unpack(">" + code, _regs_to_bytes(point, [int(r) for r in raw]))
    eng = float(value) * point.scale + point.offset
    where = f"{point.table} {point.address}"
    if not math.isfinite(eng):
        raise ModbusReplyError(
            f"point {point.name!r} ({where}, {point.type}): raw registers {_hex(raw)} decode to "
            f"{eng!r}, not a finite number"
        )
    if (point.min is not None and eng < point.min) or (point.max is not None and eng > point.max):
        raise ModbusReplyError(
            f"point {point.name!r} ({where}, {point.type}): raw registers {_hex(raw)} decode to "
            f"{eng:g}, outside the plausible range {_range(point)}"
        )
    return eng


def encode_point(point: Point, value: float | bool) -> list[int]:
    """Encode an engineering value into the point's raw registers (bits: ``[0]``/``[1]``).

    :raises ValueError: NaN/infinity, a value outside ``min``/``max``, or a raw value that does
        not fit the point's type. Integer types round to the nearest raw step.
    """
    if point.type == "bool":
        if not isinstance(value, bool | int) or value not in (0, 1):
            raise ValueError(f"point {point.name!r}: {value!r} is not a bool")
        return [int(bool(value))]
    value = float(value)
    if not math.isfinite(value):
        raise ValueError(f"point {point.name!r}: refusing to write {value!r}")
    if (point.min is not None and value < point.min) or (
        point.max is not None and value > point.max
    ):
        raise ValueError(f"point {point.name!r}: {value:g} outside its range {_range(point)}")
    raw = (value - point.offset) / point.scale
    code = TYPES[point.type][0]
    if point.type == "float32":
        if abs(raw) > _FLOAT32_MAX:
            raise ValueError(f"point {point.name!r}: raw {raw:g} does not fit float32")
        packed = struct.pack(">f", raw)
    else:
        lo, hi = _INT_RANGE[point.type]
        raw_int = round(raw)
        if not lo <= raw_int <= hi:
            raise ValueError(
                f"point {point.name!r}: {value:g} is raw {raw_int}, outside {point.type} "
                f"range {lo}..{hi}"
            )
        packed = struct.pack(">" + code, raw_int)
    return _bytes_to_regs(point, packed)


class ReadGroup(NamedTuple):
    """One read request covering adjacent points of one table."""

    table: str
    address: int
    count: int
    points: tuple[Point, ...]


class RegisterReader(Protocol):
    """What :class:`RegisterMap` needs from a link (:class:`~drivers.modbus.client.ModbusLink`)."""

    def read_input_registers(self, address: int, count: int) -> list[int]: ...
    def read_holding_registers(self, address: int, count: int) -> list[int]: ...
    def read_discrete_inputs(self, address: int, count: int) -> list[bool]: ...
    def read_coils(self, address: int, count: int) -> list[bool]: ...
    def write_registers(self, address: int, values: list[int]) -> None: ...
    def write_coil(self, address: int, value: bool) -> None: ...


class RegisterMap:
    """A validated set of points, read with as few requests as the map allows.

    Points of one table whose addresses touch are merged into one request (up to the protocol
    limit). Gaps are never bridged: real devices often answer an unmapped address with
    ILLEGAL DATA ADDRESS, which would fail the whole group.

    :param points: the map.
    :param required: names that must be present (the adapter's needs).
    :param where: prefix for error messages, e.g. ``"cell.toml [modbus].points"``.
    :raises ConfigError: duplicate names, overlapping addresses in a table, missing names.
    """

    def __init__(
        self, points: Iterable[Point], required: Iterable[str] = (), where: str = "[modbus].points"
    ) -> None:
        self.points: tuple[Point, ...] = tuple(points)
        self._by_name: dict[str, Point] = {}
        for p in self.points:
            if p.name in self._by_name:
                raise ConfigError(f"{where}: duplicate point name {p.name!r}")
            self._by_name[p.name] = p
        missing = [n for n in required if n not in self._by_name]
        if missing:
            raise ConfigError(
                f"{where}: missing required point(s) {missing}; present: {sorted(self._by_name)}"
            )
        for table in TABLES:
            in_table = sorted((p for p in self.points if p.table == table), key=lambda p: p.address)
            for a, b in itertools.pairwise(in_table):
                if b.address < a.end:
                    raise ConfigError(
                        f"{where}: points {a.name!r} ({table} {a.address}..{a.end - 1}) and "
                        f"{b.name!r} ({table} {b.address}..{b.end - 1}) overlap"
                    )
        self.read_groups: tuple[ReadGroup, ...] = tuple(self._group(self.points, MAX_GROUP))

    def __getitem__(self, name: str) -> Point:
        return self._by_name[name]

    def __contains__(self, name: object) -> bool:
        return name in self._by_name

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(self._by_name)

    @staticmethod
    def _group(points: Iterable[Point], limits: Mapping[str, int]) -> list[ReadGroup]:
        points = tuple(points)
        groups: list[ReadGroup] = []
        for table in TABLES:
            current: list[Point] = []
            for p in sorted((p for p in points if p.table == table), key=lambda p: p.address):
                if current and (
                    p.address != current[-1].end or p.end - current[0].address > limits[table]
                ):
                    groups.append(_make_group(table, current))
                    current = []
                current.append(p)
            if current:
                groups.append(_make_group(table, current))
        return groups

    def decode_group(
        self, group: ReadGroup, raw: list[int] | list[bool]
    ) -> dict[str, float | bool]:
        """Decode every point of ``group`` from the raw values read for it."""
        if len(raw) != group.count:
            raise ModbusReplyError(
                f"{group.table} {group.address}..{group.address + group.count - 1}: "
                f"got {len(raw)} values, expected {group.count}"
            )
        out: dict[str, float | bool] = {}
        for p in group.points:
            start = p.address - group.address
            out[p.name] = decode_point(p, list(raw[start : start + p.count]))
        return out

    def read_all(self, link: RegisterReader) -> dict[str, float | bool]:
        """Read and decode every point (one request per :attr:`read_groups` entry).

        :raises ModbusReplyError: from the link, or when any point fails to decode.
        """
        values: dict[str, float | bool] = {}
        for g in self.read_groups:
            raw: list[int] | list[bool] = getattr(link, f"read_{g.table}")(g.address, g.count)
            values.update(self.decode_group(g, raw))
        return values

    def encode_writes(self, values: Mapping[str, float | bool]) -> list[tuple[str, int, list[int]]]:
        """Encode named values into ``(table, address, raw values)`` write requests.

        Adjacent holding registers are merged into one request, so set-points that sit next to
        each other change together.

        :raises ConfigError: unknown name or a point in a read-only table.
        :raises ValueError: a value the point cannot encode (see :func:`encode_point`).
        """
        points = []
        for name in values:
            if name not in self._by_name:
                raise ConfigError(f"no point named {name!r} to write; known: {sorted(self.names)}")
            p = self._by_name[name]
            if p.table not in WRITABLE_TABLES:
                raise ConfigError(f"point {name!r} is in {p.table}, which cannot be written")
            points.append(p)
        encoded = {p.name: encode_point(p, values[p.name]) for p in points}
        writes: list[tuple[str, int, list[int]]] = []
        for p in sorted((p for p in points if p.table == "coils"), key=lambda p: p.address):
            writes.append(("coils", p.address, encoded[p.name]))
        limits = {"holding_registers": MAX_WRITE_GROUP}
        for g in self._group((p for p in points if p.table == "holding_registers"), limits):
            regs = [r for p in g.points for r in encoded[p.name]]
            writes.append((g.table, g.address, regs))
        return writes

    def write(self, link: RegisterReader, values: Mapping[str, float | bool]) -> None:
        """Encode and write named values (see :meth:`encode_writes`)."""
        for table, address, raw in self.encode_writes(values):
            if table == "coils":
                link.write_coil(address, bool(raw[0]))
            else:
                link.write_registers(address, raw)


def _make_group(table: str, points: list[Point]) -> ReadGroup:
    return ReadGroup(table, points[0].address, points[-1].end - points[0].address, tuple(points))
