//! The CiA 402 adapter's cycle, host-clocked by SYNC (cia402.rs): SYNC opens a cycle, every
//! drive's TPDO1 and TPDO2 complete it, RPDO1 and RPDO2 answer it, and the host's requests,
//! heartbeat and health.

use std::fmt::Write as _;

use serde_json::{Map, Value};

use super::pdo::pack_error;
use super::{format_g, Cia402Adapter, Kind};
use crate::adapter::{Adapter, AdapterStats, Feedback, FrameError, HostRequest};
use crate::frame::Frame;

impl Adapter for Cia402Adapter {
    /// The drives' fault text ([`Cia402Adapter::fault_text`]) while some drive faults.
    fn fault_detail(&self) -> Option<&str> {
        Some(self.fault_text.as_str()).filter(|t| *t != "NONE")
    }

    fn name(&self) -> &'static str {
        "cia402"
    }

    fn counter_modulus(&self) -> u32 {
        self.counter_modulus
    }

    fn host_heartbeat_timeout_s(&self) -> f64 {
        self.host_heartbeat_timeout_s
    }

    fn clock_period_s(&self) -> Option<f64> {
        Some(self.clock_period_s)
    }

    fn n_joints(&self) -> usize {
        self.joints.len()
    }

    /// SYNC: opens a cycle (counting the last incomplete if some drive had answered it but
    /// not all) and advances the counter.
    fn clock_frames(&mut self, out: &mut Vec<Frame>) {
        if self
            .joints
            .iter()
            .any(|j| j.tp1.is_some() || j.tp2.is_some())
        {
            self.stats.incomplete_cycles += 1;
            self.set_last_error("a SYNC went out before every drive had answered the last");
        }
        for j in self.joints.iter_mut() {
            j.tp1 = None;
            j.tp2 = None;
        }
        self.corrupt = false;
        self.sync_count = ((self.sync_count as u64 + 1) % self.counter_modulus as u64) as u32;
        out.push(Frame::empty(self.sync_cob_id));
    }

    /// Heartbeats (NMT state, arrival at `now`), EMCY (the error code) and TPDOs; the cycle
    /// once every drive's two TPDOs have come since the SYNC. [`Feedback::fault`] is "NONE"
    /// or the first fault's kind: LEFT_OPERATION_ENABLED (the latch), DRIVE_FAULT,
    /// QUICK_STOP, NMT_STATE or HEARTBEAT_LOST; the full text is
    /// [`Cia402Adapter::fault_text`].
    fn feed(&mut self, frame: &Frame, now: f64) -> Option<Feedback> {
        self.stats.frames += 1;
        if frame.error || frame.remote || frame.extended {
            self.stats.bad_frames += 1;
            self.set_last_error("error, remote or extended frame");
            return None;
        }
        let Some((k, kind)) = self.slot(frame.id) else {
            self.stats.unknown_frames += 1;
            return None;
        };
        let data = frame.payload();
        let j = &mut self.joints[k];
        match kind {
            Kind::Heartbeat => {
                j.nmt_state = data.first().map_or(-1, |b| (b & 0x7F) as i16);
                j.heartbeat_s = Some(now);
                return None;
            }
            Kind::Emcy => {
                j.emcy_code = if data.len() >= 2 {
                    u16::from_le_bytes([data[0], data[1]])
                } else {
                    0
                };
                return None;
            }
            Kind::Tpdo1 | Kind::Tpdo2 => {}
        }
        let pdo = if kind == Kind::Tpdo1 {
            j.tpdo1
        } else {
            j.tpdo2
        };
        if data.len() != pdo.size {
            let node_id = j.node_id;
            self.stats.bad_frames += 1;
            self.stats.last_error.clear();
            let _ = write!(
                self.stats.last_error,
                "{} of node {node_id}: {} bytes, expected {}",
                if kind == Kind::Tpdo1 {
                    "TPDO1"
                } else {
                    "TPDO2"
                },
                data.len(),
                pdo.size
            );
            self.corrupt = true;
            return None;
        }
        if kind == Kind::Tpdo1 {
            j.tp1 = Some(pdo.unpack(data));
        } else {
            j.tp2 = Some(pdo.unpack(data));
        }
        if self
            .joints
            .iter()
            .any(|j| j.tp1.is_none() || j.tp2.is_none())
        {
            return None;
        }
        self.complete(now)
    }

    /// Each drive's RPDO1 (controlword towards the request, target position [increments])
    /// and RPDO2 (velocity offset or target velocity [increments/s]; zero with `hold`).
    /// Err for a value beyond int32 or not finite, and nothing appended; as in Python, the
    /// joints before the refused one keep the refused set's targets as the last sent.
    fn command_frames(
        &mut self,
        _counter: u32,
        q: &[f64],
        dq: &[f64],
        hold: bool,
        out: &mut Vec<Frame>,
    ) -> Result<(), FrameError> {
        let n = self.joints.len();
        if q.len() != n || dq.len() != n {
            return Err(FrameError(format!(
                "CiA 402 RPDO set needs {n} positions and velocities, got {} and {}",
                q.len(),
                dq.len()
            )));
        }
        let start = out.len();
        for k in 0..n {
            let dq_k = if hold { 0.0 } else { dq[k] };
            let j = self.joints[k];
            let pos = q[k] * j.inc_per_rad;
            let vel = dq_k * j.inc_per_rad;
            if !(pos.is_finite() && vel.is_finite()) || pos.abs().max(vel.abs()) >= 2147483648.0 {
                out.truncate(start);
                return Err(FrameError(format!(
                    "CiA 402 J{}: command {} rad, {} rad/s does not fit int32",
                    k + 1,
                    format_g(q[k]),
                    format_g(dq_k)
                )));
            }
            // Python's round(): half to even
            let target = pos.round_ties_even() as i128;
            let velocity = vel.round_ties_even() as i128;
            let cw = self.controlword(k) as i128;
            // A value that rounds to 2^31 passes the check but not the packing: Python's
            // struct.error, its text. Apart from Python in one point: a target that does not
            // pack is not remembered as the last sent (Python's next request would not pack).
            let Ok(rpdo1) = j.rpdo1.pack(&[cw, target]) else {
                out.truncate(start);
                return Err(pack_error(k, "RPDO1", j.rpdo1.field(1)));
            };
            self.joints[k].last_target_inc = Some(target);
            let Ok(rpdo2) = j.rpdo2.pack(&[velocity]) else {
                out.truncate(start);
                return Err(pack_error(k, "RPDO2", j.rpdo2.field(0)));
            };
            out.push(rpdo1);
            out.push(rpdo2);
        }
        Ok(())
    }

    /// Remember `request` (every RPDO1 carries the controlword towards it) and send each drive
    /// its controlword now, with the target it was last sent (its position, if none): a
    /// request never moves the setpoint. RESET_FAULT also clears the latched drop-out.
    fn request_frames(&mut self, request: HostRequest, out: &mut Vec<Frame>) {
        if request == HostRequest::ResetFault {
            self.dropped.clear();
        }
        if request != HostRequest::ServoOn {
            self.disabled_at_cycle = Some(self.stats.cycles);
        }
        self.request = request;
        for k in 0..self.joints.len() {
            let j = self.joints[k];
            let target = j.last_target_inc.unwrap_or(j.position_inc);
            self.joints[k].last_target_inc = Some(target);
            // from_tables checked that RPDO1 holds every controlword and position
            if let Ok(f) = j.rpdo1.pack(&[self.controlword(k) as i128, target]) {
                out.push(f);
            }
        }
    }

    /// The host's NMT heartbeat: COB 0x700 + its node id, state operational.
    fn heartbeat_frame(&mut self) -> Frame {
        Frame::classic(0x700 + self.host_node_id as u32, &[self.nmt_operational])
    }

    /// A TPDO of a drive, by id alone (as Python: whatever the frame's flags).
    fn is_cycle_frame(&self, frame: &Frame) -> bool {
        matches!(self.slot(frame.id), Some((_, Kind::Tpdo1 | Kind::Tpdo2)))
    }

    fn stats(&self) -> &AdapterStats {
        &self.stats
    }

    /// `cia402_drives`: each drive's state after the last cycle ({"J1": "operation enabled",
    /// ...}, Python's CycleFeedback.status, which [`Feedback`] has no room for);
    /// `cia402_fault`: the last cycle's full fault text ([`Cia402Adapter::fault_text`]).
    fn health(&self, _now: f64) -> Map<String, Value> {
        let mut drives = Map::new();
        for (k, j) in self.joints.iter().enumerate() {
            drives.insert(format!("J{}", k + 1), Value::from(j.state.text()));
        }
        let mut out = Map::new();
        out.insert("cia402_drives".into(), Value::Object(drives));
        out.insert("cia402_fault".into(), Value::from(self.fault_text.as_str()));
        out
    }
}
