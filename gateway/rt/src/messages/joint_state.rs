//! JointState, one controller cycle of joint feedback as the CAN driver publishes it
//! (messages.rs): its binary layout, encoded without allocating and decoded with every check of
//! gateway/messages.py.

use super::python_text::py_repr;
use super::wire::{
    check_finite, check_header, f64_at, put_f64s, u32_at, MessageError, LAYOUT_VERSION,
};
use crate::{ControllerState, MAX_JOINTS};

/// One controller cycle of joint feedback as the CAN driver publishes it (gateway/messages.py
/// JointState). The driver only encodes it ([`JointState::pack`]); the decoded form, with its
/// vectors, is for tests and tools.
#[derive(Clone, Debug, PartialEq)]
pub struct JointState {
    /// controller cycle counter (32 bits on the wire, widened by the driver)
    pub cycle: i64,
    /// driver monotonic time when the full cycle had arrived [s]
    pub stamp_s: f64,
    pub controller_state: ControllerState,
    /// FLAG_* bits
    pub flags: u8,
    /// measured joint positions [rad]
    pub q_rad: Vec<f64>,
    /// measured joint velocities [rad/s]
    pub dq_rad_s: Vec<f64>,
    /// motor currents less the sensors' zero [A]
    pub current_a: Vec<f64>,
    /// the position command last sent to the controller [rad]
    pub q_cmd_rad: Vec<f64>,
    /// the velocity command last sent [rad/s]
    pub dq_cmd_rad_s: Vec<f64>,
    /// the controller's command cycle [s]; 0 = not reported
    pub cycle_period_s: f64,
}

impl JointState {
    pub const MAGIC: &'static [u8; 4] = b"LTJS";
    /// `<4sBBIdBBd`: magic, version, n, cycle, stamp, controller state, flags, period [bytes].
    pub const HEAD_SIZE: usize = 28;

    /// Bytes of a JointState of `n` joints.
    pub fn size(n: usize) -> usize {
        Self::HEAD_SIZE + 5 * n * 8
    }

    /// Number of joints.
    pub fn n(&self) -> usize {
        self.q_rad.len()
    }

    /// The wire bytes of a JointState into `out` (cleared first), straight from the slices
    /// (the CAN driver's hot path; the arguments after `out` are Python's `JointState.pack`'s,
    /// `controller_state` its value as there). `out` is not reallocated when its capacity
    /// holds [`JointState::size`]`(n)` bytes: reserve that once. The caller guarantees finite
    /// values (decoded frames, sent commands); Err if the five slices differ in length or
    /// their length is no joint count (1..16), and then `out` is left empty.
    #[allow(clippy::too_many_arguments)]
    pub fn pack(
        out: &mut Vec<u8>,
        cycle: i64,
        stamp_s: f64,
        controller_state: u8,
        flags: u8,
        cycle_period_s: f64,
        q_rad: &[f64],
        dq_rad_s: &[f64],
        current_a: &[f64],
        q_cmd_rad: &[f64],
        dq_cmd_rad_s: &[f64],
    ) -> Result<(), MessageError> {
        out.clear();
        let n = q_rad.len();
        if [dq_rad_s, current_a, q_cmd_rad, dq_cmd_rad_s]
            .iter()
            .any(|v| v.len() != n)
            || !(1..=MAX_JOINTS).contains(&n)
        {
            return Err(MessageError(format!(
                "JointState: {n}, {}, {}, {}, {} values; each must be 1..{MAX_JOINTS} joints",
                dq_rad_s.len(),
                current_a.len(),
                q_cmd_rad.len(),
                dq_cmd_rad_s.len()
            )));
        }
        out.extend_from_slice(Self::MAGIC);
        out.push(LAYOUT_VERSION);
        out.push(n as u8);
        out.extend_from_slice(&((cycle & 0xFFFF_FFFF) as u32).to_le_bytes());
        out.extend_from_slice(&stamp_s.to_le_bytes());
        out.push(controller_state);
        out.push(flags);
        out.extend_from_slice(&cycle_period_s.to_le_bytes());
        for values in [q_rad, dq_rad_s, current_a, q_cmd_rad, dq_cmd_rad_s] {
            put_f64s(out, values);
        }
        Ok(())
    }

    /// The wire bytes (allocates; tests and tools).
    pub fn to_bytes(&self) -> Result<Vec<u8>, MessageError> {
        let mut out = Vec::with_capacity(Self::size(self.n()));
        Self::pack(
            &mut out,
            self.cycle,
            self.stamp_s,
            self.controller_state as u8,
            self.flags,
            self.cycle_period_s,
            &self.q_rad,
            &self.dq_rad_s,
            &self.current_a,
            &self.q_cmd_rad,
            &self.dq_cmd_rad_s,
        )?;
        Ok(out)
    }

    /// Decode with every check of Python's `JointState.from_bytes` (allocates).
    pub fn from_bytes(data: &[u8]) -> Result<JointState, MessageError> {
        check_header(
            data,
            Self::MAGIC,
            "JointState",
            Self::HEAD_SIZE,
            LAYOUT_VERSION,
        )?;
        let n = data[5] as usize;
        let cycle = u32_at(data, 6) as i64;
        let stamp = f64_at(data, 10);
        let cstate = data[18];
        let flags = data[19];
        let period = f64_at(data, 20);
        if !(1..=MAX_JOINTS).contains(&n) {
            return Err(MessageError(format!(
                "JointState: joint count {n} outside 1..16"
            )));
        }
        let want = Self::size(n);
        if data.len() != want {
            return Err(MessageError(format!(
                "JointState: {} bytes, expected {want} for {n} joints",
                data.len()
            )));
        }
        if !(stamp.is_finite() && period.is_finite() && period >= 0.0) {
            return Err(MessageError(format!(
                "JointState: stamp_s {} / cycle_period_s {} invalid",
                py_repr(stamp),
                py_repr(period)
            )));
        }
        let controller_state = ControllerState::from_u8(cstate).ok_or_else(|| {
            MessageError(format!("JointState: controller_state {cstate} unknown"))
        })?;
        let block = |k: usize| -> Vec<f64> {
            (0..n)
                .map(|j| f64_at(data, Self::HEAD_SIZE + (k * n + j) * 8))
                .collect()
        };
        let names = [
            "q_rad",
            "dq_rad_s",
            "current_a",
            "q_cmd_rad",
            "dq_cmd_rad_s",
        ];
        let mut body: Vec<Vec<f64>> = (0..5).map(block).collect();
        for (values, name) in body.iter().zip(names) {
            check_finite(&format!("JointState.{name}"), values)?;
        }
        let dq_cmd = body.pop().unwrap_or_default();
        let q_cmd = body.pop().unwrap_or_default();
        let current = body.pop().unwrap_or_default();
        let dq = body.pop().unwrap_or_default();
        let q = body.pop().unwrap_or_default();
        Ok(JointState {
            cycle,
            stamp_s: stamp,
            controller_state,
            flags,
            q_rad: q,
            dq_rad_s: dq,
            current_a: current,
            q_cmd_rad: q_cmd,
            dq_cmd_rad_s: dq_cmd,
            cycle_period_s: period,
        })
    }
}
