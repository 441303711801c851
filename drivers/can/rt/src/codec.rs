//! A DBC message's signal layout as a table, and the codec over it: the compiled form of
//! drivers/can/codec.py, bit for bit.
//!
//! cantools stays the only DBC parser: drivers/can/rt_tables.py exports each message's
//! layout (start bit, length, signedness, scale, offset, range, the raw bounds codec.py
//! derives) and [`MessageCodec::from_table`] reads it. What the table allows is what codec.py
//! compiles: little-endian (Intel, `@1`) integer signals of up to 64 bits in frames of up to
//! 64 bytes, with cantools' conversions:
//!
//! * decode: raw from the bit field, checked against the raw range codec.py accepts (the DBC
//!   range widened by half a step), physical = raw × scale + offset as codec.py computes it;
//! * encode: the checks and texts of codec.py's `_checked` (finite, inside the DBC range, an
//!   integer for an unscaled signal), raw = round((value − offset) / scale) with Python's
//!   `round` (ties to even), the field-overflow check where codec.py has one.
//!
//! Decoding reports errors as a small `Copy` value ([`DecodeError`]) written out only when
//! someone wants the text, so a bad frame costs no allocation either. The table readers at the
//! bottom are shared with the adapters (ltc_adapter.rs, ltc_fd_adapter.rs).

use std::fmt::{self, Write};

use serde_json::Value;

use crate::adapter::FrameError;
use crate::frame::CANFD_MAX_DLEN;

/// Which of cantools' conversions a signal has: it fixes how a value is rounded and whether
/// the physical value is an integer (codec.py `Conversion`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Conversion {
    /// scale 1, offset 0: the physical value is the raw integer
    Identity,
    /// integer scale and offset (cantools' LinearIntegerConversion)
    LinearInteger,
    /// any other scale and offset (floats)
    Linear,
}

/// One signal of a message: its bits, conversion and limits (codec.py `SignalLayout`, plus the
/// raw ranges codec.py derives from them).
#[derive(Clone, Debug)]
pub struct Signal {
    /// the DBC's signal name (error texts name it)
    pub name: String,
    /// bit number of the least significant bit (DBC `@1` numbering)
    pub start_bit: usize,
    /// width of the field [bits], 1..=64
    pub length_bits: usize,
    /// two's complement raw value
    pub signed: bool,
    pub conversion: Conversion,
    /// physical = raw × scale + offset
    pub scale: f64,
    pub offset: f64,
    /// DBC range (physical), None where the DBC gives no bound
    pub minimum: Option<f64>,
    pub maximum: Option<f64>,
    /// "" if the DBC gives none
    pub unit: String,
    /// the field's raw range
    pub raw_min: i64,
    pub raw_max: i64,
    /// raw values decoding accepts (codec.py `_accepted_raw_range`)
    pub decode_raw: (i64, i64),
    /// raw values encoding produces from in-range values (codec.py `_raw_bounds_for_encode`)
    pub encode_raw: Option<(i64, i64)>,
    /// the DBC's value table (VAL_), empty if none
    pub choices: Vec<(i64, String)>,
    /// integer scale and offset of a [`Conversion::LinearInteger`] signal (exact arithmetic)
    int_scale: i64,
    int_offset: i64,
    /// "[min, max]" as Python prints the DBC range in error texts
    range_text: String,
    /// " unit" or "", as codec.py's error texts append the unit
    unit_text: String,
    /// codec.py emits the raw-overflow check for this signal
    check_overflow: bool,
}

/// Why a payload did not decode; [`MessageCodec::write_decode_error`] gives codec.py's text.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum DecodeError {
    /// the payload is not the message's length [bytes]
    Length { got: usize },
    /// signal `signal` (index) has a raw value outside what decoding accepts
    OutOfRange { signal: usize, raw: i64 },
}

/// One message's codec: its id, length and format, and its signals in the DBC's order (the
/// order codec.py checks them, so the first failing signal is the one both name).
#[derive(Clone, Debug)]
pub struct MessageCodec {
    /// the DBC's message name
    pub name: String,
    /// 11- or 29-bit identifier
    pub id: u32,
    /// how errors name the frame, e.g. "JOINT_CMD_J1 (0x201)"
    pub label: String,
    /// payload length [bytes]
    pub length: usize,
    /// a CAN FD frame
    pub fd: bool,
    /// sent with the CAN FD bit rate switch
    pub brs: bool,
    /// 29-bit identifier
    pub extended: bool,
    /// in the DBC's order (by start bit)
    pub signals: Vec<Signal>,
}

