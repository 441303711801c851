//! LTC-1F, the CAN FD profile of LTC-1 (PROTOCOL.md §10), seen from the host:
//! drivers/can/ltc_fd.py's `LtcFdAdapter` compiled, bit for bit and text for text.
//!
//! One frame each way per cycle: the controller's CYCLE_FB (CAN FD, 64 bytes: the CTRL_STATUS
//! signals and every joint's position, velocity and current) is the whole cycle, and the host
//! answers with one CYCLE_CMD (CAN FD with bit rate switch, 48 bytes, CRC-16/CCITT-FALSE of
//! §10.3). There is nothing to assemble: a valid CYCLE_FB is a complete cycle, a bad one is a
//! lost cycle and cannot spoil a neighbour. HOST_REQUEST, the heartbeats and the receiver's
//! checks are LTC-1's ([`crate::ltc_base::LtcBase`]).
//!
//! Built by [`LtcFdAdapter::from_tables`] from drivers/can/rt_tables.py's
//! `ltc_tables("ltc_fd", n)`; the cycle allocates nothing.

use serde_json::Value;

use crate::adapter::{Adapter, AdapterStats, Feedback, FrameError, HostRequest, MAX_JOINTS};
use crate::frame::Frame;
use crate::ltc_base::LtcBase;
use crate::ltc_status::{StatusSignals, STATUS_SIGNALS};

/// The LTC-1F host adapter (registry name `ltc_fd`): ltc_fd.py `LtcFdAdapter`.
pub struct LtcFdAdapter {
    base: LtcBase,
    stats: AdapterStats,
    /// CYCLE_FB's message index and id
    cycle: usize,
    cycle_id: u32,
    status_signals: StatusSignals,
    /// position_jk, velocity_jk, current_jk of CYCLE_FB, for every joint the DBC carries
    joint_signals: [[usize; 3]; MAX_JOINTS],
    /// CYCLE_CMD's message index
    command: usize,
    /// counter, hold, crc of CYCLE_CMD
    command_signals: [usize; 3],
    /// position_cmd_jk, velocity_cmd_jk of CYCLE_CMD, for every joint the DBC carries
    command_joint_signals: [[usize; 2]; MAX_JOINTS],
}

impl LtcFdAdapter {
    /// Build from rt_tables.py's `ltc_tables("ltc_fd", n_joints)`; Err names the missing or
    /// wrong entry.
    pub fn from_tables(tables: &Value) -> Result<LtcFdAdapter, String> {
        let mut base = LtcBase::from_tables(tables, "ltc_fd", "LTC-1F", "fd")?;
        let m = base.max_joints;
        let cycle = base.spec("CYCLE_FB")?;
        let command = base.spec("CYCLE_CMD")?;
        for spec in [cycle, command] {
            if !base.specs[spec].codec.fd {
                let name = &base.specs[spec].codec.name;
                return Err(format!(
                    "tables.messages[{name}].fd: {name} must be a CAN FD frame"
                ));
            }
        }
        let joint_names = |prefixes: &[&str]| -> Vec<String> {
            (1..=m)
                .flat_map(|k| prefixes.iter().map(move |p| format!("{p}_j{k}")))
                .collect()
        };

        let fb_joints = joint_names(&["position", "velocity", "current"]);
        let mut known: Vec<&str> = STATUS_SIGNALS.to_vec();
        known.extend(fb_joints.iter().map(String::as_str));
        base.require_only(cycle, &known)?;
        let status_signals = StatusSignals::bind(&mut base, cycle)?;
        let mut joint_signals = [[0; 3]; MAX_JOINTS];
        for (k, names) in fb_joints.chunks(3).enumerate() {
            joint_signals[k] =
                base.signals(cycle, [&names[0], &names[1], &names[2]].map(|s| s.as_str()))?;
        }

        let cmd_joints = joint_names(&["position_cmd", "velocity_cmd"]);
        let mut known = vec!["counter", "hold", "crc"];
        known.extend(cmd_joints.iter().map(String::as_str));
        base.require_only(command, &known)?;
        base.require_integer(command, &["counter", "hold", "crc"])?;
        let command_signals = base.signals(command, ["counter", "hold", "crc"])?;
        let mut command_joint_signals = [[0; 2]; MAX_JOINTS];
        for (k, names) in cmd_joints.chunks(2).enumerate() {
            command_joint_signals[k] =
                base.signals(command, [names[0].as_str(), names[1].as_str()])?;
        }
        Ok(LtcFdAdapter {
            cycle_id: base.specs[cycle].codec.id,
            base,
            stats: AdapterStats {
                last_error: String::with_capacity(256),
                ..Default::default()
            },
            cycle,
            status_signals,
            joint_signals,
            command,
            command_signals,
            command_joint_signals,
        })
    }
}

