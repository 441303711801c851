//! JointCommand, the position/velocity command computed from one JointState (messages.rs): its
//! binary layout, encoded and decoded without allocating, with every check of
//! gateway/messages.py.

use super::python_text::py_repr;
use super::wire::{check_finite, check_header, f64_at, put_f64s, u32_at, MessageError};
use crate::MAX_JOINTS;

/// A position/velocity command computed from one JointState (gateway/messages.py
/// JointCommand), decoded without allocating: only the first `n` entries of each array are
/// joints.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct JointCommand {
    /// the JointState.cycle this command answers (32 bits on the wire)
    pub cycle: i64,
    /// JointState.stamp_s it was computed from: ages the command [s]
    pub state_stamp_s: f64,
    /// control-process monotonic time at publication [s]
    pub sent_stamp_s: f64,
    /// number of joints
    pub n: usize,
    /// position command [rad]; see [`JointCommand::q_cmd_rad`]
    pub q_cmd_rad: [f64; MAX_JOINTS],
    /// velocity command [rad/s]; see [`JointCommand::dq_cmd_rad_s`]
    pub dq_cmd_rad_s: [f64; MAX_JOINTS],
    /// control-process monotonic time the JointState arrived [s]; 0 = not reported
    pub state_rx_stamp_s: f64,
}

impl JointCommand {
    pub const MAGIC: &'static [u8; 4] = b"LTJC";
    /// Layout 2 added `state_rx_stamp_s`.
    pub const VERSION: u8 = 2;
    /// `<4sBBIddd`: magic, version, n, cycle, three stamps [bytes].
    pub const HEAD_SIZE: usize = 34;

    /// Bytes of a JointCommand of `n` joints.
    pub fn size(n: usize) -> usize {
        Self::HEAD_SIZE + 2 * n * 8
    }

    /// The position command's joints [rad].
    pub fn q_cmd_rad(&self) -> &[f64] {
        &self.q_cmd_rad[..self.n]
    }

    /// The velocity command's joints [rad/s].
    pub fn dq_cmd_rad_s(&self) -> &[f64] {
        &self.dq_cmd_rad_s[..self.n]
    }

    /// Decode with every check of Python's `JointCommand.from_bytes`; no allocation unless
    /// the payload is refused.
    pub fn from_bytes(data: &[u8]) -> Result<JointCommand, MessageError> {
        check_header(
            data,
            Self::MAGIC,
            "JointCommand",
            Self::HEAD_SIZE,
            Self::VERSION,
        )?;
        let n = data[5] as usize;
        let cycle = u32_at(data, 6) as i64;
        let state_stamp = f64_at(data, 10);
        let sent_stamp = f64_at(data, 18);
        let rx_stamp = f64_at(data, 26);
        if !(1..=MAX_JOINTS).contains(&n) {
            return Err(MessageError(format!(
                "JointCommand: joint count {n} outside 1..16"
            )));
        }
        let want = Self::size(n);
        if data.len() != want {
            return Err(MessageError(format!(
                "JointCommand: {} bytes, expected {want} for {n} joints",
                data.len()
            )));
        }
        if !(state_stamp.is_finite() && sent_stamp.is_finite() && rx_stamp.is_finite()) {
            return Err(MessageError("JointCommand: stamps must be finite".into()));
        }
        let mut cmd = JointCommand {
            cycle,
            state_stamp_s: state_stamp,
            sent_stamp_s: sent_stamp,
            n,
            q_cmd_rad: [0.0; MAX_JOINTS],
            dq_cmd_rad_s: [0.0; MAX_JOINTS],
            state_rx_stamp_s: rx_stamp,
        };
        for j in 0..n {
            cmd.q_cmd_rad[j] = f64_at(data, Self::HEAD_SIZE + j * 8);
            cmd.dq_cmd_rad_s[j] = f64_at(data, Self::HEAD_SIZE + (n + j) * 8);
        }
        check_finite("JointCommand.q_cmd_rad", cmd.q_cmd_rad())?;
        check_finite("JointCommand.dq_cmd_rad_s", cmd.dq_cmd_rad_s())?;
        Ok(cmd)
    }

    /// The wire bytes of a JointCommand into `out` (cleared first; not reallocated when its
    /// capacity holds [`JointCommand::size`]`(n)`), with Python's `JointCommand.pack`
    /// checks: a command that is not finite is never encoded.
    pub fn pack(
        out: &mut Vec<u8>,
        cycle: i64,
        state_stamp_s: f64,
        sent_stamp_s: f64,
        q_cmd_rad: &[f64],
        dq_cmd_rad_s: &[f64],
        state_rx_stamp_s: f64,
    ) -> Result<(), MessageError> {
        out.clear();
        let n = q_cmd_rad.len();
        if dq_cmd_rad_s.len() != n || !(1..=MAX_JOINTS).contains(&n) {
            return Err(MessageError(format!(
                "JointCommand: {n} positions and {} velocities",
                dq_cmd_rad_s.len()
            )));
        }
        for (name, values) in [("q_cmd_rad", q_cmd_rad), ("dq_cmd_rad_s", dq_cmd_rad_s)] {
            if let Some(k) = values.iter().position(|v| !v.is_finite()) {
                return Err(MessageError(format!(
                    "JointCommand.{name}[{k}] is {}; must be finite",
                    py_repr(values[k])
                )));
            }
        }
        let stamps = [state_stamp_s, sent_stamp_s, state_rx_stamp_s];
        if !stamps.iter().all(|v| v.is_finite()) {
            return Err(MessageError("JointCommand: stamps must be finite".into()));
        }
        out.extend_from_slice(Self::MAGIC);
        out.push(Self::VERSION);
        out.push(n as u8);
        out.extend_from_slice(&((cycle & 0xFFFF_FFFF) as u32).to_le_bytes());
        put_f64s(out, &stamps);
        put_f64s(out, q_cmd_rad);
        put_f64s(out, dq_cmd_rad_s);
        Ok(())
    }

    /// The wire bytes (allocates; tests and tools).
    pub fn to_bytes(&self) -> Result<Vec<u8>, MessageError> {
        let mut out = Vec::with_capacity(Self::size(self.n));
        Self::pack(
            &mut out,
            self.cycle,
            self.state_stamp_s,
            self.sent_stamp_s,
            self.q_cmd_rad(),
            self.dq_cmd_rad_s(),
            self.state_rx_stamp_s,
        )?;
        Ok(out)
    }
}