impl Signal {
    fn from_table(v: &Value, path: &str, frame_bits: usize) -> Result<Signal, String> {
        let name = text(v, "name", path)?.to_string();
        let start_bit = uint(v, "start_bit", path)? as usize;
        let length_bits = uint(v, "length_bits", path)? as usize;
        let signed = boolean(v, "signed", path)?;
        if !(1..=64).contains(&length_bits) || (!signed && length_bits == 64) {
            return Err(format!(
                "{path}.length_bits: {length_bits} bits; the codec carries 1..64 signed and \
                 1..63 unsigned"
            ));
        }
        if start_bit + length_bits > frame_bits {
            return Err(format!(
                "{path}: bits {start_bit}..{} do not fit the {}-byte frame",
                start_bit + length_bits - 1,
                frame_bits / 8
            ));
        }
        let conversion = match text(v, "conversion", path)? {
            "identity" => Conversion::Identity,
            "linear_integer" => Conversion::LinearInteger,
            "linear" => Conversion::Linear,
            other => return Err(format!("{path}.conversion: unknown conversion {other:?}")),
        };
        let scale = float(v, "scale", path)?;
        let offset = float(v, "offset", path)?;
        if !scale.is_finite() || scale == 0.0 || !offset.is_finite() {
            return Err(format!(
                "{path}: scale {scale} and offset {offset} must be finite, scale ≠ 0"
            ));
        }
        let (mut int_scale, mut int_offset) = (1, 0);
        match conversion {
            Conversion::Identity if scale != 1.0 || offset != 0.0 => {
                return Err(format!(
                    "{path}: an identity conversion with scale {scale}, offset {offset}"
                ));
            }
            Conversion::LinearInteger => {
                int_scale = int(v, "scale", path)?;
                int_offset = int(v, "offset", path)?;
            }
            _ => {}
        }
        let minimum = optional_float(v, "minimum", path)?;
        let maximum = optional_float(v, "maximum", path)?;
        let unit = text(v, "unit", path)?.to_string();
        let (raw_min, raw_max) = field_range(length_bits, signed);
        if int(v, "raw_min", path)? != raw_min || int(v, "raw_max", path)? != raw_max {
            return Err(format!(
                "{path}: raw_min/raw_max differ from the {length_bits}-bit field's \
                 {raw_min}..{raw_max}"
            ));
        }
        let decode_raw = int_pair(field(v, "decode_raw", path)?, &format!("{path}.decode_raw"))?
            .ok_or_else(|| format!("{path}.decode_raw: missing"))?;
        if decode_raw.0 < raw_min || decode_raw.1 > raw_max || decode_raw.0 > decode_raw.1 {
            return Err(format!(
                "{path}.decode_raw: {decode_raw:?} is not inside {raw_min}..{raw_max}"
            ));
        }
        let encode_raw = int_pair(field(v, "encode_raw", path)?, &format!("{path}.encode_raw"))?;
        let check_overflow = match encode_raw {
            None => true,
            Some((lo, hi)) => lo < raw_min || hi > raw_max,
        };
        let mut choices = Vec::new();
        let choices_path = format!("{path}.choices");
        match field(v, "choices", path)? {
            Value::Null => {}
            Value::Array(items) => {
                for item in items {
                    let pair = item.as_array().filter(|p| p.len() == 2);
                    let value = pair.and_then(|p| p[0].as_i64());
                    let label = pair.and_then(|p| p[1].as_str());
                    match (value, label) {
                        (Some(value), Some(label)) => choices.push((value, label.to_string())),
                        _ => return Err(format!("{choices_path}: {item} is not [value, name]")),
                    }
                }
            }
            other => {
                return Err(format!(
                    "{choices_path}: expected a list or null, got {other}"
                ))
            }
        }
        let mut range_text = String::from("[");
        write_python_number(&mut range_text, field(v, "minimum", path)?);
        range_text.push_str(", ");
        write_python_number(&mut range_text, field(v, "maximum", path)?);
        range_text.push(']');
        let unit_text = if unit.is_empty() {
            String::new()
        } else {
            format!(" {unit}")
        };
        Ok(Signal {
            name,
            start_bit,
            length_bits,
            signed,
            conversion,
            scale,
            offset,
            minimum,
            maximum,
            unit,
            raw_min,
            raw_max,
            decode_raw,
            encode_raw,
            choices,
            int_scale,
            int_offset,
            range_text,
            unit_text,
            check_overflow,
        })
    }

