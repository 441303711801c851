"""Compiled codecs for DBC messages: cantools reads the DBC, generated code does the bits.

The DBC stays the source of truth. At start-up :func:`compile_message` turns one cantools
``Message`` into a :class:`MessageCodec`: a Python encode and a decode function generated for
that one layout, with every shift, mask, scale, offset and limit inlined as a constant. A cycle's
frames then cost a few integer operations each instead of cantools' generic path (bitstruct,
dictionaries, per-signal conversion objects): see ``python -m drivers.can.codec_bench``.

What it supports is what our DBCs use (``ltc_v1.dbc``, ``ltc_fd_v1.dbc``): little-endian
(Intel, ``@1``) integer signals of any bit position and length in frames of up to 64 bytes,
signed or unsigned, with scale, offset, minimum and maximum. Anything else (big-endian, float
or multiplexed signals, container messages, overlapping signals) is refused with a
:class:`~gateway.errors.ConfigError` naming the message and the signal, rather than mis-encoded.

Results are bit for bit those of cantools (``tests/unit/test_can_codec.py`` checks every
message of both DBCs): encoding rounds the scaled value exactly as cantools' conversions do
(``round((value − offset) / scale)``; the ``divmod`` form for integer scales), decoding returns
``raw × scale + offset`` (an ``int`` for unscaled signals, as cantools does).

Strictness is LTC-1's (PROTOCOL.md §2.1: "a value outside its range is never clamped by a
conforming sender"): encoding raises :class:`~gateway.errors.FrameError` naming the frame, the
signal, the value and its unit for a non-number, a non-finite value, a value outside the DBC
range, and a non-integer for an unscaled signal. Decoding raises FrameError for a value outside
the DBC range by more than half a step (PROTOCOL.md §8).
"""

from __future__ import annotations

import linecache
import math
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any, Literal

import numpy as np
from cantools.database.conversion import (
    BaseConversion,
    IdentityConversion,
    LinearConversion,
    LinearIntegerConversion,
)

from gateway.errors import ConfigError, FrameError

__all__ = ["MAX_FRAME_BYTES", "MessageCodec", "SignalLayout", "compile_message", "compile_messages"]

#: The longest CAN FD payload (ISO 11898-1:2015) [bytes].
MAX_FRAME_BYTES = 64

Conversion = Literal["identity", "linear_integer", "linear"]


@dataclass(frozen=True)
class SignalLayout:
    """One signal as the compiled code sees it: bits, conversion and limits, from the DBC."""

    name: str
    start_bit: int  #: bit number of the least significant bit (DBC ``@1`` numbering)
    length_bits: int
    is_signed: bool  #: two's complement raw value
    scale: int | float  #: physical = raw × scale + offset
    offset: int | float
    conversion: Conversion  #: which of cantools' conversions the DBC implies (rounding rule)
    minimum: float | None  #: DBC minimum (physical), None if the DBC gives none
    maximum: float | None  #: DBC maximum (physical), None if the DBC gives none
    unit: str  #: "" if the DBC gives none

    @property
    def is_integer(self) -> bool:
        """Unscaled (scale 1, offset 0): the physical value must be an integer."""
        return self.conversion == "identity"

    @property
    def raw_min(self) -> int:
        return -(1 << (self.length_bits - 1)) if self.is_signed else 0

    @property
    def raw_max(self) -> int:
        return (1 << (self.length_bits - 1 if self.is_signed else self.length_bits)) - 1

    def to_raw(self, value: int | float) -> int:
        """cantools' ``numeric_scaled_to_raw`` for this conversion (the rounding we must match)."""
        if self.conversion == "identity":
            return round(value)
        if self.conversion == "linear_integer":
            raw = value - self.offset
            quotient, remainder = divmod(raw, self.scale)
            return round(quotient) if remainder == 0 else round(raw / self.scale)
        return round((value - self.offset) / self.scale)

    def to_physical(self, raw: int) -> int | float:
        """cantools' ``raw_to_scaled`` for this conversion."""
        if self.conversion == "identity":
            return raw
        return raw * self.scale + self.offset


