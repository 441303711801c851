//! What every binary layout shares (messages.rs): the layout version, the little-endian field
//! access, the header and finiteness checks of gateway/messages.py, and the [`MessageError`]
//! that names what was wrong.

use super::python_text::{py_bytes_repr, py_repr};

/// Layout version of every binary message except [`JointCommand`](super::JointCommand).
pub const LAYOUT_VERSION: u8 = 1;

/// A payload that is not the message it claims to be (gateway/errors.py MessageError); the
/// text names the message, the field and what is wrong, as Python's does.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct MessageError(pub String);

impl std::fmt::Display for MessageError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.0)
    }
}

impl std::error::Error for MessageError {}

pub(super) fn f64_at(data: &[u8], offset: usize) -> f64 {
    let mut b = [0u8; 8];
    b.copy_from_slice(&data[offset..offset + 8]);
    f64::from_le_bytes(b)
}

pub(super) fn u32_at(data: &[u8], offset: usize) -> u32 {
    u32::from_le_bytes([
        data[offset],
        data[offset + 1],
        data[offset + 2],
        data[offset + 3],
    ])
}

pub(super) fn put_f64s(out: &mut Vec<u8>, values: &[f64]) {
    for v in values {
        out.extend_from_slice(&v.to_le_bytes());
    }
}

/// gateway/messages.py `_check_header`: length at least `min_len`, the magic, the version.
pub(super) fn check_header(
    data: &[u8],
    magic: &[u8; 4],
    what: &str,
    min_len: usize,
    version: u8,
) -> Result<(), MessageError> {
    if data.len() < min_len {
        return Err(MessageError(format!(
            "{what}: payload is {} bytes, shorter than its header",
            data.len()
        )));
    }
    if &data[..4] != magic {
        return Err(MessageError(format!(
            "{what}: magic {} is not {}",
            py_bytes_repr(&data[..4]),
            py_bytes_repr(magic)
        )));
    }
    if data[4] != version {
        return Err(MessageError(format!(
            "{what}: layout version {} unsupported (want {version})",
            data[4]
        )));
    }
    Ok(())
}

/// gateway/messages.py `_finite`: the first value that is not finite, named.
pub(super) fn check_finite(name: &str, values: &[f64]) -> Result<(), MessageError> {
    match values.iter().position(|v| !v.is_finite()) {
        None => Ok(()),
        Some(bad) => Err(MessageError(format!(
            "{name}[{bad}] is {}; every value must be finite",
            py_repr(values[bad])
        ))),
    }
}
