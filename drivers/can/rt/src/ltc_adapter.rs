//! LTC-1, the robot controller's classic-CAN external-command protocol, seen from the host:
//! drivers/can/ltc.py's `LtcAdapter` compiled, bit for bit and text for text.
//!
//! Per control cycle the controller sends JOINT_FB_J1..Jn, then CTRL_STATUS, which closes the
//! cycle (PROTOCOL.md §3); the host answers with JOINT_CMD_J1..Jn. A cycle is returned only if
//! the status and every configured joint's feedback (with the status's counter low byte)
//! arrived valid since the previous status; one bad per-cycle frame or a bus error frame loses
//! the whole cycle (§8).
//!
//! What LTC-1 shares with its CAN FD profile LTC-1F (ltc_fd_adapter.rs) is [`LtcBase`]
//! (ltc_base.rs): the tables, the receiver's checks of §8, HOST_REQUEST and the heartbeats.
//!
//! Built by [`LtcAdapter::from_tables`] from drivers/can/rt_tables.py's `ltc_tables("ltc_dbc",
//! n)`; the cycle then allocates nothing: decoded values go to preallocated scratch, errors are
//! kept as `Copy` values and written into `last_error`'s reused buffer.

use std::fmt::Write;

use serde_json::Value;

use crate::adapter::{Adapter, AdapterStats, Feedback, FrameError, HostRequest, MAX_JOINTS};
use crate::codec;
use crate::frame::Frame;
use crate::ltc_base::{LtcBase, LtcError};
use crate::ltc_status::{StatusSignals, STATUS_SIGNALS};

pub use crate::ltc_base::TABLES_FORMAT;
pub use crate::ltc_enums::{CONTROLLER_STATES, FAULT_CODES, HOST_REQUESTS, NMT_STATES};

/// One joint's JOINT_FB of the cycle being assembled.
#[derive(Clone, Copy, Debug)]
struct JointSample {
    /// [rad]
    q: f64,
    /// [rad/s]
    dq: f64,
    /// [A]
    current: f64,
    /// the low byte of the cycle counter it carries
    counter: i64,
}

/// The LTC-1 host adapter (registry name `ltc_dbc`): ltc.py `LtcAdapter`.
pub struct LtcAdapter {
    base: LtcBase,
    stats: AdapterStats,
    /// CTRL_STATUS's message index and id
    status: usize,
    status_id: u32,
    status_signals: StatusSignals,
    /// JOINT_FB_Jk (k = index + 1) message indices, for every joint the DBC carries
    feedback: [usize; MAX_JOINTS],
    /// position, velocity, current, counter of each JOINT_FB
    feedback_signals: [[usize; 4]; MAX_JOINTS],
    /// the joint (1-based) of each message index that is a JOINT_FB, 0 for the others
    joint_of: Vec<u8>,
    /// JOINT_CMD_Jk (k = index + 1) message indices
    command: [usize; MAX_JOINTS],
    /// position_cmd, velocity_cmd, hold, counter, crc of each JOINT_CMD
    command_signals: [[usize; 5]; MAX_JOINTS],
    /// JOINT_FB.counter is the cycle counter modulo this (its low byte)
    feedback_counter_modulus: i64,
    /// the feedback of the cycle being assembled, per configured joint
    joints: [Option<JointSample>; MAX_JOINTS],
    /// why the cycle being assembled is already lost, if it is
    tainted: Option<LtcError>,
}

const FEEDBACK_SIGNALS: [&str; 4] = ["position", "velocity", "current", "counter"];
const COMMAND_SIGNALS: [&str; 5] = ["position_cmd", "velocity_cmd", "hold", "counter", "crc"];

impl LtcAdapter {
    /// Build from rt_tables.py's `ltc_tables("ltc_dbc", n_joints)`; Err names the missing or
    /// wrong entry.
    pub fn from_tables(tables: &Value) -> Result<LtcAdapter, String> {
        let mut base = LtcBase::from_tables(tables, "ltc_dbc", "LTC-1", "classic")?;
        let status = base.spec("CTRL_STATUS")?;
        base.require_only(status, &STATUS_SIGNALS)?;
        let status_signals = StatusSignals::bind(&mut base, status)?;
        let mut feedback = [0; MAX_JOINTS];
        let mut feedback_signals = [[0; 4]; MAX_JOINTS];
        let mut command = [0; MAX_JOINTS];
        let mut command_signals = [[0; 5]; MAX_JOINTS];
        let mut joint_of = vec![0u8; base.specs.len()];
        for k in 0..base.max_joints {
            let fb = base.spec(&format!("JOINT_FB_J{}", k + 1))?;
            base.require_only(fb, &FEEDBACK_SIGNALS)?;
            base.require_integer(fb, &["counter"])?;
            feedback[k] = fb;
            feedback_signals[k] = base.signals(fb, FEEDBACK_SIGNALS)?;
            joint_of[fb] = (k + 1) as u8;
            let cmd = base.spec(&format!("JOINT_CMD_J{}", k + 1))?;
            base.require_only(cmd, &COMMAND_SIGNALS)?;
            base.require_integer(cmd, &["hold", "counter", "crc"])?;
            command[k] = cmd;
            command_signals[k] = base.signals(cmd, COMMAND_SIGNALS)?;
        }
        let m = codec::uint(tables, "feedback_counter_modulus", "tables")?;
        if !(1..=1 << 16).contains(&m) {
            return Err(format!(
                "tables.feedback_counter_modulus: {m} outside 1..65536"
            ));
        }
        Ok(LtcAdapter {
            status_id: base.specs[status].codec.id,
            base,
            stats: AdapterStats {
                last_error: String::with_capacity(256),
                ..Default::default()
            },
            status,
            status_signals,
            feedback,
            feedback_signals,
            joint_of,
            command,
            command_signals,
            feedback_counter_modulus: m as i64,
            joints: [None; MAX_JOINTS],
            tainted: None,
        })
    }