    /// The physical value of `raw`, computed as codec.py's generated decoder does (so the same
    /// IEEE operations: `raw * scale` without `+ 0` for a positive-scale linear signal).
    pub fn physical(&self, raw: i64) -> f64 {
        match self.conversion {
            Conversion::Identity => raw as f64,
            Conversion::LinearInteger => {
                (raw as i128 * self.int_scale as i128 + self.int_offset as i128) as f64
            }
            Conversion::Linear if self.offset == 0.0 && self.scale > 0.0 => raw as f64 * self.scale,
            Conversion::Linear => raw as f64 * self.scale + self.offset,
        }
    }

    /// cantools' `numeric_scaled_to_raw` of a finite `value`: Python's `round`, ties to even.
    /// An integer-valued f64 (it may lie outside every integer type: checked by the caller).
    fn to_raw(&self, value: f64) -> f64 {
        match self.conversion {
            Conversion::Identity => value,
            // For a float value divmod's exact branch gives the same integer as the division.
            Conversion::LinearInteger | Conversion::Linear => {
                ((value - self.offset) / self.scale).round_ties_even()
            }
        }
    }

    /// `value` as codec.py's error texts print it: Python's repr of the float the adapter
    /// passed, an integer for an unscaled signal (the Python adapters pass ints there).
    fn write_value(&self, out: &mut String, value: f64) {
        if self.conversion == Conversion::Identity && value.is_finite() && value.fract() == 0.0 {
            let _ = write!(out, "{:.0}", value + 0.0);
        } else {
            let _ = write_py_float(out, value);
        }
    }

    /// codec.py `to_physical` for an error text: an int for integer conversions, else a float
    /// (which, unlike the decoder, always adds the offset).
    fn write_physical(&self, out: &mut String, raw: i64) {
        match self.conversion {
            Conversion::Identity => {
                let _ = write!(out, "{raw}");
            }
            Conversion::LinearInteger => {
                let _ = write!(
                    out,
                    "{}",
                    raw as i128 * self.int_scale as i128 + self.int_offset as i128
                );
            }
            Conversion::Linear => {
                let _ = write_py_float(out, raw as f64 * self.scale + self.offset);
            }
        }
    }
}

impl MessageCodec {
    /// One entry of the tables' `messages` list; Err names the entry (`path`) that is missing
    /// or wrong.
    pub fn from_table(v: &Value, path: &str) -> Result<MessageCodec, String> {
        let name = text(v, "name", path)?.to_string();
        let id = uint(v, "id", path)?;
        let length = uint(v, "length", path)? as usize;
        let fd = boolean(v, "fd", path)?;
        let extended = boolean(v, "extended", path)?;
        if id > if extended { 0x1FFF_FFFF } else { 0x7FF } {
            return Err(format!("{path}.id: 0x{id:X} does not fit its id format"));
        }
        let lengths_ok = if fd {
            crate::frame::CANFD_LENGTHS.contains(&length) && length > 0
        } else {
            (1..=8).contains(&length)
        };
        if !lengths_ok || length > CANFD_MAX_DLEN {
            return Err(format!(
                "{path}.length: {length} bytes is no {} frame's length",
                if fd { "CAN FD" } else { "classic CAN" }
            ));
        }
        let mut signals = Vec::new();
        let mut used = [0u64; 8]; // bits of the frame already taken by a signal
        for (k, s) in array(v, "signals", path)?.iter().enumerate() {
            let sname = s.get("name").and_then(Value::as_str).unwrap_or("?");
            let spath = format!("{path}.signals[{k}: {sname}]");
            let sig = Signal::from_table(s, &spath, 8 * length)?;
            for bit in sig.start_bit..sig.start_bit + sig.length_bits {
                if used[bit / 64] & (1 << (bit % 64)) != 0 {
                    return Err(format!("{spath}: overlaps another signal of {name}"));
                }
                used[bit / 64] |= 1 << (bit % 64);
            }
            signals.push(sig);
        }
        if signals.is_empty() {
            return Err(format!("{path}.signals: {name} has no signals"));
        }
        Ok(MessageCodec {
            label: text(v, "where", path)?.to_string(),
            name,
            id: id as u32,
            length,
            fd,
            brs: boolean(v, "brs", path)?,
            extended,
            signals,
        })
    }

