//! The fake adapter the core's tests drive (core_tests.rs): a trivial protocol of its own, so
//! the tests do not depend on a vendor's codec, and the decoding of the frames the core sends.

use crate::adapter::{
    Adapter, AdapterStats, ControllerState, Feedback, FrameError, HostRequest, MAX_JOINTS,
};
use crate::frame::Frame;
use serde_json::json;

use super::N;

pub(super) const FB_ID: u32 = 0x100; // + joint: counter u16, q f64, dq f64, current f64
pub(super) const STATUS_ID: u32 = 0x180; // counter u16, state u8, servo u8, estop u8, period_us u32
pub(super) const CMD_ID: u32 = 0x200; // + joint: counter u16, hold u8, q f64, dq f64
pub(super) const REQUEST_ID: u32 = 0x020; // request u8
pub(super) const HEARTBEAT_ID: u32 = 0x700; // 5
pub(super) const SYNC_ID: u32 = 0x080;
/// The fake protocol carries |q| up to this [rad].
pub(super) const Q_RANGE: f64 = 100.0;

pub(super) fn f64_at(data: &[u8], at: usize) -> f64 {
    f64::from_le_bytes(data[at..at + 8].try_into().unwrap())
}

/// A trivial controller protocol: one feedback frame per joint, then a status frame that
/// closes the cycle; one command frame per joint; 16-bit counters.
pub(super) struct FakeAdapter {
    n: usize,
    clock_period_s: Option<f64>,
    stats: AdapterStats,
    got: [Option<(u32, f64, f64, f64)>; MAX_JOINTS],
    corrupt: bool,
}

impl FakeAdapter {
    pub(super) fn new(n: usize, clock_period_s: Option<f64>) -> FakeAdapter {
        FakeAdapter {
            n,
            clock_period_s,
            stats: AdapterStats::default(),
            got: [None; MAX_JOINTS],
            corrupt: false,
        }
    }

    fn drop_cycle(&mut self, why: &str, corrupt: bool) {
        if corrupt {
            self.stats.corrupt_cycles += 1;
        } else {
            self.stats.incomplete_cycles += 1;
        }
        self.stats.last_error = why.to_string();
        self.got = [None; MAX_JOINTS];
        self.corrupt = false;
    }
}

impl Adapter for FakeAdapter {
    fn name(&self) -> &'static str {
        "fake"
    }

    fn counter_modulus(&self) -> u32 {
        65536
    }

    fn host_heartbeat_timeout_s(&self) -> f64 {
        0.5
    }

    fn clock_period_s(&self) -> Option<f64> {
        self.clock_period_s
    }

    fn n_joints(&self) -> usize {
        self.n
    }

    fn clock_frames(&mut self, out: &mut Vec<Frame>) {
        out.push(Frame::empty(SYNC_ID));
    }

    fn feed(&mut self, frame: &Frame, _now: f64) -> Option<Feedback> {
        self.stats.frames += 1;
        if frame.error {
            self.stats.bad_frames += 1;
            self.stats.last_error = "error frame".into();
            self.corrupt = true;
            return None;
        }
        let data = frame.payload();
        if (FB_ID..FB_ID + self.n as u32).contains(&frame.id) {
            if data.len() < 26 {
                self.stats.bad_frames += 1;
                self.stats.last_error = format!("feedback of {} bytes", data.len());
                self.corrupt = true;
                return None;
            }
            let counter = u16::from_le_bytes([data[0], data[1]]) as u32;
            self.got[(frame.id - FB_ID) as usize] =
                Some((counter, f64_at(data, 2), f64_at(data, 10), f64_at(data, 18)));
            return None;
        }
        if frame.id != STATUS_ID {
            self.stats.unknown_frames += 1;
            return None;
        }
        if data.len() < 9 {
            self.stats.bad_frames += 1;
            self.stats.last_error = "short status".into();
            self.drop_cycle("short status", true);
            return None;
        }
        let counter = u16::from_le_bytes([data[0], data[1]]) as u32;
        if self.corrupt {
            self.drop_cycle("a bad frame in the cycle", true);
            return None;
        }
        let Some(state) = ControllerState::from_u8(data[2]) else {
            self.drop_cycle("bad controller state", true);
            return None;
        };
        let mut fb = Feedback::new(self.n);
        for k in 0..self.n {
            match self.got[k] {
                Some((c, q, dq, i)) if c == counter => {
                    fb.q[k] = q;
                    fb.dq[k] = dq;
                    fb.current[k] = i;
                }
                _ => {
                    self.drop_cycle("a joint's feedback is missing", false);
                    return None;
                }
            }
        }
        self.got = [None; MAX_JOINTS];
        fb.counter = counter;
        fb.controller_state = state;
        fb.servo_power = data[3] != 0;
        fb.estop = data[4] != 0;
        fb.period_s = u32::from_le_bytes([data[5], data[6], data[7], data[8]]) as f64 * 1e-6;
        fb.fault = if state == ControllerState::Fault {
            "FOLLOWING_ERROR"
        } else {
            "NONE"
        };
        self.stats.cycles += 1;
        Some(fb)
    }

    fn command_frames(
        &mut self,
        counter: u32,
        q: &[f64],
        dq: &[f64],
        hold: bool,
        out: &mut Vec<Frame>,
    ) -> Result<(), FrameError> {
        if let Some(k) = (0..self.n).find(|&k| !(q[k].abs() <= Q_RANGE && dq[k].is_finite())) {
            return Err(FrameError(format!(
                "J{}: command {} rad outside ±{Q_RANGE}",
                k + 1,
                q[k]
            )));
        }
        for k in 0..self.n {
            let mut data = [0u8; 19];
            data[..2].copy_from_slice(&(counter as u16).to_le_bytes());
            data[2] = hold as u8;
            data[3..11].copy_from_slice(&q[k].to_le_bytes());
            data[11..19].copy_from_slice(&dq[k].to_le_bytes());
            out.push(Frame::fd(CMD_ID + k as u32, &data, false));
        }
        Ok(())
    }

    fn request_frames(&mut self, request: HostRequest, out: &mut Vec<Frame>) {
        out.push(Frame::classic(REQUEST_ID, &[request as u8]));
    }

    fn heartbeat_frame(&mut self) -> Frame {
        Frame::classic(HEARTBEAT_ID, &[5])
    }

    fn stats(&self) -> &AdapterStats {
        &self.stats
    }

    fn health(&self, _now: f64) -> serde_json::Map<String, serde_json::Value> {
        let mut h = serde_json::Map::new();
        h.insert("fake_frames".into(), json!(self.stats.frames));
        h.insert("cycles".into(), json!("the adapter's, never the core's"));
        h
    }
}

