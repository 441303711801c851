//! The enums LTC defines beside its DBC (ltc_frames.py, PROTOCOL.md §6.2, §7): the controller
//! states, fault codes, host requests and NMT states, as (wire value, name) tables, and which
//! of them a signal holds.

/// CTRL_STATUS.state's values (gateway/messages.py ControllerState).
pub const CONTROLLER_STATES: [(i64, &str); 4] =
    [(0, "BRAKED"), (1, "HOLD"), (2, "EXTERNAL"), (3, "FAULT")];
/// CTRL_STATUS.fault_code's values (ltc_frames.py FaultCode, PROTOCOL.md §6.2).
pub const FAULT_CODES: [(i64, &str); 7] = [
    (0, "NONE"),
    (1, "ESTOP"),
    (2, "CMD_TIMEOUT"),
    (3, "HOST_HEARTBEAT_LOST"),
    (4, "FOLLOWING_ERROR"),
    (5, "BAD_COMMAND"),
    (6, "JOINT_LIMIT"),
];
/// HOST_REQUEST.request's values (adapter.py HostRequest).
pub const HOST_REQUESTS: [(i64, &str); 3] = [(0, "BRAKE"), (1, "SERVO_ON"), (2, "RESET_FAULT")];
/// The heartbeats' NMT states (ltc_frames.py NmtState, CiA 301).
pub const NMT_STATES: [(i64, &str); 4] = [
    (0, "BOOT"),
    (4, "STOPPED"),
    (5, "OPERATIONAL"),
    (127, "PRE_OPERATIONAL"),
];

/// The enums LTC defines beside the DBC; the DBC's value tables must say the same
/// (ltc_protocol.py `check_enum_against_dbc`), and decoding refuses any other value.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum LtcEnum {
    ControllerState,
    FaultCode,
    HostRequest,
    NmtState,
}

impl LtcEnum {
    pub(crate) fn members(self) -> &'static [(i64, &'static str)] {
        match self {
            LtcEnum::ControllerState => &CONTROLLER_STATES,
            LtcEnum::FaultCode => &FAULT_CODES,
            LtcEnum::HostRequest => &HOST_REQUESTS,
            LtcEnum::NmtState => &NMT_STATES,
        }
    }

    pub(crate) fn type_name(self) -> &'static str {
        match self {
            LtcEnum::ControllerState => "ControllerState",
            LtcEnum::FaultCode => "FaultCode",
            LtcEnum::HostRequest => "HostRequest",
            LtcEnum::NmtState => "NmtState",
        }
    }

    /// The member's name for wire value `value`, None if it is not a member.
    pub(crate) fn name_of(self, value: i64) -> Option<&'static str> {
        self.members()
            .iter()
            .find(|(v, _)| *v == value)
            .map(|(_, n)| *n)
    }

    /// The wire value of the member called `name`.
    pub(crate) fn value_of(self, name: &str) -> Option<i64> {
        self.members()
            .iter()
            .find(|(_, n)| *n == name)
            .map(|(v, _)| *v)
    }
}
