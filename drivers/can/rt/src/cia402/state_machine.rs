//! The CiA 402 power drive system's state machine as data (cia402.rs): the states, the
//! statusword's coding of them, the transitions the host drives with their controlwords (the
//! standard's numbers), and the controlword that moves a drive one step towards a request.

use crate::adapter::HostRequest;

/// The standard's device control commands (controlword bits 0-3 and 7).
pub const CW_DISABLE_VOLTAGE: u16 = 0x0000;
pub const CW_QUICK_STOP: u16 = 0x0002;
pub const CW_SHUTDOWN: u16 = 0x0006;
/// Also "disable operation" (transition 5).
pub const CW_SWITCH_ON: u16 = 0x0007;
pub const CW_ENABLE_OPERATION: u16 = 0x000F;
/// Fault reset: the drive acts on its rising edge.
pub const CW_FAULT_RESET: u16 = 0x0080;

/// The CiA 402 power drive system's states (cia402.py DriveState).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum DriveState {
    NotReadyToSwitchOn,
    SwitchOnDisabled,
    ReadyToSwitchOn,
    SwitchedOn,
    OperationEnabled,
    QuickStopActive,
    FaultReactionActive,
    Fault,
}

impl DriveState {
    /// Every state, in the standard's order.
    pub const ALL: [DriveState; 8] = [
        DriveState::NotReadyToSwitchOn,
        DriveState::SwitchOnDisabled,
        DriveState::ReadyToSwitchOn,
        DriveState::SwitchedOn,
        DriveState::OperationEnabled,
        DriveState::QuickStopActive,
        DriveState::FaultReactionActive,
        DriveState::Fault,
    ];

    /// The state's text as Python's DriveState value (fault texts, health, the tables).
    pub fn text(self) -> &'static str {
        match self {
            DriveState::NotReadyToSwitchOn => "not ready to switch on",
            DriveState::SwitchOnDisabled => "switch on disabled",
            DriveState::ReadyToSwitchOn => "ready to switch on",
            DriveState::SwitchedOn => "switched on",
            DriveState::OperationEnabled => "operation enabled",
            DriveState::QuickStopActive => "quick stop active",
            DriveState::FaultReactionActive => "fault reaction active",
            DriveState::Fault => "fault",
        }
    }

    /// The state whose [`DriveState::text`] is `text`.
    pub fn from_text(text: &str) -> Option<DriveState> {
        DriveState::ALL.iter().copied().find(|s| s.text() == text)
    }

    /// A fault or its reaction: the drive stopped on its own and needs a fault reset.
    pub(super) fn faulted(self) -> bool {
        matches!(self, DriveState::Fault | DriveState::FaultReactionActive)
    }
}

/// The standard's state coding of the statusword: (mask, value, state), first match wins.
pub const STATUSWORD_STATES: [(u16, u16, DriveState); 8] = [
    (0x4F, 0x00, DriveState::NotReadyToSwitchOn),
    (0x4F, 0x40, DriveState::SwitchOnDisabled),
    (0x6F, 0x21, DriveState::ReadyToSwitchOn),
    (0x6F, 0x23, DriveState::SwitchedOn),
    (0x6F, 0x27, DriveState::OperationEnabled),
    (0x6F, 0x07, DriveState::QuickStopActive),
    (0x4F, 0x0F, DriveState::FaultReactionActive),
    (0x4F, 0x08, DriveState::Fault),
];

/// The drive state a statusword codes (the standard's table; every value codes one: the
/// unusual combinations of bits 5 and 6 count as not ready to switch on).
pub fn decode_state(statusword: u16) -> DriveState {
    STATUSWORD_STATES
        .iter()
        .find(|&&(mask, value, _)| statusword & mask == value)
        .map_or(DriveState::NotReadyToSwitchOn, |&(_, _, state)| state)
}

/// The transitions the host drives: (number, from, to, controlword). The others are the
/// drive's own (0, 1: power-up; 12 after a quick stop; 13, 14: fault reaction).
pub const TRANSITIONS: [(u8, DriveState, DriveState, u16); 12] = {
    use DriveState as S;
    [
        (2, S::SwitchOnDisabled, S::ReadyToSwitchOn, CW_SHUTDOWN),
        (3, S::ReadyToSwitchOn, S::SwitchedOn, CW_SWITCH_ON),
        (4, S::SwitchedOn, S::OperationEnabled, CW_ENABLE_OPERATION),
        (5, S::OperationEnabled, S::SwitchedOn, CW_SWITCH_ON),
        (6, S::SwitchedOn, S::ReadyToSwitchOn, CW_SHUTDOWN),
        (
            7,
            S::ReadyToSwitchOn,
            S::SwitchOnDisabled,
            CW_DISABLE_VOLTAGE,
        ),
        (8, S::OperationEnabled, S::ReadyToSwitchOn, CW_SHUTDOWN),
        (
            9,
            S::OperationEnabled,
            S::SwitchOnDisabled,
            CW_DISABLE_VOLTAGE,
        ),
        (10, S::SwitchedOn, S::SwitchOnDisabled, CW_DISABLE_VOLTAGE),
        (11, S::OperationEnabled, S::QuickStopActive, CW_QUICK_STOP),
        (15, S::Fault, S::SwitchOnDisabled, CW_FAULT_RESET),
        (
            16,
            S::QuickStopActive,
            S::OperationEnabled,
            CW_ENABLE_OPERATION,
        ),
    ]
};

/// The controlword that moves a drive in `state` one step towards what `request` asks, and
/// that step's transition number (None: none, the controlword keeps the state).
///
/// SERVO_ON walks 2 → 3 → 4 to *operation enabled* (3 and 4 by one controlword, *switch on +
/// enable operation*). BRAKE leaves it by *disable operation* (5: the drive holds while its
/// brake engages) and rests in *ready to switch on* (6, 2: power stage off). RESET_FAULT is fault reset (15). A quick stop is never undone here (no
/// 16): it runs to its end and the drive must be switched on again from the start.
pub fn controlword_for(state: DriveState, request: HostRequest) -> (u16, Option<u8>) {
    use DriveState as S;
    if state.faulted() {
        if request == HostRequest::ResetFault && state == S::Fault {
            return (CW_FAULT_RESET, Some(15));
        }
        return (CW_SHUTDOWN, None);
    }
    if state == S::QuickStopActive {
        return (CW_QUICK_STOP, None);
    }
    let step = if request == HostRequest::ServoOn {
        match state {
            S::SwitchOnDisabled => 2,
            // "switch on + enable operation": the drive makes 3, then 4 at its next tick. Not
            // "switch on": the host reads the state one SYNC late, and "switch on" is disable
            // operation (5) to a drive that has already reached operation enabled.
            S::ReadyToSwitchOn => return (CW_ENABLE_OPERATION, Some(3)),
            S::SwitchedOn => 4,
            S::OperationEnabled => return (CW_ENABLE_OPERATION, None),
            _ => return (CW_SHUTDOWN, None),
        }
    } else {
        // BRAKE (and RESET_FAULT of a drive that is not in fault)
        match state {
            S::OperationEnabled => 5,
            S::SwitchedOn => 6,
            S::SwitchOnDisabled => 2,
            _ => return (CW_SHUTDOWN, None),
        }
    };
    let cw = TRANSITIONS
        .iter()
        .find(|t| t.0 == step)
        .map_or(CW_SHUTDOWN, |t| t.3);
    (cw, Some(step))
}