def _conversion_of(message_name: str, signal: Any) -> tuple[Conversion, int | float, int | float]:
    # The same factory cantools uses (also inside its NamedSignalConversion for enum signals),
    # so the rounding rule below is the one cantools applies to this signal.
    conv = BaseConversion.factory(
        scale=signal.conversion.scale,
        offset=signal.conversion.offset,
        choices=None,
        is_float=signal.conversion.is_float,
    )
    if isinstance(conv, IdentityConversion):
        return "identity", 1, 0
    if isinstance(conv, LinearIntegerConversion):
        return "linear_integer", conv.scale, conv.offset
    if isinstance(conv, LinearConversion):
        return "linear", conv.scale, conv.offset
    raise ConfigError(  # a conversion class added by a later cantools
        f"{message_name}.{signal.name}: unsupported cantools conversion {conv!r}"
    )


def _layout_of(message: Any) -> tuple[SignalLayout, ...]:
    """The signals of ``message``; ConfigError for anything the compiled code cannot do."""
    name = message.name
    if message.is_container:
        raise ConfigError(f"{name}: container messages are not supported by the compiled codec")
    if not 0 < message.length <= MAX_FRAME_BYTES:
        raise ConfigError(f"{name}: length {message.length} bytes outside 1..{MAX_FRAME_BYTES}")
    if not message.signals:
        raise ConfigError(f"{name}: has no signals")
    layouts = []
    used = 0  # bit mask of the bits already taken by a signal
    for sig in message.signals:
        where = f"{name}.{sig.name}"
        if sig.byte_order != "little_endian":
            raise ConfigError(
                f"{where}: big-endian (Motorola, @0) signals are not supported by the "
                "compiled codec; LTC DBCs are little-endian (@1)"
            )
        if sig.conversion.is_float:
            raise ConfigError(f"{where}: float (IEEE) signals are not supported by the codec")
        if sig.is_multiplexer or sig.multiplexer_ids is not None:
            raise ConfigError(f"{where}: multiplexed signals are not supported by the codec")
        if sig.length < 1 or sig.start < 0 or sig.start + sig.length > 8 * message.length:
            raise ConfigError(
                f"{where}: bits {sig.start}..{sig.start + sig.length - 1} do not fit "
                f"the {message.length}-byte frame"
            )
        mask = ((1 << sig.length) - 1) << sig.start
        if used & mask:
            raise ConfigError(f"{where}: overlaps another signal of {name}")
        used |= mask
        conversion, scale, offset = _conversion_of(name, sig)
        if scale == 0:
            raise ConfigError(f"{where}: scale 0 cannot be inverted")
        for bound in (sig.minimum, sig.maximum):
            if bound is not None and not math.isfinite(bound):
                raise ConfigError(f"{where}: range bound {bound} is not finite")
        if sig.minimum is not None and sig.maximum is not None and sig.minimum > sig.maximum:
            raise ConfigError(f"{where}: minimum {sig.minimum} > maximum {sig.maximum}")
        layouts.append(
            SignalLayout(
                name=sig.name,
                start_bit=sig.start,
                length_bits=sig.length,
                is_signed=bool(sig.is_signed),
                scale=scale,
                offset=offset,
                conversion=conversion,
                minimum=sig.minimum,
                maximum=sig.maximum,
                unit=sig.unit or "",
            )
        )
    return tuple(layouts)


def _first_true(lo: int, hi: int, pred: Callable[[int], bool]) -> int:
    """Smallest raw in [lo, hi] with ``pred`` true (``hi + 1`` if none), for a monotone
    predicate (false below some raw, true from it on)."""
    hi += 1
    while lo < hi:
        mid = (lo + hi) // 2
        if pred(mid):
            hi = mid
        else:
            lo = mid + 1
    return lo


def _accepted_raw_range(sig: SignalLayout) -> tuple[int, int] | None:
    """Raw values whose physical value decode accepts: the DBC range widened by half a step.

    ``raw × scale + offset`` is monotone in raw (IEEE multiplication and addition are), so the
    accepted set is an interval, and checking the raw integer against it is exactly the
    physical comparison at a fraction of the cost. None: no raw value is accepted.
    """
    tol = abs(sig.scale) / 2
    lo_phys = None if sig.minimum is None else sig.minimum - tol
    hi_phys = None if sig.maximum is None else sig.maximum + tol

    def above_min(raw: int) -> bool:
        return lo_phys is None or sig.to_physical(raw) >= lo_phys

    def below_max(raw: int) -> bool:
        return hi_phys is None or sig.to_physical(raw) <= hi_phys

    r0, r1 = sig.raw_min, sig.raw_max
    if sig.scale > 0:  # physical value rises with raw
        first = _first_true(r0, r1, above_min)
        last = _first_true(r0, r1, lambda r: not below_max(r)) - 1
    else:
        first = _first_true(r0, r1, below_max)
        last = _first_true(r0, r1, lambda r: not above_min(r)) - 1
    return (first, last) if first <= last else None