impl Adapter for LtcFdAdapter {
    fn name(&self) -> &'static str {
        "ltc_fd"
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
        match self.base.decode(frame) {
            Ok(Some(spec)) if spec == self.cycle => {
                self.stats.cycles += 1;
                let n = self.base.n_joints;
                let codec = &self.base.specs[self.cycle].codec;
                let raw = &self.base.raw;
                let mut fb = Feedback::new(n);
                for (k, &[p, v, c]) in self.joint_signals[..n].iter().enumerate() {
                    fb.q[k] = codec.physical(p, raw[p]);
                    fb.dq[k] = codec.physical(v, raw[v]);
                    fb.current[k] = codec.physical(c, raw[c]);
                }
                self.status_signals.fill(codec, raw, &mut fb);
                Some(fb)
            }
            Ok(Some(_)) => None, // heartbeats; another host's commands and requests
            Ok(None) => {
                self.stats.unknown_frames += 1;
                None
            }
            Err(e) => {
                self.base.count_bad(&e, &mut self.stats);
                if frame.id == self.cycle_id && !frame.error {
                    self.stats.corrupt_cycles += 1;
                }
                None
            }
        }
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
                "CYCLE_CMD needs {n} positions and velocities, got {} and {}",
                q.len(),
                dq.len()
            )));
        }
        let [c, h, crc] = self.command_signals;
        let values = &mut self.base.values;
        values[c] = (counter % self.base.command_counter_modulus) as f64;
        values[h] = if hold { 1.0 } else { 0.0 };
        values[crc] = 0.0;
        for (k, &[p, v]) in self.command_joint_signals[..self.base.max_joints]
            .iter()
            .enumerate()
        {
            // joints the arm does not have are sent as 0 (§10.2.2)
            (values[p], values[v]) = if k < n { (q[k], dq[k]) } else { (0.0, 0.0) };
        }
        out.push(self.base.encode(self.command)?);
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
mod tests {
    use super::*;
    use crate::adapter::ControllerState;
    use crate::ltc_adapter::golden;

    fn adapter(n: usize) -> LtcFdAdapter {
        let mut t = golden::cases("ltc_fd")[0]["tables"].clone();
        t["n_joints"] = n.into();
        LtcFdAdapter::from_tables(&t).unwrap()
    }

    /// The controller's CYCLE_FB, encoded with the same codec: status, then joints k at
    /// q = 0.1·k, dq = −0.01·k, current 1.5 (all six, whatever the host's joint count).
    fn cycle(a: &mut LtcFdAdapter, counter: u32) -> Frame {
        let spec = a.cycle;
        let status = a.base.signals(spec, STATUS_SIGNALS).unwrap();
        let values = [counter as f64, 2.0, 1.0, 0.0, 1.0, 0.0, 2000.0];
        for (i, v) in status.into_iter().zip(values) {
            a.base.values[i] = v;
        }
        for k in 0..a.base.max_joints {
            let [p, v, c] = a.joint_signals[k];
            let j = (k + 1) as f64;
            (a.base.values[p], a.base.values[v], a.base.values[c]) = (0.1 * j, -0.01 * j, 1.5);
        }
        a.base.encode(spec).unwrap()
    }

    #[test]
    fn crc16_check_value_and_manual_example() {
        assert_eq!(crate::frame_crc::crc16_ccitt_false(b"123456789"), 0x29B1);
        // PROTOCOL.md §10.3: CYCLE_CMD answering 0x1234, joint 1 at 0.1 rad and −0.25 rad/s,
        // joint 2 at −0.2 rad and +0.5 rad/s, the others 0: CRC 0x04CD
        let mut a = adapter(2);
        let mut out = Vec::new();
        a.command_frames(0x1234, &[0.1, -0.2], &[-0.25, 0.5], false, &mut out)
            .unwrap();
        let f = out[0];
        assert_eq!((f.id, f.fd, f.brs, f.len), (0x200, true, true, 48));
        assert_eq!(
            &f.data[..16],
            &[0x34, 0x12, 0, 0, 0xa0, 0x86, 0x01, 0x3c, 0xf6, 0xc0, 0xf2, 0xfc, 0x88, 0x13, 0, 0]
        );
        assert_eq!((f.data[46], f.data[47]), (0xcd, 0x04));
        assert_eq!(crate::frame_crc::frame_crc16(0x200, &f.data[..46]), 0x04CD);
        out.clear();
        a.command_frames(0x1234, &[0.1, -0.2], &[-0.25, 0.5], true, &mut out)
            .unwrap();
        assert_eq!(
            (out[0].data[2], out[0].data[46], out[0].data[47]),
            (1, 0x21, 0x43)
        );
    }

