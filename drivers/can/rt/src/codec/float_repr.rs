//! A float as Python's `repr` writes it, without allocating (codec.rs's error texts, as
//! codec.py's).

use std::fmt::{self, Write};

/// A few bytes of stack to format into, so error texts cost no allocation of their own.
struct StackText {
    buf: [u8; 40],
    len: usize,
}

impl Write for StackText {
    fn write_str(&mut self, s: &str) -> fmt::Result {
        let end = self.len + s.len();
        if end > self.buf.len() {
            return Err(fmt::Error);
        }
        self.buf[self.len..end].copy_from_slice(s.as_bytes());
        self.len = end;
        Ok(())
    }
}

/// Write `v` as Python's `repr(float)` does: the shortest digits that round-trip (Rust's `{:e}`
/// finds the same ones), positional from 1e-4 up to below 1e16 with at least one decimal
/// (`9.0`, `0.0001`), else exponential with a signed two-digit exponent (`1e-05`, `1e+300`),
/// and `nan`, `inf`, `-inf`.
pub fn write_py_float<W: Write + ?Sized>(out: &mut W, v: f64) -> fmt::Result {
    if v.is_nan() {
        return out.write_str("nan");
    }
    if v.is_infinite() {
        return out.write_str(if v > 0.0 { "inf" } else { "-inf" });
    }
    let mut sci = StackText {
        buf: [0; 40],
        len: 0,
    };
    write!(sci, "{v:e}")?;
    let sci = std::str::from_utf8(&sci.buf[..sci.len]).map_err(|_| fmt::Error)?;
    let (negative, sci) = match sci.strip_prefix('-') {
        Some(rest) => (true, rest),
        None => (false, sci),
    };
    let (mantissa, exponent) = sci.split_once('e').ok_or(fmt::Error)?;
    let exponent: i32 = exponent.parse().map_err(|_| fmt::Error)?;
    let mut digits = [0u8; 24];
    let mut n = 0;
    for b in mantissa.bytes().filter(|&b| b != b'.') {
        digits[n] = b;
        n += 1;
    }
    let digits = std::str::from_utf8(&digits[..n]).map_err(|_| fmt::Error)?;
    if negative {
        out.write_char('-')?;
    }
    let point = exponent + 1; // digits are 0.DIGITS × 10^point
    if -4 < point && point <= 16 {
        if point <= 0 {
            out.write_str("0.")?;
            for _ in 0..-point {
                out.write_char('0')?;
            }
            out.write_str(digits)
        } else if point as usize >= n {
            out.write_str(digits)?;
            for _ in n..point as usize {
                out.write_char('0')?;
            }
            out.write_str(".0")
        } else {
            let (int_part, frac) = digits.split_at(point as usize);
            write!(out, "{int_part}.{frac}")
        }
    } else {
        let (first, rest) = digits.split_at(1);
        out.write_str(first)?;
        if !rest.is_empty() {
            write!(out, ".{rest}")?;
        }
        let sign = if exponent < 0 { '-' } else { '+' };
        write!(out, "e{sign}{:02}", exponent.unsigned_abs())
    }
}

/// [`write_py_float`] into a new String.
pub fn py_float(v: f64) -> String {
    let mut s = String::new();
    let _ = write_py_float(&mut s, v);
    s
}