    /// The index of signal `name`, or None.
    pub fn index(&self, name: &str) -> Option<usize> {
        self.signals.iter().position(|s| s.name == name)
    }

    /// The raw values of every signal of `data` into `raw[..signals.len()]`, each checked
    /// against the range decoding accepts, in the DBC's order.
    pub fn decode(&self, data: &[u8], raw: &mut [i64]) -> Result<(), DecodeError> {
        if data.len() != self.length {
            return Err(DecodeError::Length { got: data.len() });
        }
        for (i, sig) in self.signals.iter().enumerate() {
            let r = extract(data, sig.start_bit, sig.length_bits, sig.signed);
            if r < sig.decode_raw.0 || r > sig.decode_raw.1 {
                return Err(DecodeError::OutOfRange { signal: i, raw: r });
            }
            raw[i] = r;
        }
        Ok(())
    }

    /// The physical value of signal `i` with raw value `raw`.
    pub fn physical(&self, i: usize, raw: i64) -> f64 {
        self.signals[i].physical(raw)
    }

    /// Encode the physical `values` (one per signal, in the DBC's order) into
    /// `data[..length]`; the first value codec.py would refuse gives its FrameError text.
    pub fn encode(&self, values: &[f64], data: &mut [u8]) -> Result<(), FrameError> {
        if values.len() != self.signals.len() || data.len() != self.length {
            return Err(FrameError(format!(
                "{}: {} values for {} signals into {} bytes, expected {}",
                self.label,
                values.len(),
                self.signals.len(),
                data.len(),
                self.length
            )));
        }
        data.fill(0);
        for (sig, &value) in self.signals.iter().zip(values) {
            let raw = self.checked_raw(sig, value)?;
            let mask = if sig.length_bits == 64 {
                u64::MAX
            } else {
                (1u64 << sig.length_bits) - 1
            };
            insert(data, sig.start_bit, sig.length_bits, raw as u64 & mask);
        }
        Ok(())
    }

    /// The raw value of `value` for `sig`, or codec.py's FrameError (`_checked`, `_overflow`).
    fn checked_raw(&self, sig: &Signal, value: f64) -> Result<i64, FrameError> {
        let fail = |what: &dyn Fn(&mut String)| {
            let mut text = format!("{}: {} = ", self.label, sig.name);
            sig.write_value(&mut text, value);
            text.push_str(&sig.unit_text);
            what(&mut text);
            FrameError(text)
        };
        if !value.is_finite() {
            return Err(fail(&|t| t.push_str(" is not finite")));
        }
        if sig.minimum.is_some_and(|m| value < m) || sig.maximum.is_some_and(|m| value > m) {
            return Err(fail(&|t| {
                t.push_str(" outside its DBC range ");
                t.push_str(&sig.range_text);
            }));
        }
        if sig.conversion == Conversion::Identity && value.fract() != 0.0 {
            return Err(fail(&|t| t.push_str(" must be an integer")));
        }
        // + 0.0: Python's round gives the int 0, never −0
        let raw = sig.to_raw(value) + 0.0;
        // 2⁶³ is exact in f64: from it on (or an infinity) no i64 field holds the value
        let two_63 = (1u64 << 63) as f64;
        let in_field =
            (-two_63..two_63).contains(&raw) && (sig.raw_min..=sig.raw_max).contains(&(raw as i64));
        if sig.check_overflow && !in_field {
            return Err(fail(&|t| {
                let _ = write!(
                    t,
                    " is raw {raw:.0}, outside the {}-bit field's {}..{}",
                    sig.length_bits, sig.raw_min, sig.raw_max
                );
            }));
        }
        Ok(raw as i64)
    }

