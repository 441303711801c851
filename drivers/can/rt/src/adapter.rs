//! The vendor-agnostic port between the host core and a robot controller's CAN protocol: the
//! compiled form of drivers/can/adapter.py's contract (read its docstring for the rules).
//!
//! An adapter is built once, before the cycle, from tables the Python side derives from the
//! protocol's DBC/EDS files (cantools and canopen stay the only parsers of those files); on the
//! cycle it decodes received frames into a [`Feedback`] and encodes command sets, without
//! allocating (frames go into a caller's `Vec` whose capacity is kept).

use crate::frame::Frame;

pub use bus_rt::{ControllerState, MAX_JOINTS};

/// What the host asks of the controller's power stage (LTC-1's wire values).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[repr(u8)]
pub enum HostRequest {
    /// servo off, brakes engaged (the safe default)
    Brake = 0,
    /// servo on; the controller holds position until it gets commands
    ServoOn = 1,
    /// leave FAULT for BRAKED once the cause is gone
    ResetFault = 2,
}

impl HostRequest {
    pub fn name(self) -> &'static str {
        match self {
            HostRequest::Brake => "BRAKE",
            HostRequest::ServoOn => "SERVO_ON",
            HostRequest::ResetFault => "RESET_FAULT",
        }
    }
}

/// One complete controller cycle, assembled from its frames (adapter.py CycleFeedback).
/// Only the first `n` entries of each array are joints.
#[derive(Clone, Copy, Debug)]
pub struct Feedback {
    /// the cycle counter as on the wire (wraps at the adapter's counter modulus)
    pub counter: u32,
    pub n: usize,
    /// measured joint positions [rad]
    pub q: [f64; MAX_JOINTS],
    /// measured joint velocities [rad/s]
    pub dq: [f64; MAX_JOINTS],
    /// motor currents [A]
    pub current: [f64; MAX_JOINTS],
    pub controller_state: ControllerState,
    /// the controller sees its e-stop input open
    pub estop: bool,
    /// drives powered
    pub servo_power: bool,
    /// vendor fault name, "NONE" when there is no fault
    pub fault: &'static str,
    /// the controller's cycle period as it reports it [s]
    pub period_s: f64,
}

impl Feedback {
    pub fn new(n: usize) -> Feedback {
        Feedback {
            counter: 0,
            n,
            q: [0.0; MAX_JOINTS],
            dq: [0.0; MAX_JOINTS],
            current: [0.0; MAX_JOINTS],
            controller_state: ControllerState::Braked,
            estop: false,
            servo_power: false,
            fault: "NONE",
            period_s: 0.0,
        }
    }

    pub fn q(&self) -> &[f64] {
        &self.q[..self.n]
    }

    pub fn dq(&self) -> &[f64] {
        &self.dq[..self.n]
    }

    pub fn current(&self) -> &[f64] {
        &self.current[..self.n]
    }
}

/// Frame and cycle counters of one adapter instance (monotonic, never reset).
#[derive(Clone, Debug, Default)]
pub struct AdapterStats {
    /// frames fed
    pub frames: u64,
    /// frames of ids this protocol does not define (ignored)
    pub unknown_frames: u64,
    /// frames that failed to decode (DLC, CRC, range, RTR, error frames)
    pub bad_frames: u64,
    /// complete cycles returned
    pub cycles: u64,
    /// status frames whose cycle lacked a joint's feedback
    pub incomplete_cycles: u64,
    /// status frames whose cycle contained a bad frame
    pub corrupt_cycles: u64,
    /// the most recent reason a frame or cycle was dropped
    pub last_error: String,
}

/// A value the protocol cannot carry (the text names the signal and the value); never clamped.
#[derive(Clone, Debug, PartialEq)]
pub struct FrameError(pub String);

impl std::fmt::Display for FrameError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.0)
    }
}

/// One vendor's CAN protocol, seen from the host (adapter.py CanAdapter).
pub trait Adapter: Send {
    /// Registry name (`[can].adapter`).
    fn name(&self) -> &'static str;
    /// The cycle counter of [`Feedback`] wraps at this value.
    fn counter_modulus(&self) -> u32;
    /// The controller faults when the host heartbeat is silent this long [s].
    fn host_heartbeat_timeout_s(&self) -> f64;
    /// Host-clocked protocols: the period of [`Adapter::clock_frames`] [s]; None: the
    /// controller clocks the cycle.
    fn clock_period_s(&self) -> Option<f64> {
        None
    }
    fn n_joints(&self) -> usize;
    /// The frames that start a host-clocked cycle (CANopen: SYNC); none otherwise.
    fn clock_frames(&mut self, _out: &mut Vec<Frame>) {}
    /// Take one received frame; the cycle it completes, if it completes a valid one. Never
    /// fails for a bad frame: it is counted in the stats and its cycle dropped.
    /// `now` [s, CLOCK_MONOTONIC]: for protocols that watch their nodes (CiA 402 heartbeats).
    fn feed(&mut self, frame: &Frame, now: f64) -> Option<Feedback>;
    /// Append to `out` the frames answering the cycle whose wire counter is `counter`;
    /// `hold` asks the controller to hold `q` with zero velocity. Err if a value does not fit
    /// the protocol (then nothing is appended).
    fn command_frames(
        &mut self,
        counter: u32,
        q: &[f64],
        dq: &[f64],
        hold: bool,
        out: &mut Vec<Frame>,
    ) -> Result<(), FrameError>;
    /// Append the frames that ask the controller for `request`.
    fn request_frames(&mut self, request: HostRequest, out: &mut Vec<Frame>);
    /// The host's "I am alive and operational" frame.
    fn heartbeat_frame(&mut self) -> Frame;
    /// True if `frame` carries one of the controller's per-cycle frames (by id).
    fn is_cycle_frame(&self, _frame: &Frame) -> bool {
        false
    }
    fn stats(&self) -> &AdapterStats;
    /// Adapter-specific health entries as a JSON object's members (e.g. the drives' states);
    /// empty by default.
    fn health(&self, _now: f64) -> serde_json::Map<String, serde_json::Value> {
        serde_json::Map::new()
    }
    /// What the last cycle's fault is, in the adapter's words (which drive, its code), for
    /// the operator; None where the protocol says no more than [`Feedback::fault`].
    fn fault_detail(&self) -> Option<&str> {
        None
    }
}
