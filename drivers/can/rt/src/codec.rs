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
//! someone wants the text, so a bad frame costs no allocation either. The table readers
//! (codec/table_readers.rs) are shared with the LTC adapters (ltc_base.rs, ltc_adapter.rs).

use std::fmt::Write;

use serde_json::Value;

use crate::adapter::FrameError;
use crate::frame::CANFD_MAX_DLEN;

mod float_repr;
mod table_readers;

pub use self::float_repr::{py_float, write_py_float};
pub use self::table_readers::f64_of;
pub(crate) use self::table_readers::{array, boolean, field, float, int, text, uint};
use self::table_readers::{int_pair, optional_float};

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

#[cfg(test)]
#[path = "codec_tests.rs"]
mod tests;
