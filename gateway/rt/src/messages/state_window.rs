//! StateWindow, the joint states of a window of controller cycles for readers off the cycle
//! (messages.rs): its binary layout, encoded without allocating and decoded with every check of
//! gateway/messages.py.

use super::python_text::py_repr;
use super::wire::{
    check_finite, check_header, f64_at, put_f64s, u32_at, MessageError, LAYOUT_VERSION,
};
use crate::MAX_JOINTS;

/// The joint states of a window of controller cycles, for readers off the cycle
/// (gateway/messages.py StateWindow): how many, the fastest joint speed any of them read,
/// each joint's lowest and highest position, and the newest JointState whole. The driver only
/// encodes it ([`StateWindow::pack`]); the decoded form is for tests and tools.
#[derive(Clone, Debug, PartialEq)]
pub struct StateWindow {
    /// controller cycles in the window (>= 1)
    pub states: u32,
    /// the fastest joint's measured speed in any of them [rad/s]
    pub max_speed_rad_s: f64,
    /// each joint's lowest measured position in the window [rad]
    pub q_lo_rad: Vec<f64>,
    /// ... and its highest [rad]
    pub q_hi_rad: Vec<f64>,
    /// the window's last JointState payload
    pub newest: Vec<u8>,
}

impl StateWindow {
    pub const MAGIC: &'static [u8; 4] = b"LTSW";
    /// `<4sBBId`: magic, version, n, states, max speed [bytes].
    pub const HEAD_SIZE: usize = 18;

    /// Bytes of a window of `n` joints whose newest state is `newest_len` bytes.
    pub fn size(n: usize, newest_len: usize) -> usize {
        Self::HEAD_SIZE + 2 * n * 8 + newest_len
    }

    /// The wire bytes of a window into `out` (cleared first; not reallocated when its
    /// capacity holds [`StateWindow::size`]). Err (and `out` empty) if the bounds differ in
    /// length or are no joint count (1..16).
    pub fn pack(
        out: &mut Vec<u8>,
        states: u32,
        max_speed_rad_s: f64,
        q_lo_rad: &[f64],
        q_hi_rad: &[f64],
        newest: &[u8],
    ) -> Result<(), MessageError> {
        out.clear();
        let n = q_lo_rad.len();
        if q_hi_rad.len() != n || !(1..=MAX_JOINTS).contains(&n) {
            return Err(MessageError(format!(
                "StateWindow: {n} lowest and {} highest positions",
                q_hi_rad.len()
            )));
        }
        out.extend_from_slice(Self::MAGIC);
        out.push(LAYOUT_VERSION);
        out.push(n as u8);
        out.extend_from_slice(&states.to_le_bytes());
        out.extend_from_slice(&max_speed_rad_s.to_le_bytes());
        put_f64s(out, q_lo_rad);
        put_f64s(out, q_hi_rad);
        out.extend_from_slice(newest);
        Ok(())
    }

    /// Decode with every check of Python's `StateWindow.from_bytes` (the newest state is
    /// checked by whoever decodes it; allocates).
    pub fn from_bytes(data: &[u8]) -> Result<StateWindow, MessageError> {
        check_header(
            data,
            Self::MAGIC,
            "StateWindow",
            Self::HEAD_SIZE,
            LAYOUT_VERSION,
        )?;
        let n = data[5] as usize;
        let states = u32_at(data, 6);
        let speed = f64_at(data, 10);
        if !(1..=MAX_JOINTS).contains(&n) {
            return Err(MessageError(format!(
                "StateWindow: joint count {n} outside 1..16"
            )));
        }
        let end = Self::HEAD_SIZE + 2 * n * 8;
        if data.len() <= end {
            return Err(MessageError(format!(
                "StateWindow: {} bytes, no state after {n} bounds",
                data.len()
            )));
        }
        if states < 1 || !(speed.is_finite() && speed >= 0.0) {
            return Err(MessageError(format!(
                "StateWindow: {states} states / max speed {} invalid",
                py_repr(speed)
            )));
        }
        let lo: Vec<f64> = (0..n)
            .map(|j| f64_at(data, Self::HEAD_SIZE + j * 8))
            .collect();
        let hi: Vec<f64> = (0..n)
            .map(|j| f64_at(data, Self::HEAD_SIZE + (n + j) * 8))
            .collect();
        check_finite("StateWindow.q_lo_rad", &lo)?;
        check_finite("StateWindow.q_hi_rad", &hi)?;
        if lo.iter().zip(&hi).any(|(l, h)| l > h) {
            return Err(MessageError(
                "StateWindow: a joint's lowest position is above its highest".into(),
            ));
        }
        Ok(StateWindow {
            states,
            max_speed_rad_s: speed,
            q_lo_rad: lo,
            q_hi_rad: hi,
            newest: data[end..].to_vec(),
        })
    }
}
