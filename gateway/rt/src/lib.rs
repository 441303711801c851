//! The bus contract, compiled (gateway/messages.py's twin in Rust, bit-exact with it): the
//! binary zenoh messages the compiled cycles read and write (the CAN driver's, the control
//! law's), the controller's state and the joint count they are sized for. Pure Rust, tested
//! with `cargo test`; every compiled piece of the product links it.

pub mod messages;

/// Most joints any message or adapter carries (CiA 402: 16 drives).
pub const MAX_JOINTS: usize = 16;

/// State of the closed robot controller (gateway/messages.py ControllerState).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[repr(u8)]
pub enum ControllerState {
    /// brakes engaged, servo off (power-on default)
    Braked = 0,
    /// servo on, holding the last valid position command
    Hold = 1,
    /// servo on, tracking external position/velocity commands
    External = 2,
    /// brakes engaged after a fault; needs a reset request
    Fault = 3,
}

impl ControllerState {
    pub fn name(self) -> &'static str {
        match self {
            ControllerState::Braked => "BRAKED",
            ControllerState::Hold => "HOLD",
            ControllerState::External => "EXTERNAL",
            ControllerState::Fault => "FAULT",
        }
    }

    pub fn from_u8(v: u8) -> Option<ControllerState> {
        match v {
            0 => Some(ControllerState::Braked),
            1 => Some(ControllerState::Hold),
            2 => Some(ControllerState::External),
            3 => Some(ControllerState::Fault),
            _ => None,
        }
    }

    /// HOLD or EXTERNAL: the drives are powered and follow the host.
    pub fn servoing(self) -> bool {
        matches!(self, ControllerState::Hold | ControllerState::External)
    }
}