    #[test]
    fn one_cycle_feedback_frame_is_one_cycle() {
        let mut a = adapter(2);
        let f = cycle(&mut a, 0xBEEF);
        let fb = a.feed(&f, 0.0).expect("a cycle");
        assert_eq!(
            (fb.counter, fb.n, fb.controller_state),
            (0xBEEF, 2, ControllerState::External)
        );
        assert_eq!(
            (fb.fault, fb.estop, fb.servo_power, fb.period_s),
            ("ESTOP", true, false, 2000.0 * 1e-6)
        );
        assert_eq!(fb.q(), &[100000.0 * 1e-6, 200000.0 * 1e-6]);
        assert_eq!(fb.dq(), &[-100.0 * 0.0001, -200.0 * 0.0001]);
        assert_eq!(a.stats().cycles, 1);
        assert!(a.is_cycle_frame(&f));
    }

    #[test]
    fn a_bad_cycle_feedback_frame_is_a_lost_cycle() {
        let mut a = adapter(6);
        let good = cycle(&mut a, 1);
        let mut classic = Frame::classic(good.id, &good.data[..8]);
        classic.brs = false;
        assert!(a.feed(&classic, 0.0).is_none());
        assert_eq!(
            a.stats().last_error,
            "CYCLE_FB (0x180): classic CAN frame; LTC-1F sends it as CAN FD"
        );
        let mut fault = good;
        fault.data[3] = 7;
        assert!(a.feed(&fault, 0.0).is_none());
        assert_eq!(
            a.stats().last_error,
            "CYCLE_FB (0x180): fault_code = 7 outside its range [0, 6]"
        );
        let mut short = good;
        short.len = 48;
        assert!(a.feed(&short, 0.0).is_none());
        assert_eq!(
            a.stats().last_error,
            "CYCLE_FB (0x180): DLC 48 with 48 data bytes, expected 64"
        );
        let mut err = Frame::empty(0x180);
        err.error = true;
        assert!(a.feed(&err, 0.0).is_none());
        let s = a.stats();
        assert_eq!(
            (s.bad_frames, s.corrupt_cycles),
            (4, 3),
            "an error frame is no lost CYCLE_FB"
        );
        assert!(a.feed(&good, 0.0).is_some(), "the next one is fine");
        let mut request = Vec::new();
        a.request_frames(HostRequest::Brake, &mut request);
        let fd_request = Frame::fd(request[0].id, request[0].payload(), true);
        a.feed(&fd_request, 0.0);
        assert_eq!(
            a.stats().last_error,
            "HOST_REQUEST (0x020): CAN FD frame; LTC-1F sends it as classic CAN"
        );
        a.feed(&Frame::classic(0x181, &[0; 8]), 0.0); // an LTC-1 id means nothing here
        assert_eq!(a.stats().unknown_frames, 1);
    }

    #[test]
    fn command_sets_pad_and_refuse() {
        let mut a = adapter(1);
        let mut out = vec![Frame::empty(1)];
        a.command_frames(0x1_0005, &[0.5], &[0.0], false, &mut out)
            .unwrap();
        assert_eq!(&out[1].data[..2], &[5, 0], "all 16 bits of the counter");
        assert!(
            out[1].data[9..46].iter().all(|&b| b == 0),
            "joints 2..6 sent as 0"
        );
        let e = a
            .command_frames(0, &[0.0], &[f64::INFINITY], false, &mut out)
            .unwrap_err();
        assert_eq!(
            e.0,
            "CYCLE_CMD (0x200): velocity_cmd_j1 = inf rad/s is not finite"
        );
        let e = a.command_frames(0, &[], &[], false, &mut out).unwrap_err();
        assert_eq!(
            e.0,
            "CYCLE_CMD needs 1 positions and velocities, got 0 and 0"
        );
        assert_eq!(out.len(), 2);
    }

    #[test]
    fn tables_for_the_other_profile_are_refused() {
        let t = golden::cases("ltc_dbc")[0]["tables"].clone();
        let e = LtcFdAdapter::from_tables(&t).err().expect("refused");
        assert_eq!(e, "tables.adapter: \"ltc_dbc\", expected \"ltc_fd\"");
        let mut t = golden::cases("ltc_fd")[0]["tables"].clone();
        let cmd = t["messages"]
            .as_array_mut()
            .unwrap()
            .iter_mut()
            .find(|m| m["name"] == "CYCLE_CMD");
        cmd.unwrap()["signals"]
            .as_array_mut()
            .unwrap()
            .retain(|s| s["name"] != "velocity_cmd_j6");
        let e = LtcFdAdapter::from_tables(&t).err().expect("refused");
        assert_eq!(
            e,
            "tables.messages[CYCLE_CMD].signals: no signal velocity_cmd_j6"
        );
    }

    #[test]
    fn golden_vectors_from_python() {
        let mut totals = (0, 0, 0);
        for case in golden::cases("ltc_fd") {
            let (f, c, r) = golden::replay(&case, LtcFdAdapter::from_tables);
            totals = (totals.0 + f, totals.1 + c, totals.2 + r);
        }
        assert!(
            totals.0 > 300 && totals.1 > 100 && totals.2 > 500,
            "{totals:?}"
        );
    }
}
