//! How the core answers a cycle the control process's command did not (core.rs): a coast on
//! the last forwarded command, a controlled stop's ramp, or a hold set.

use super::notes::{ERROR, INFO};
use super::{Answer, Cycle, HostCore, RAMP_MAX_AGE_CYCLES};
use crate::adapter::{FrameError, MAX_JOINTS};
use crate::core_config::LostCycleAnswer;
use crate::frame::Frame;
use crate::stop_ramp::StopRamp;

fn any_nonzero(values: &[f64]) -> bool {
    values.iter().any(|&v| v != 0.0) // NaN counts, as numpy's any() does
}

impl HostCore {
    /// The hold set for `pending` into `out`; holding begins (at the last forwarded command
    /// when it is within the following error of the measured position, else at the measured
    /// position) if it had not.
    pub(super) fn hold_frames(
        &mut self,
        pending: &Cycle,
        out: &mut Vec<Frame>,
    ) -> Result<(), FrameError> {
        let n = self.n;
        if !self.holding {
            let q_meas = pending.q_rad;
            let near = |last: &[f64; MAX_JOINTS]| {
                (0..n).all(|k| (last[k] - q_meas[k]).abs() <= self.max_fe[k])
            };
            self.hold_q = Some(match self.last_forwarded_q {
                Some(last) if near(&last) => last,
                _ => q_meas,
            });
            self.holding = true;
        }
        let hold_q = self.hold_q.unwrap_or(pending.q_rad);
        self.adapter
            .command_frames(pending.counter, &hold_q[..n], &self.zeros[..n], true, out)
    }

    /// A controlled stop is about to begin: the arm was commanded moving a moment ago and the
    /// stop is an ordinary one, so the next cycle starts a ramp ([`HostCore::ramp_for`]). The
    /// servo request is decided between cycles too: without this, the operator's stop
    /// arriving between two cycles asked for the brakes before the ramp could begin (the
    /// fault campaign's `operator_stop`: 135 mm/s to rest in 32 ms, not a ramp).
    pub(super) fn ramp_due(&self, now: f64) -> bool {
        let (Some(last), Some(pending)) = (self.last_forward, self.pending) else {
            return false;
        };
        if self.holding || !any_nonzero(&last.dq[..self.n]) {
            return false;
        }
        let age = pending.cycle + 1 - last.cycle; // at the cycle the ramp would begin
        age <= RAMP_MAX_AGE_CYCLES && self.controlled_stop(now)
    }

    /// Whether the pending cycle belongs to a controlled stop: the one under way, or a new one
    /// (started here, in `self.ramp`) from the last forwarded command when a controlled stop
    /// begins while the arm was commanded; false (and a ramp under way ends where it got to)
    /// when the cycle is to be held.
    fn ramp_for(&mut self, pending: &Cycle, now: f64) -> bool {
        let n = self.n;
        if let Some(ramp) = self.ramp.as_ref() {
            if self.controlled_stop(now) {
                return true;
            }
            let mut q = [0.0; MAX_JOINTS];
            let mut dq = [0.0; MAX_JOINTS];
            ramp.at(pending.cycle, &mut q[..n], &mut dq[..n]); // a fault: hold where it is
            self.ramp = None;
            self.hold_q = Some(q);
            self.holding = true;
            return false;
        }
        let Some(last) = self.last_forward else {
            return false;
        };
        if self.holding || !self.controlled_stop(now) {
            return false;
        }
        let age = pending.cycle - last.cycle;
        if last.period_s <= 0.0
            || !(0..=RAMP_MAX_AGE_CYCLES).contains(&age)
            || !any_nonzero(&last.dq[..n])
        {
            return false;
        }
        // the path's velocity where the last commands followed a cycle nobody commanded
        // (ramp_start.rs), else the last command's own
        let mut dq0 = [0.0; MAX_JOINTS];
        let from_path = self
            .path
            .start_velocity(&last.dq[..n], last.period_s, &mut dq0[..n]);
        // where the last command (or its coasting) has got to
        let mut q_now = [0.0; MAX_JOINTS];
        for ((q, &q0), &dq) in q_now.iter_mut().zip(&last.q).zip(&dq0).take(n) {
            *q = q0 + dq * age as f64 * last.period_s;
        }
        let ramp = StopRamp::start(
            pending.cycle,
            &q_now[..n],
            &dq0[..n],
            &self.stop_decel,
            last.period_s,
        );
        let duration_s = ramp.duration_s;
        self.ramp = Some(ramp);
        self.notes.note(INFO, "ramp", now, || {
            format!(
                "controlled stop: ramping to standstill in {:.0} ms{}",
                duration_s * 1e3,
                if from_path {
                    " at the path's speed (a cycle went uncommanded just before)"
                } else {
                    ""
                }
            )
        });
        true
    }