/// A frame the core sent, decoded.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(super) enum Sent {
    Cmd {
        joint: usize,
        counter: u32,
        hold: bool,
        q: f64,
        dq: f64,
    },
    Request(u8),
    Heartbeat,
    Sync,
}

pub(super) fn decode(frame: &Frame) -> Sent {
    let d = frame.payload();
    match frame.id {
        REQUEST_ID => Sent::Request(d[0]),
        HEARTBEAT_ID => Sent::Heartbeat,
        SYNC_ID => Sent::Sync,
        id if (CMD_ID..CMD_ID + MAX_JOINTS as u32).contains(&id) => Sent::Cmd {
            joint: (id - CMD_ID) as usize,
            counter: u16::from_le_bytes([d[0], d[1]]) as u32,
            hold: d[2] != 0,
            q: f64_at(d, 3),
            dq: f64_at(d, 11),
        },
        id => panic!("the core sent an unknown frame 0x{id:X}"),
    }
}

/// One command set: (counter, hold, q, dq) per joint.
#[derive(Clone, Debug, PartialEq)]
pub(super) struct Set {
    pub(super) counters: Vec<u32>,
    pub(super) hold: Vec<bool>,
    pub(super) q: Vec<f64>,
    pub(super) dq: Vec<f64>,
}

impl Set {
    pub(super) fn all_hold(&self) -> bool {
        self.hold.iter().all(|&h| h)
    }

    pub(super) fn none_hold(&self) -> bool {
        self.hold.iter().all(|&h| !h)
    }
}

/// The command frames among `sent`, as sets of N.
pub(super) fn commands(sent: &[Sent]) -> Vec<Set> {
    let cmds: Vec<_> = sent
        .iter()
        .filter_map(|s| match *s {
            Sent::Cmd {
                joint,
                counter,
                hold,
                q,
                dq,
            } => Some((joint, counter, hold, q, dq)),
            _ => None,
        })
        .collect();
    assert_eq!(cmds.len() % N, 0, "whole command sets");
    cmds.chunks(N)
        .map(|c| {
            assert!(
                c.iter().enumerate().all(|(k, f)| f.0 == k),
                "joints in order"
            );
            Set {
                counters: c.iter().map(|f| f.1).collect(),
                hold: c.iter().map(|f| f.2).collect(),
                q: c.iter().map(|f| f.3).collect(),
                dq: c.iter().map(|f| f.4).collect(),
            }
        })
        .collect()
}

pub(super) fn requests(sent: &[Sent]) -> Vec<HostRequest> {
    sent.iter()
        .filter_map(|s| match *s {
            Sent::Request(0) => Some(HostRequest::Brake),
            Sent::Request(1) => Some(HostRequest::ServoOn),
            Sent::Request(2) => Some(HostRequest::ResetFault),
            _ => None,
        })
        .collect()
}