def _raw_bounds_for_encode(sig: SignalLayout) -> tuple[int, int] | None:
    """Raw values encoding can produce from a value inside the DBC range; None if unbounded."""
    if sig.minimum is None or sig.maximum is None:
        return None
    a, b = sig.to_raw(sig.minimum), sig.to_raw(sig.maximum)
    return min(a, b), max(a, b)


class MessageCodec:
    """Encode and decode one DBC message with code generated for its layout.

    :meth:`encode` takes the physical values positionally in :attr:`signal_names` order (the
    DBC's, by start bit) and returns the payload; :meth:`decode` returns the physical values in
    that order. :meth:`encoder` and :meth:`decoder` generate the same for any order the caller
    names, so a protocol binds signals by name once, at start-up, and calls positionally after.
    """

    def __init__(self, message: Any) -> None:
        self.name: str = str(message.name)
        self.frame_id: int = int(message.frame_id)
        self.length: int = int(message.length)  #: payload length [bytes]
        self.is_fd: bool = bool(message.is_fd)
        self.is_extended_frame: bool = bool(message.is_extended_frame)
        #: how errors name the frame, e.g. "JOINT_CMD_J1 (0x201)"
        self.where = f"{self.name} (0x{self.frame_id:03X})"
        self.signals: tuple[SignalLayout, ...] = _layout_of(message)
        self.signal_names: tuple[str, ...] = tuple(s.name for s in self.signals)
        self._index = {s.name: i for i, s in enumerate(self.signals)}
        self._accept = [_accepted_raw_range(s) for s in self.signals]
        for sig, accepted in zip(self.signals, self._accept, strict=True):
            if accepted is None:
                raise ConfigError(
                    f"{self.name}.{sig.name}: no {sig.length_bits}-bit raw value lies in the "
                    f"DBC range [{sig.minimum}, {sig.maximum}]"
                )
        self.encode: Callable[..., bytearray] = self.encoder(self.signal_names)
        self.decode: Callable[[bytes | bytearray], tuple[Any, ...]] = self.decoder(
            self.signal_names
        )

    def __repr__(self) -> str:
        return f"MessageCodec({self.where}, {self.length} bytes, signals {self.signal_names})"

    # --- mapping forms (tests, tools; not the hot path) -------------------------------------
    def encode_mapping(self, values: Mapping[str, Any]) -> bytearray:
        """Encode ``{signal name: physical value}``; every signal of the message is required."""
        missing = [n for n in self.signal_names if n not in values]
        extra = sorted(set(values) - set(self.signal_names))
        if missing or extra:
            raise FrameError(f"{self.where}: missing signals {missing}, unknown signals {extra}")
        return self.encode(*(values[n] for n in self.signal_names))

    def decode_mapping(self, data: bytes | bytearray) -> dict[str, Any]:
        """``{signal name: physical value}``, like cantools' ``decode(decode_choices=False)``."""
        return dict(zip(self.signal_names, self.decode(data), strict=True))

    # --- code generation --------------------------------------------------------------------
    def _order(self, names: Iterable[str], what: str) -> list[int]:
        order = []
        for n in names:
            if n not in self._index:
                raise ConfigError(f"{self.name}: {what} names unknown signal {n!r}")
            order.append(self._index[n])
        if len(set(order)) != len(order):
            raise ConfigError(f"{self.name}: {what} names a signal twice: {list(names)}")
        return order

    def encoder(self, names: Sequence[str]) -> Callable[..., bytearray]:
        """A function of the physical values in ``names`` order (every signal, once) → payload."""
        order = self._order(names, "encoder")
        if len(order) != len(self.signals):
            missing = [s.name for i, s in enumerate(self.signals) if i not in order]
            raise ConfigError(f"{self.name}: encoder must name every signal; missing {missing}")
        args = [f"v{i}" for i in order]
        lines = [f"def encode({', '.join(args)}):"]
        terms = []
        for i, sig in enumerate(self.signals):
            v = f"v{i}"
            if sig.is_integer:
                fast_type = "int"
                lo, hi = sig.minimum, sig.maximum
            else:
                fast_type = "float"
                lo = -math.inf if sig.minimum is None else sig.minimum
                hi = math.inf if sig.maximum is None else sig.maximum
            # The fast path is a type test and one chained comparison (which NaN fails); every
            # other value (ints for scaled signals, numpy scalars, bools, errors) takes the
            # checked path, which returns the value normalised as LTC-1 always did.
            conds = [f"type({v}) is not {fast_type}"]
            if lo is not None and hi is not None:
                strict = "<" if math.isinf(lo) else "<="
                strict_hi = "<" if math.isinf(hi) else "<="
                conds.append(f"not ({_lit(lo)} {strict} {v} {strict_hi} {_lit(hi)})")
            elif lo is not None:
                conds.append(f"{v} < {_lit(lo)}")
            elif hi is not None:
                conds.append(f"{v} > {_lit(hi)}")
            lines.append(f"    if {' or '.join(conds)}:")
            lines.append(f"        {v} = _checked({i}, {v})")
            r = f"r{i}"
            if sig.conversion == "identity":
                r = v  # the checked value is the raw value
            elif sig.conversion == "linear_integer":
                lines.append(f"    _x = {v} - {_lit(sig.offset)}")
                lines.append(f"    _q, _m = divmod(_x, {_lit(sig.scale)})")
                lines.append(f"    {r} = round(_q) if _m == 0 else round(_x / {_lit(sig.scale)})")
            elif sig.offset == 0:  # v − 0 is v, bit for bit, also for −0.0
                lines.append(f"    {r} = round({v} / {_lit(sig.scale)})")
            else:
                lines.append(f"    {r} = round(({v} - {_lit(sig.offset)}) / {_lit(sig.scale)})")
            bounds = _raw_bounds_for_encode(sig)
            if bounds is None or bounds[0] < sig.raw_min or bounds[1] > sig.raw_max:
                lines.append(f"    if not ({sig.raw_min} <= {r} <= {sig.raw_max}):")
                lines.append(f"        _overflow({i}, {v}, {r})")
            field = r
            may_be_negative = sig.is_signed and (bounds is None or bounds[0] < 0)
            if may_be_negative:
                field = f"({r} & {_hex((1 << sig.length_bits) - 1)})"
            terms.append(f"({field} << {sig.start_bit})" if sig.start_bit else field)
        packed = " | ".join(terms)
        lines.append(f"    return bytearray(({packed}).to_bytes({self.length}, 'little'))")
        return self._compile("\n".join(lines) + "\n", "encode", "encode")

    def decoder(self, names: Sequence[str]) -> Callable[[bytes | bytearray], tuple[Any, ...]]:
        """A function payload → tuple of the physical values of ``names``, in that order.

        Every signal's range is checked, named or not.
        """
        order = self._order(names, "decoder")
        lines = [
            "def decode(data):",
            f"    if len(data) != {self.length}:",
            "        _bad_length(data)",
            "    x = _from_bytes(data, 'little')",
        ]
        top = 8 * self.length
        for i, sig in enumerate(self.signals):
            shifted = f"(x >> {sig.start_bit})" if sig.start_bit else "x"
            if sig.start_bit + sig.length_bits != top:
                shifted = f"({shifted} & {_hex((1 << sig.length_bits) - 1)})"
            if sig.is_signed:
                sign = _hex(1 << (sig.length_bits - 1))
                shifted = f"(({shifted} ^ {sign}) - {sign})"
            lines.append(f"    r{i} = {shifted}")
            accepted = self._accept[i]
            assert accepted is not None  # refused in __init__
            lo, hi = accepted
            if lo > sig.raw_min and hi < sig.raw_max:
                lines.append(f"    if not ({lo} <= r{i} <= {hi}):")
            elif lo > sig.raw_min:
                lines.append(f"    if r{i} < {lo}:")
            elif hi < sig.raw_max:
                lines.append(f"    if r{i} > {hi}:")
            else:
                continue
            lines.append(f"        _out_of_range({i}, r{i})")
        values = []
        for i in order:
            sig = self.signals[i]
            if sig.conversion == "identity":
                values.append(f"r{i}")
            elif sig.offset == 0 and sig.scale > 0 and sig.conversion == "linear":
                # + 0 would only turn a −0.0 into 0.0, and raw × scale is −0.0 only for scale < 0
                values.append(f"r{i} * {_lit(sig.scale)}")
            else:
                values.append(f"r{i} * {_lit(sig.scale)} + {_lit(sig.offset)}")
        lines.append(f"    return ({', '.join(values)}{',' if len(values) == 1 else ''})")
        return self._compile("\n".join(lines) + "\n", "decode", "decode")

    def _compile(self, source: str, function: str, what: str) -> Callable[..., Any]:
        filename = f"<{what} {self.name} 0x{self.frame_id:X} {id(source):x}>"
        namespace: dict[str, Any] = {
            "_checked": self._checked,
            "_overflow": self._overflow,
            "_bad_length": self._bad_length,
            "_out_of_range": self._out_of_range,
            "_from_bytes": int.from_bytes,
        }
        exec(compile(source, filename, "exec"), namespace)  # our own generated code only
        # Tracebacks through generated code show its source.
        linecache.cache[filename] = (len(source), None, source.splitlines(True), filename)
        fn = namespace[function]
        fn.source = source  # for debugging: print(codec.encode.source)
        return fn  # type: ignore[no-any-return]

    # --- the slow, checked paths the generated code calls ----------------------------------
    def _checked(self, index: int, value: Any) -> int | float:
        """``value`` normalised for signal ``index`` (int if unscaled, else float), or FrameError.

        The checks and messages of LTC-1's encoder, in its order: a number, finite, inside the
        DBC range, an integer for an unscaled signal.
        """
        sig = self.signals[index]
        where, name = self.where, sig.name
        unit = f" {sig.unit}" if sig.unit else ""
        if isinstance(value, bool | np.bool_):
            value = int(value)
        if not isinstance(value, int | float | np.integer | np.floating):
            raise FrameError(f"{where}: {name} = {value!r} is not a number")
        exact = int(value) if isinstance(value, int | np.integer) else None
        v = float(value)
        if not math.isfinite(v):
            raise FrameError(f"{where}: {name} = {value!r}{unit} is not finite")
        number = exact if exact is not None else v
        if (sig.minimum is not None and number < sig.minimum) or (
            sig.maximum is not None and number > sig.maximum
        ):
            raise FrameError(
                f"{where}: {name} = {value!r}{unit} outside its DBC range "
                f"[{sig.minimum}, {sig.maximum}]"
            )
        if sig.is_integer:
            if exact is not None:
                return exact
            if not v.is_integer():
                raise FrameError(f"{where}: {name} = {value!r}{unit} must be an integer")
            return int(v)
        return v

    def _overflow(self, index: int, value: Any, raw: int) -> None:
        sig = self.signals[index]
        unit = f" {sig.unit}" if sig.unit else ""
        raise FrameError(
            f"{self.where}: {sig.name} = {value!r}{unit} is raw {raw}, outside the "
            f"{sig.length_bits}-bit field's {sig.raw_min}..{sig.raw_max}"
        )

    def _bad_length(self, data: bytes | bytearray) -> None:
        raise FrameError(f"{self.where}: {len(data)} data bytes, expected {self.length}")

    def _out_of_range(self, index: int, raw: int) -> None:
        sig = self.signals[index]
        raise FrameError(
            f"{self.where}: {sig.name} = {sig.to_physical(raw)} outside its range "
            f"[{sig.minimum}, {sig.maximum}]"
        )


def _lit(value: int | float) -> str:
    """A Python literal that evaluates to exactly ``value`` (repr round-trips floats)."""
    if isinstance(value, float) and math.isinf(value):
        return "float('inf')" if value > 0 else "float('-inf')"
    return repr(value)


def _hex(value: int) -> str:
    return f"0x{value:X}"


def compile_message(message: Any) -> MessageCodec:
    """Compile one cantools ``Message``; ConfigError naming message and signal if unsupported."""
    return MessageCodec(message)


def compile_messages(db: Any, names: Iterable[str] | None = None) -> dict[str, MessageCodec]:
    """Compile ``names`` (default: every message) of a cantools database, by message name."""
    wanted = list(names) if names is not None else [m.name for m in db.messages]
    codecs = {}
    for name in wanted:
        try:
            message = db.get_message_by_name(name)
        except KeyError:
            raise ConfigError(f"message {name} missing from the DBC") from None
        codecs[name] = MessageCodec(message)
    return codecs