    /// CTRL_STATUS arrived valid: the cycle it closes, if complete and untainted.
    fn close_cycle(&mut self) -> Option<Feedback> {
        let n = self.base.n_joints;
        let joints = std::mem::replace(&mut self.joints, [None; MAX_JOINTS]);
        let tainted = self.tainted.take();
        let raw = &self.base.raw;
        let counter = self.status_signals.counter(raw);
        let stats = &mut self.stats;
        if let Some(e) = tainted {
            stats.corrupt_cycles += 1;
            stats.last_error.clear();
            let _ = write!(stats.last_error, "cycle {counter} dropped: ");
            self.base.write_error(&e, &mut stats.last_error);
            return None;
        }
        let low = counter % self.feedback_counter_modulus;
        let complete = |j: &Option<JointSample>| j.is_some_and(|s| s.counter == low);
        if !joints[..n].iter().all(complete) {
            stats.incomplete_cycles += 1;
            stats.last_error.clear();
            let _ = write!(
                stats.last_error,
                "cycle {counter} dropped: no JOINT_FB with counter {low} for joint(s) ["
            );
            let missing = joints[..n].iter().enumerate().filter(|(_, j)| !complete(j));
            for (i, (k, _)) in missing.enumerate() {
                let _ = write!(
                    stats.last_error,
                    "{}{}",
                    if i > 0 { ", " } else { "" },
                    k + 1
                );
            }
            stats.last_error.push(']');
            return None;
        }
        stats.cycles += 1;
        let mut fb = Feedback::new(n);
        for (k, j) in joints[..n].iter().enumerate() {
            let j = j.expect("complete");
            (fb.q[k], fb.dq[k], fb.current[k]) = (j.q, j.dq, j.current);
        }
        self.status_signals
            .fill(&self.base.specs[self.status].codec, raw, &mut fb);
        Some(fb)
    }
}

impl Adapter for LtcAdapter {
    fn name(&self) -> &'static str {
        "ltc_dbc"
    }

    fn counter_modulus(&self) -> u32 {
        self.base.counter_modulus
    }

    fn host_heartbeat_timeout_s(&self) -> f64 {
        self.base.host_heartbeat_timeout_s
    }

    fn n_joints(&self) -> usize {
        self.base.n_joints
    }

    fn feed(&mut self, frame: &Frame, _now: f64) -> Option<Feedback> {
        self.stats.frames += 1;
        let spec = match self.base.decode(frame) {
            Ok(Some(spec)) => spec,
            Ok(None) => {
                self.stats.unknown_frames += 1;
                return None;
            }
            Err(e) => {
                self.base.count_bad(&e, &mut self.stats);
                if frame.id == self.status_id && !frame.error {
                    // the status that would close this cycle is lost: so is the cycle
                    self.joints = [None; MAX_JOINTS];
                    self.tainted = None;
                    self.stats.corrupt_cycles += 1;
                } else if frame.error || self.base.is_cycle_frame(frame.id) {
                    self.tainted = Some(e);
                }
                return None;
            }
        };
        if spec == self.status {
            return self.close_cycle();
        }
        let joint = self.joint_of[spec] as usize;
        if joint != 0 && joint <= self.base.n_joints {
            // a bigger arm's extra joints are not ours
            let [p, v, c, counter] = self.feedback_signals[joint - 1];
            let codec = &self.base.specs[self.feedback[joint - 1]].codec;
            let raw = &self.base.raw;
            self.joints[joint - 1] = Some(JointSample {
                q: codec.physical(p, raw[p]),
                dq: codec.physical(v, raw[v]),
                current: codec.physical(c, raw[c]),
                counter: raw[counter],
            });
        }
        None // heartbeats; other hosts' commands and requests
    }

    fn command_frames(
        &mut self,
        counter: u32,
        q: &[f64],
        dq: &[f64],
        hold: bool,
        out: &mut Vec<Frame>,
    ) -> Result<(), FrameError> {
        let n = self.base.n_joints;
        if q.len() != n || dq.len() != n {
            return Err(FrameError(format!(
                "JOINT_CMD set needs {n} positions and velocities, got {} and {}",
                q.len(),
                dq.len()
            )));
        }
        let low = counter % self.base.command_counter_modulus;
        let start = out.len();
        for k in 0..n {
            let [p, v, h, c, crc] = self.command_signals[k];
            let values = &mut self.base.values;
            (values[p], values[v], values[h]) = (q[k], dq[k], if hold { 1.0 } else { 0.0 });
            (values[c], values[crc]) = (low as f64, 0.0);
            match self.base.encode(self.command[k]) {
                Ok(frame) => out.push(frame),
                Err(e) => {
                    out.truncate(start);
                    return Err(e);
                }
            }
        }
        Ok(())
    }

    fn request_frames(&mut self, request: HostRequest, out: &mut Vec<Frame>) {
        self.base.request_frames(request, out);
    }

    fn heartbeat_frame(&mut self) -> Frame {
        self.base.heartbeat_frame()
    }

    fn is_cycle_frame(&self, frame: &Frame) -> bool {
        self.base.is_cycle_frame(frame.id)
    }

    fn stats(&self) -> &AdapterStats {
        &self.stats
    }
}

#[cfg(test)]
#[path = "ltc_golden_tests.rs"]
pub(crate) mod golden;

#[cfg(test)]
#[path = "ltc_adapter_tests.rs"]
mod tests;
