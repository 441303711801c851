//! The zero-moment law's learning from the cycle that just ended (zero_moment.rs): the online
//! inner-loop estimate and eq. (28) (or eqs. 28 and 30), fed only when the drive followed the
//! command that drove the cycle as sent.

use super::{Parts, State, ZeroMoment};
use crate::chain::MAX_JOINTS;
use crate::law::inner_estimate::{self, cycle_means};
use crate::law::outer_loop::Adaptation;

/// Python's `round` (half to even) of a float to an integer.
pub(super) fn round_even(x: f64) -> i64 {
    x.round_ties_even() as i64
}

impl ZeroMoment {
    /// Feed the cycle that just ended to the estimate and the loop's adaptation (eq. 28, or
    /// eqs. 28 and 30) if the drive followed the command that drove it as sent.
    pub(super) fn cycle_regression(
        &mut self,
        parts: &mut Parts,
        st: &State,
        followed: bool,
        period_s: f64,
    ) -> Result<(), String> {
        let n = self.n();
        let prev = self.prev_state;
        let mut q_now = [0.0; MAX_JOINTS];
        let mut dq_now = [0.0; MAX_JOINTS];
        q_now[..n].copy_from_slice(st.q);
        dq_now[..n].copy_from_slice(st.dq);
        self.prev_state = Some((q_now, dq_now));
        let Some((q0, dq0)) = prev.filter(|_| followed) else {
            self.sent.clear();
            return Ok(());
        };
        if self.sent.len() < self.s.command_delay_cycles + 1 {
            return Ok(());
        }
        let (q_cmd, dq_cmd) = self.sent[0];
        let rate = self.s.drive_servo_rate_hz;
        let ticks = if rate != 0.0 {
            round_even(period_s * rate)
        } else {
            0
        };
        let cycle = inner_estimate::Cycle {
            q_cmd_rad: &q_cmd[..n],
            dq_cmd_rad_s: &dq_cmd[..n],
            q_start_rad: &q0[..n],
            q_end_rad: st.q,
            period_s,
            dq_start_end_rad_s: Some((&dq0[..n], st.dq)),
            ticks,
        };
        if let Some(est) = parts.inner.as_deref_mut() {
            est.update(&cycle, st.current_a, 0.02)?;
        }
        if !matches!(parts.outer.adaptation(), Adaptation::None) {
            let mut u1 = [0.0; MAX_JOINTS];
            let mut u2 = [0.0; MAX_JOINTS];
            cycle_means(&cycle, &mut u1[..n], &mut u2[..n])?;
            let mut tau_m = [0.0; MAX_JOINTS];
            self.motor_torque(st.current_a, &mut tau_m[..n]);
            parts.outer.adapt(&u1[..n], &u2[..n], &tau_m[..n], period_s);
        }
        Ok(())
    }

    pub(super) fn regressing(&self, parts: &Parts) -> bool {
        parts.inner.is_some() || !matches!(parts.outer.adaptation(), Adaptation::None)
    }
}