    /// Answer the pending cycle with the controlled stop's ramp while one runs, else with a
    /// hold set (none if the position cannot be encoded).
    pub(super) fn hold(&mut self, now: f64, out: &mut Vec<Frame>) {
        let Some(pending) = self.pending else {
            return;
        };
        let n = self.n;
        if self.ramp_for(&pending, now) {
            let mut q = [0.0; MAX_JOINTS];
            let mut dq = [0.0; MAX_JOINTS];
            let done = match self.ramp.as_ref() {
                Some(ramp) => ramp.at(pending.cycle, &mut q[..n], &mut dq[..n]),
                None => true,
            };
            if !done {
                let mark = out.len();
                match self
                    .adapter
                    .command_frames(pending.counter, &q[..n], &dq[..n], false, out)
                {
                    Ok(()) => {
                        self.set_answer(Answer::Ramp);
                        self.ramped += 1;
                        self.last_sent_q = Some(q);
                        self.last_sent_dq = Some(dq);
                        return;
                    }
                    Err(exc) => {
                        out.truncate(mark);
                        self.notes.note(ERROR, "ramp", now, || {
                            format!("cannot send the ramp: {exc}; holding")
                        });
                    }
                }
            }
            self.ramp = None; // hold where it ended
            self.hold_q = Some(q);
            self.holding = true;
        }
        let mark = out.len();
        if let Err(exc) = self.hold_frames(&pending, out) {
            // measured q the protocol cannot carry: nothing to hold
            out.truncate(mark);
            self.notes.note(ERROR, "hold", now, || {
                format!("cannot build a hold set: {exc}")
            });
            return;
        }
        self.set_answer(Answer::Hold);
        self.held += 1;
        self.last_sent_q = self.hold_q;
        self.last_sent_dq = Some(self.zeros);
    }

    fn set_answer(&mut self, answer: Answer) {
        if let Some(p) = self.pending.as_mut() {
            p.answer = answer;
        }
    }

    /// Answer a cycle whose command is late with the last forwarded command, moved on by its
    /// own velocity, as long as that command answered one of the `coast_max_cycles` cycles
    /// before this one (and, against a controller whose cycles stalled, is at most
    /// `deadline_s` plus one period more than that many old), and moved on stays within the
    /// following error and limits a forwarded command must meet; false if coasting is not
    /// allowed. A hold after it keeps the coasted position: the controller was sent there.
    ///
    /// The bound counts the periods the coast spans: the command of the cycle before is one
    /// period plus the answer deadline old when it coasts, 12 ms at LTC-1's 8 ms, so a bound
    /// of `deadline_s` (10 ms) alone let nothing coast at that rate and every late command
    /// became a hold, a dead stop of an arm the hand was moving (0.2 rad/s to 0 within one
    /// cycle on J2, 54 A, in the stack's release test, 2026-11-29). The age bound stays: a
    /// controller whose cycles stalled gets a hold, not a command extrapolated over the
    /// stall.
    pub(super) fn coast(&mut self, now: f64, out: &mut Vec<Frame>) -> bool {
        let (Some(pending), Some(last)) = (self.pending, self.last_forward) else {
            return false;
        };
        let max_cycles = self.config.coast_max_cycles;
        if self.config.lost_cycle_answer == LostCycleAnswer::Hold
            || self.holding
            || pending.cycle - last.cycle > max_cycles
            || now - last.stamp_s
                > self.command_age_limit_s() + (max_cycles + 1) as f64 * last.period_s
        {
            return false;
        }
        let n = self.n;
        let mut q_coast = [0.0; MAX_JOINTS];
        let age = (pending.cycle - last.cycle) as f64;
        for ((q, &q0), &dq) in q_coast.iter_mut().zip(&last.q).zip(&last.dq).take(n) {
            *q = q0 + dq * age * last.period_s;
        }
        // what a forwarded command must meet: near the arm's measured position, in the limits
        if (0..n).any(|k| {
            (q_coast[k] - pending.q_rad[k]).abs() > self.max_fe[k]
                || q_coast[k] < self.lower[k]
                || q_coast[k] > self.upper[k]
        }) {
            return false;
        }
        let mark = out.len();
        if self
            .adapter
            .command_frames(pending.counter, &q_coast[..n], &last.dq[..n], false, out)
            .is_err()
        {
            out.truncate(mark);
            return false;
        }
        self.set_answer(Answer::Coast);
        self.coasted += 1;
        self.last_sent_q = Some(q_coast);
        self.last_sent_dq = Some(last.dq);
        self.last_forwarded_q = Some(q_coast); // a hold that follows does not pull the arm back
        true
    }
}
