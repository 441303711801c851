"""Floats for the compiled side's JSON: the number where serde_json's default parser (no
``float_roundtrip``) reads it back exactly, else its ``repr`` (drivers/can/rt_tables.py's tables
and the golden vectors of drivers/can/rt_tables_golden.py)."""

from __future__ import annotations

import decimal
import math


def _json_float(value: float) -> float | str:
    """``value`` for JSON: the number where serde_json's default parser reads it back exactly
    (significand ≤ 2⁵³ and decimal exponent within ±22: one correctly rounded IEEE operation),
    else its repr."""
    if not math.isfinite(value):
        return repr(value)
    _sign, digits, exponent = decimal.Decimal(repr(value)).as_tuple()
    assert isinstance(exponent, int)
    if int("".join(map(str, digits))) <= 1 << 53 and -22 <= exponent <= 22:
        return value
    return repr(value)
