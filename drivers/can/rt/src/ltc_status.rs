//! CTRL_STATUS's signals in both LTC profiles (CTRL_STATUS of LTC-1, the head of LTC-1F's
//! CYCLE_FB): where they are in a message, and how they fill a cycle's [`Feedback`].

use crate::adapter::{ControllerState, Feedback};
use crate::codec::MessageCodec;
use crate::ltc_base::LtcBase;
use crate::ltc_enums::LtcEnum;

/// Indices of the CTRL_STATUS signals in a message (CTRL_STATUS, or the head of LTC-1F's
/// CYCLE_FB), and how they fill a [`Feedback`] (ltc.py `cycle_feedback`).
pub(crate) struct StatusSignals {
    counter: usize,
    state: usize,
    fault: usize,
    estop: usize,
    servo: usize,
    period: usize,
}

/// CTRL_STATUS's signals (ltc_protocol.py STATUS_SIGNALS).
pub(crate) const STATUS_SIGNALS: [&str; 7] = [
    "cycle_counter",
    "state",
    "fault_code",
    "missed_cycles",
    "estop_active",
    "servo_power",
    "cycle_period_us",
];

impl StatusSignals {
    /// Bind the status signals of `spec`, and its enums (state, then fault_code:
    /// ltc_protocol.py's order of checks).
    pub(crate) fn bind(base: &mut LtcBase, spec: usize) -> Result<StatusSignals, String> {
        let [counter, state, fault, _missed, estop, servo, period] =
            base.signals(spec, STATUS_SIGNALS)?;
        base.require_integer(spec, &STATUS_SIGNALS[..6])?;
        base.bind_enum(spec, "state", LtcEnum::ControllerState)?;
        base.bind_enum(spec, "fault_code", LtcEnum::FaultCode)?;
        Ok(StatusSignals {
            counter,
            state,
            fault,
            estop,
            servo,
            period,
        })
    }

    /// The status's cycle counter, from raw values `raw`.
    pub(crate) fn counter(&self, raw: &[i64]) -> i64 {
        raw[self.counter]
    }

    /// Fill `fb`'s status part from the accepted raw values `raw` of `codec`.
    pub(crate) fn fill(&self, codec: &MessageCodec, raw: &[i64], fb: &mut Feedback) {
        fb.counter = raw[self.counter] as u32;
        let state = ControllerState::from_u8(raw[self.state] as u8);
        fb.controller_state = state.unwrap_or(ControllerState::Fault); // checked: a member
        fb.fault = LtcEnum::FaultCode
            .name_of(raw[self.fault])
            .unwrap_or("NONE");
        fb.estop = raw[self.estop] != 0;
        fb.servo_power = raw[self.servo] != 0;
        // ltc.py: cycle_period_us * 1e-6, the same IEEE product
        fb.period_s = codec.physical(self.period, raw[self.period]) * 1e-6;
    }
}
