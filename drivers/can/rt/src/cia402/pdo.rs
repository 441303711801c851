//! A mapped PDO of a CiA 402 drive (cia402.rs): its COB-ID and how its objects pack into a
//! classic CAN frame, little-endian with no gaps, as Python's struct packs them, with struct's
//! words for a value that does not fit.

use serde_json::Value;

use super::table_fields::{text, uint};
use crate::adapter::FrameError;
use crate::frame::{Frame, CAN_SFF_MASK};

/// One mapped object's packing: a Python struct format code with standard sizes ("<").
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) struct Field(u8);

impl Field {
    fn parse(code: u8) -> Option<Field> {
        b"bBhHiIlLqQ".contains(&code).then_some(Field(code))
    }

    /// [bytes]
    fn size(self) -> usize {
        match self.0 {
            b'b' | b'B' => 1,
            b'h' | b'H' => 2,
            b'i' | b'I' | b'l' | b'L' => 4,
            _ => 8,
        }
    }

    fn signed(self) -> bool {
        self.0.is_ascii_lowercase()
    }

    /// The values it holds: (min, max).
    pub(super) fn range(self) -> (i128, i128) {
        let bits = 8 * self.size() as u32;
        if self.signed() {
            (-(1i128 << (bits - 1)), (1i128 << (bits - 1)) - 1)
        } else {
            (0, (1i128 << bits) - 1)
        }
    }

    /// Python struct's text for a value out of range (struct.error).
    fn range_error(self) -> String {
        let (lo, hi) = self.range();
        match self.0 {
            b'b' => format!("byte format requires {lo} <= number <= {hi}"),
            b'B' => format!("ubyte format requires {lo} <= number <= {hi}"),
            b'h' => format!("short format requires {lo} <= number <= {hi}"),
            b'H' => format!("ushort format requires {lo} <= number <= {hi}"),
            b'q' | b'Q' => "argument out of range".into(),
            c => format!("'{}' format requires {lo} <= number <= {hi}", c as char),
        }
    }

    fn get(self, bytes: &[u8]) -> i128 {
        let mut raw = [0u8; 8];
        raw[..bytes.len()].copy_from_slice(bytes);
        let u = u64::from_le_bytes(raw);
        if self.signed() {
            let shift = 64 - 8 * self.size() as u32;
            (((u << shift) as i64) >> shift) as i128
        } else {
            u as i128
        }
    }

    fn put(self, value: i128, bytes: &mut [u8]) {
        let raw = (value as u64).to_le_bytes();
        bytes.copy_from_slice(&raw[..bytes.len()]);
    }
}

/// One mapped PDO: its COB-ID and how its mapped objects pack (little-endian, no gaps).
#[derive(Clone, Copy, Debug)]
pub(super) struct Pdo {
    pub(super) cob_id: u32,
    fields: [Field; 8],
    n_fields: usize,
    /// [bytes]
    pub(super) size: usize,
}

impl Pdo {
    /// A PDO of the tables: {cob_id, format (a struct format, "<Hl"), objects}.
    pub(super) fn from_json(v: &Value, what: &str, n_fields: usize) -> Result<Pdo, String> {
        let cob_id = uint(v, "cob_id", what)?;
        if cob_id > CAN_SFF_MASK as u64 {
            return Err(format!(
                "{what}.cob_id: 0x{cob_id:X} is not an 11-bit CAN id"
            ));
        }
        let format = text(v, "format", what)?;
        let codes = format.strip_prefix('<').ok_or_else(|| {
            format!("{what}.format: {format:?} is not a little-endian struct format")
        })?;
        let mut pdo = Pdo {
            cob_id: cob_id as u32,
            fields: [Field(b'B'); 8],
            n_fields: 0,
            size: 0,
        };
        for code in codes.bytes() {
            let field = Field::parse(code).ok_or_else(|| {
                format!("{what}.format: {format:?}: only integer codes bBhHiIlLqQ are supported")
            })?;
            if pdo.n_fields == 8 {
                return Err(format!("{what}.format: {format:?} has more than 8 objects"));
            }
            pdo.fields[pdo.n_fields] = field;
            pdo.n_fields += 1;
            pdo.size += field.size();
        }
        if pdo.size > 8 {
            return Err(format!(
                "{what}: {} bytes do not fit a classic CAN frame",
                pdo.size
            ));
        }
        if pdo.n_fields != n_fields {
            return Err(format!(
                "{what}.format: {format:?} packs {} objects, the cycle needs {n_fields}",
                pdo.n_fields
            ));
        }
        let objects = v.get("objects").and_then(Value::as_array);
        if objects.is_some_and(|o| o.len() != n_fields) {
            return Err(format!(
                "{what}.objects: not {n_fields} objects as its format"
            ));
        }
        Ok(pdo)
    }

    pub(super) fn field(&self, k: usize) -> Field {
        self.fields[k]
    }

    /// The values of a frame of exactly `size` bytes.
    pub(super) fn unpack<const N: usize>(&self, data: &[u8]) -> [i128; N] {
        let mut out = [0i128; N];
        let mut at = 0;
        for (k, v) in out.iter_mut().enumerate() {
            let f = self.fields[k];
            *v = f.get(&data[at..at + f.size()]);
            at += f.size();
        }
        out
    }

    /// The frame of `values`; Err(index of the value that does not fit its field).
    pub(super) fn pack(&self, values: &[i128]) -> Result<Frame, usize> {
        let mut frame = Frame::empty(self.cob_id);
        let mut at = 0;
        for (k, &v) in values.iter().enumerate().take(self.n_fields) {
            let f = self.fields[k];
            let (lo, hi) = f.range();
            if v < lo || v > hi {
                return Err(k);
            }
            f.put(v, &mut frame.data[at..at + f.size()]);
            at += f.size();
        }
        frame.len = self.size as u8;
        Ok(frame)
    }
}

/// Joint `k`'s value that does not fit `field` of its `pdo`, in Python struct's words.
pub(super) fn pack_error(k: usize, pdo: &str, field: Field) -> FrameError {
    FrameError(format!("CiA 402 J{} {pdo}: {}", k + 1, field.range_error()))
}