    /// codec.py's text for a decode error (`_bad_length`, `_out_of_range`), appended to `out`.
    pub fn write_decode_error(&self, error: &DecodeError, out: &mut String) {
        match *error {
            DecodeError::Length { got } => {
                let _ = write!(
                    out,
                    "{}: {got} data bytes, expected {}",
                    self.label, self.length
                );
            }
            DecodeError::OutOfRange { signal, raw } => {
                let sig = &self.signals[signal];
                let _ = write!(out, "{}: {} = ", self.label, sig.name);
                sig.write_physical(out, raw);
                let _ = write!(out, " outside its range {}", sig.range_text);
            }
        }
    }
}

/// The raw range of a `length_bits`-wide field.
fn field_range(length_bits: usize, signed: bool) -> (i64, i64) {
    if signed {
        let half = 1i128 << (length_bits - 1);
        (-half as i64, (half - 1) as i64)
    } else {
        (0, ((1i128 << length_bits) - 1) as i64)
    }
}

/// The little-endian bit field at `start` (LSB) of `length` bits, sign-extended if `signed`.
fn extract(data: &[u8], start: usize, length: usize, signed: bool) -> i64 {
    let first = start / 8;
    let last = (start + length - 1) / 8;
    let mut acc: u128 = 0;
    for (k, &b) in data[first..=last].iter().enumerate() {
        acc |= (b as u128) << (8 * k);
    }
    let bits = (acc >> (start % 8)) as u64;
    if length == 64 {
        return bits as i64;
    }
    let v = bits & ((1u64 << length) - 1);
    if signed && v & (1u64 << (length - 1)) != 0 {
        v as i64 - (1i64 << length)
    } else {
        v as i64
    }
}

/// OR `field` (already masked to `length` bits) into `data` at bit `start`.
fn insert(data: &mut [u8], start: usize, length: usize, field: u64) {
    let first = start / 8;
    let last = (start + length - 1) / 8;
    let shifted = (field as u128) << (start % 8);
    for k in 0..=last - first {
        data[first + k] |= (shifted >> (8 * k)) as u8;
    }
}

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

/// A table number as Python prints it: `None` for null, an int as an int, a float (a JSON
/// float or a repr string, see [`f64_of`]) as Python's repr.
fn write_python_number(out: &mut String, v: &Value) {
    match v {
        Value::Null => out.push_str("None"),
        Value::Number(n) if n.is_i64() || n.is_u64() => {
            let _ = write!(out, "{n}");
        }
        _ => {
            let _ = write_py_float(out, f64_of(v).unwrap_or(f64::NAN));
        }
    }
}

// --- reading the tables ----------------------------------------------------------------------
// Every reader names the entry it wanted ("tables.messages[3: CTRL_STATUS].id: missing").

/// A float of the tables: a JSON number, or a string holding Python's repr of a float
/// (rt_tables.py writes a float as a string where serde_json's default parser would not read
/// the number back exactly: long significands, large exponents, nan and infinities).
pub fn f64_of(v: &Value) -> Option<f64> {
    match v {
        Value::Number(n) => n.as_f64(),
        Value::String(s) => s.parse().ok(),
        _ => None,
    }
}

/// `v[key]`, or Err naming `path.key`.
pub(crate) fn field<'a>(v: &'a Value, key: &str, path: &str) -> Result<&'a Value, String> {
    v.get(key).ok_or_else(|| format!("{path}.{key}: missing"))
}

fn wrong(path: &str, key: &str, want: &str, got: &Value) -> String {
    format!("{path}.{key}: expected {want}, got {got}")
}

pub(crate) fn uint(v: &Value, key: &str, path: &str) -> Result<u64, String> {
    let x = field(v, key, path)?;
    x.as_u64()
        .ok_or_else(|| wrong(path, key, "an unsigned integer", x))
}

pub(crate) fn int(v: &Value, key: &str, path: &str) -> Result<i64, String> {
    let x = field(v, key, path)?;
    x.as_i64().ok_or_else(|| wrong(path, key, "an integer", x))
}

pub(crate) fn float(v: &Value, key: &str, path: &str) -> Result<f64, String> {
    let x = field(v, key, path)?;
    f64_of(x).ok_or_else(|| wrong(path, key, "a number", x))
}

fn optional_float(v: &Value, key: &str, path: &str) -> Result<Option<f64>, String> {
    match field(v, key, path)? {
        Value::Null => Ok(None),
        x => f64_of(x)
            .map(Some)
            .ok_or_else(|| wrong(path, key, "a number or null", x)),
    }
}

