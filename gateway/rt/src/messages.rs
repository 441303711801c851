//! The zenoh messages the compiled cycles read and write, bit-exact with
//! gateway/messages.py: the fixed little-endian binary layouts (a 4-byte magic naming the type,
//! a 1-byte layout version, then fields) of [`JointState`], [`JointCommand`], [`IoState`] and
//! [`StateWindow`], the `JointState.flags` bits and the gateway's [`Lifecycle`].
//!
//! Decoding checks what Python's `from_bytes` checks (magic, version, length, joint count,
//! every float finite) and names what was wrong in a [`MessageError`] worded like Python's.
//! Encoding and the per-cycle decoding ([`JointCommand`], [`IoState`]) never allocate: an
//! encoder writes into a caller's `Vec<u8>` whose capacity it keeps, a decoded command holds
//! fixed arrays. Stamps are CLOCK_MONOTONIC seconds, as in Python.
//!
//! The helpers of messages/python_text.rs format numbers as Python's `repr` and
//! `format(v, "g")` do, so the messages of every ported module read as the Python driver's did.

mod io_state;
mod joint_command;
mod joint_state;
mod python_text;
mod state_window;
mod wire;

pub use self::io_state::IoState;
pub use self::joint_command::JointCommand;
pub use self::joint_state::JointState;
pub use self::python_text::{fmt_g, py_bytes_repr, py_repr};
pub use self::state_window::StateWindow;
pub use self::wire::{MessageError, LAYOUT_VERSION};
pub use crate::ControllerState;

/// `JointState.flags`: the controller sees its e-stop input open.
pub const FLAG_ESTOP: u8 = 1;
/// `JointState.flags`: the drives are powered.
pub const FLAG_SERVO_POWER: u8 = 2;
/// `JointState.flags`: the previous cycle was answered with a hold (or not at all, which
/// freezes the controller's reference).
pub const FLAG_PREV_HOLD: u8 = 4;
/// `JointState.flags`: the previous cycle was answered by coasting on the last command.
pub const FLAG_PREV_COAST: u8 = 8;

/// The gateway's lifecycle (gateway/messages.py Lifecycle). STOPPED is the default and the
/// state every error path leads back to.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[repr(u8)]
pub enum Lifecycle {
    /// brakes on; nothing moves
    Stopped = 0,
    /// servo on, holding position; waiting for the enabling device
    Ready = 1,
    /// enabling device held; the control process's commands reach the robot
    Teaching = 2,
    /// an error stopped the robot; `reset` once the cause is gone
    Fault = 3,
    /// enabling device held; the control process plays an excitation plan
    Identifying = 4,
    /// enabling device held; the control process plays a taught program back
    Replaying = 5,
}

/// Every lifecycle state, in value order (Python's `tuple(Lifecycle)`).
pub const LIFECYCLE_STATES: [Lifecycle; 6] = [
    Lifecycle::Stopped,
    Lifecycle::Ready,
    Lifecycle::Teaching,
    Lifecycle::Fault,
    Lifecycle::Identifying,
    Lifecycle::Replaying,
];

/// Lifecycle states in which the control process's commands may reach the robot.
pub const COMMANDING: [Lifecycle; 3] = [
    Lifecycle::Teaching,
    Lifecycle::Identifying,
    Lifecycle::Replaying,
];

/// Lifecycle states in which the control process plays a plan.
pub const PLAYING: [Lifecycle; 2] = [Lifecycle::Identifying, Lifecycle::Replaying];

impl Lifecycle {
    /// The Python member name ("STOPPED" ...).
    pub fn name(self) -> &'static str {
        match self {
            Lifecycle::Stopped => "STOPPED",
            Lifecycle::Ready => "READY",
            Lifecycle::Teaching => "TEACHING",
            Lifecycle::Fault => "FAULT",
            Lifecycle::Identifying => "IDENTIFYING",
            Lifecycle::Replaying => "REPLAYING",
        }
    }

    /// The name on the wire of a lifecycle message ("stopped" ...).
    pub fn wire_name(self) -> &'static str {
        match self {
            Lifecycle::Stopped => "stopped",
            Lifecycle::Ready => "ready",
            Lifecycle::Teaching => "teaching",
            Lifecycle::Fault => "fault",
            Lifecycle::Identifying => "identifying",
            Lifecycle::Replaying => "replaying",
        }
    }

    /// The state of a member name ("TEACHING"), as Python's `Lifecycle[name]`.
    pub fn from_name(name: &str) -> Option<Lifecycle> {
        LIFECYCLE_STATES.iter().copied().find(|s| s.name() == name)
    }

    pub fn from_u8(v: u8) -> Option<Lifecycle> {
        LIFECYCLE_STATES.get(v as usize).copied()
    }

    /// One of [`COMMANDING`]: the control process's commands may reach the robot.
    pub fn commanding(self) -> bool {
        COMMANDING.contains(&self)
    }

    /// One of [`PLAYING`].
    pub fn playing(self) -> bool {
        PLAYING.contains(&self)
    }
}

#[cfg(test)]
#[path = "messages_tests.rs"]
mod tests;