pub(crate) fn boolean(v: &Value, key: &str, path: &str) -> Result<bool, String> {
    let x = field(v, key, path)?;
    x.as_bool()
        .ok_or_else(|| wrong(path, key, "true or false", x))
}

pub(crate) fn text<'a>(v: &'a Value, key: &str, path: &str) -> Result<&'a str, String> {
    let x = field(v, key, path)?;
    x.as_str().ok_or_else(|| wrong(path, key, "a string", x))
}

pub(crate) fn array<'a>(v: &'a Value, key: &str, path: &str) -> Result<&'a Vec<Value>, String> {
    let x = field(v, key, path)?;
    x.as_array().ok_or_else(|| wrong(path, key, "a list", x))
}

/// `[lo, hi]` of integers, or None for null.
fn int_pair(v: &Value, path: &str) -> Result<Option<(i64, i64)>, String> {
    if v.is_null() {
        return Ok(None);
    }
    match v
        .as_array()
        .map(|a| a.iter().map(Value::as_i64).collect::<Vec<_>>())
        .as_deref()
    {
        Some([Some(lo), Some(hi)]) => Ok(Some((*lo, *hi))),
        _ => Err(format!(
            "{path}: expected [lo, hi] integers or null, got {v}"
        )),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use serde_json::json;

    fn signal(name: &str, start: u64, bits: u64, signed: bool, conv: &str, scale: Value) -> Value {
        let (raw_min, raw_max) = field_range(bits as usize, signed);
        json!({"name": name, "start_bit": start, "length_bits": bits, "signed": signed,
               "conversion": conv, "scale": scale, "offset": 0, "minimum": null,
               "maximum": null, "unit": "", "raw_min": raw_min, "raw_max": raw_max,
               "decode_raw": [raw_min, raw_max], "encode_raw": null, "choices": null})
    }

    /// JOINT_CMD_J1 of ltc_v1.dbc, as rt_tables.py exports it.
    fn joint_cmd() -> MessageCodec {
        let mut pos = signal("position_cmd", 0, 24, true, "linear", json!(1e-6));
        pos["minimum"] = json!(-8.388608);
        pos["maximum"] = json!(8.388607);
        pos["unit"] = json!("rad");
        pos["encode_raw"] = json!([-8388608, 8388607]);
        let mut vel = signal("velocity_cmd", 24, 16, true, "linear", json!(0.0001));
        vel["minimum"] = json!(-3.2768);
        vel["maximum"] = json!(3.2767);
        vel["unit"] = json!("rad/s");
        vel["encode_raw"] = json!([-32768, 32767]);
        let mut hold = signal("hold", 40, 1, false, "identity", json!(1));
        hold["minimum"] = json!(0);
        hold["maximum"] = json!(1);
        hold["encode_raw"] = json!([0, 1]);
        let counter = signal("counter", 48, 8, false, "identity", json!(1));
        let crc = signal("crc", 56, 8, false, "identity", json!(1));
        let msg = json!({"name": "JOINT_CMD_J1", "id": 513, "where": "JOINT_CMD_J1 (0x201)",
                         "length": 8, "fd": false, "brs": false, "extended": false,
                         "signals": [pos, vel, hold, counter, crc]});
        MessageCodec::from_table(&msg, "m").unwrap()
    }

    #[test]
    fn python_float_repr() {
        let cases: [(f64, &str); 22] = [
            (0.0, "0.0"),
            (-0.0, "-0.0"),
            (9.0, "9.0"),
            (0.1, "0.1"),
            (-8.388608, "-8.388608"),
            (1e-4, "0.0001"),
            (1e-5, "1e-05"),
            (1.5e-7, "1.5e-07"),
            (1e16, "1e+16"),
            (1234567890123456.0, "1234567890123456.0"),
            (12345678901234567.0, "1.2345678901234568e+16"),
            (1e300, "1e+300"),
            (f64::MAX, "1.7976931348623157e+308"),
            (5e-324, "5e-324"),
            (0.30000000000000004, "0.30000000000000004"),
            (123.456, "123.456"),
            (-0.00012, "-0.00012"),
            (100.0, "100.0"),
            (f64::NAN, "nan"),
            (f64::INFINITY, "inf"),
            (f64::NEG_INFINITY, "-inf"),
            (2.5e-6, "2.5e-06"),
        ];
        for (v, want) in cases {
            assert_eq!(py_float(v), want, "{v:e}");
        }
    }

    #[test]
    fn manual_example_encodes_and_decodes() {
        // PROTOCOL.md §4: position 0.1 rad, velocity −0.25 rad/s, hold 0, counter 0x2A
        let c = joint_cmd();
        let mut data = [0u8; 8];
        c.encode(&[0.1, -0.25, 0.0, 42.0, 0.0], &mut data).unwrap();
        assert_eq!(data, [0xa0, 0x86, 0x01, 0x3c, 0xf6, 0x00, 0x2a, 0x00]);
        let mut raw = [0i64; 5];
        c.decode(&data, &mut raw).unwrap();
        assert_eq!(raw, [100000, -2500, 0, 42, 0]);
        assert_eq!(c.physical(0, raw[0]), 100000.0 * 1e-6);
        assert_eq!(c.physical(1, raw[1]), -2500.0 * 0.0001);
    }

    #[test]
    fn rounding_is_pythons_ties_to_even() {
        let c = joint_cmd();
        let mut data = [0u8; 8];
        let mut raw = [0i64; 5];
        // Python: 5e-07 / 1e-06 == 0.5 → 0 (even), 1.5e-06 → 2, 3.5e-06 → 4; but
        // 2.5e-06 / 1e-06 == 2.5000000000000004 → 3 (the division rounds first)
        for (q, want) in [
            (5e-7, 0),
            (1.5e-6, 2),
            (3.5e-6, 4),
            (-5e-7, 0),
            (-1.5e-6, -2),
            (2.5e-6, 3),
            (-2.5e-6, -3),
            (-0.0, 0),
            (8.388607, 8388607),
        ] {
            c.encode(&[q, 0.0, 1.0, 255.0, 0.0], &mut data).unwrap();
            c.decode(&data, &mut raw).unwrap();
            assert_eq!(raw[0], want, "{q}");
            assert_eq!(raw[2..4], [1, 255]);
        }
    }

    #[test]
    fn encode_errors_are_codec_py_texts() {
        let c = joint_cmd();
        let mut data = [0u8; 8];
        let err = |q: f64, dq: f64, hold: f64| {
            c.encode(&[q, dq, hold, 0.0, 0.0], &mut [0u8; 8])
                .unwrap_err()
                .0
        };
        assert_eq!(
            err(9.0, 0.0, 0.0),
            "JOINT_CMD_J1 (0x201): position_cmd = 9.0 rad outside its DBC range [-8.388608, 8.388607]"
        );
        assert_eq!(
            err(f64::NAN, 0.0, 0.0),
            "JOINT_CMD_J1 (0x201): position_cmd = nan rad is not finite"
        );
        assert_eq!(
            err(0.0, -1e300, 0.0),
            "JOINT_CMD_J1 (0x201): velocity_cmd = -1e+300 rad/s outside its DBC range [-3.2768, 3.2767]"
        );
        assert_eq!(
            err(0.0, 0.0, 0.5),
            "JOINT_CMD_J1 (0x201): hold = 0.5 must be an integer"
        );
        assert_eq!(
            err(0.0, 0.0, 2.0),
            "JOINT_CMD_J1 (0x201): hold = 2 outside its DBC range [0, 1]"
        );
        // counter has no DBC range in this table: the field overflow is checked
        let e = c
            .encode(&[0.0, 0.0, 0.0, 256.0, 0.0], &mut data)
            .unwrap_err()
            .0;
        assert_eq!(
            e,
            "JOINT_CMD_J1 (0x201): counter = 256 is raw 256, outside the 8-bit field's 0..255"
        );
        let e = c
            .encode(&[0.0, 0.0, 0.0, 1e20, 0.0], &mut data)
            .unwrap_err()
            .0;
        assert!(
            e.ends_with("is raw 100000000000000000000, outside the 8-bit field's 0..255"),
            "{e}"
        );
    }

    #[test]
    fn decode_checks_the_accepted_raw_range() {
        let mut t = json!({"name": "S", "id": 16, "where": "S (0x010)", "length": 2, "fd": false,
                           "brs": false, "extended": false,
                           "signals": [signal("state", 0, 8, false, "identity", json!(1)),
                                       signal("t", 8, 8, true, "linear", json!(0.5))]});
        t["signals"][0]["minimum"] = json!(0);
        t["signals"][0]["maximum"] = json!(3);
        t["signals"][0]["decode_raw"] = json!([0, 3]);
        t["signals"][1]["minimum"] = json!(-10.0);
        t["signals"][1]["maximum"] = json!(10.0);
        t["signals"][1]["decode_raw"] = json!([-21, 21]);
        let c = MessageCodec::from_table(&t, "m").unwrap();
        let mut raw = [0i64; 2];
        let mut text = String::new();
        let e = c.decode(&[4, 0], &mut raw).unwrap_err();
        c.write_decode_error(&e, &mut text);
        assert_eq!(text, "S (0x010): state = 4 outside its range [0, 3]");
        text.clear();
        let e = c.decode(&[3, (-22i8) as u8], &mut raw).unwrap_err();
        c.write_decode_error(&e, &mut text);
        assert_eq!(text, "S (0x010): t = -11.0 outside its range [-10.0, 10.0]");
        c.decode(&[3, (-21i8) as u8], &mut raw).unwrap();
        assert_eq!((raw, c.physical(1, raw[1])), ([3, -21], -10.5));
        text.clear();
        let e = c.decode(&[3], &mut raw).unwrap_err();
        c.write_decode_error(&e, &mut text);
        assert_eq!(text, "S (0x010): 1 data bytes, expected 2");
    }

    #[test]
    fn wide_fields_anywhere_in_a_64_byte_frame() {
        let sigs = vec![
            signal("a", 3, 64, true, "identity", json!(1)),
            signal("b", 67, 63, false, "identity", json!(1)),
            signal("c", 500, 12, true, "identity", json!(1)),
        ];
        let t = json!({"name": "W", "id": 0x123, "where": "W (0x123)", "length": 64, "fd": true,
                       "brs": true, "extended": false, "signals": sigs});
        let c = MessageCodec::from_table(&t, "m").unwrap();
        let mut data = [0u8; 64];
        let mut raw = [0i64; 3];
        // identity values travel as f64: take ones it holds exactly
        let values = [
            -(1i64 << 62) as f64,
            ((1u64 << 62) + (1 << 20)) as f64,
            -2048.0,
        ];
        c.encode(&values, &mut data).unwrap();
        c.decode(&data, &mut raw).unwrap();
        assert_eq!(raw, [-(1i64 << 62), (1i64 << 62) + (1 << 20), -2048]);
    }

    #[test]
    fn bad_tables_name_the_entry() {
        let mut t = json!({"name": "X", "id": 1, "where": "X (0x001)", "length": 8, "fd": false,
                           "brs": false, "extended": false,
                           "signals": [signal("a", 0, 8, false, "identity", json!(1))]});
        t["signals"][0].as_object_mut().unwrap().remove("scale");
        assert_eq!(
            MessageCodec::from_table(&t, "m").unwrap_err(),
            "m.signals[0: a].scale: missing"
        );
        t["signals"][0]["scale"] = json!("x");
        assert!(MessageCodec::from_table(&t, "m")
            .unwrap_err()
            .starts_with("m.signals[0: a].scale: expected a number"));
        t["signals"][0]["scale"] = json!(1);
        t["signals"][0]["start_bit"] = json!(60);
        assert!(MessageCodec::from_table(&t, "m")
            .unwrap_err()
            .contains("do not fit the 8-byte frame"));
        t["signals"][0]["start_bit"] = json!(0);
        t["signals"]
            .as_array_mut()
            .unwrap()
            .push(signal("b", 4, 8, false, "identity", json!(1)));
        assert!(MessageCodec::from_table(&t, "m")
            .unwrap_err()
            .contains("overlaps another signal of X"));
        t["length"] = json!(9);
        assert!(MessageCodec::from_table(&t, "m")
            .unwrap_err()
            .contains("no classic CAN frame's length"));
    }

    #[test]
    fn floats_as_strings_are_read_exactly() {
        assert_eq!(
            f64_of(&json!("0.30000000000000004")),
            Some(0.30000000000000004)
        );
        assert!(f64_of(&json!("nan")).unwrap().is_nan());
        assert_eq!(f64_of(&json!("-inf")), Some(f64::NEG_INFINITY));
        assert_eq!(f64_of(&json!(1e-6)), Some(1e-6));
        assert_eq!(f64_of(&json!(true)), None);
    }
}
