//! The core's input from CAN (core.rs): each received frame fed to the adapter, and each cycle
//! it completes widened, checked and turned into a JointState (and, now and then, a
//! StateWindow), with its hold at once when forwarding is blocked.

use super::notes::{ERROR, WARNING};
use super::{Answer, Cycle, FrameOutcome, HostCore};
use crate::adapter::{Feedback, MAX_JOINTS};
use crate::frame::Frame;
use crate::messages::{JointState, FLAG_ESTOP, FLAG_PREV_COAST, FLAG_PREV_HOLD, FLAG_SERVO_POWER};

impl HostCore {
    /// Take one received frame. A frame that completes a cycle fills `state` with its
    /// JointState (and `window` with a StateWindow when one closes); a blocked cycle's hold
    /// goes into `out` at once.
    pub fn on_frame(
        &mut self,
        frame: &Frame,
        now: f64,
        out: &mut Vec<Frame>,
        state: &mut Vec<u8>,
        window: &mut Vec<u8>,
    ) -> FrameOutcome {
        self.last_now = now;
        if frame.len as usize > frame.data.len() {
            // not a frame from_wire makes: nothing in it can be read
            self.notes.note(WARNING, "frame", now, || {
                format!("CAN: a frame of {} data bytes dropped", frame.len)
            });
            return FrameOutcome::default();
        }
        if frame.error {
            if let Some(fault) = self.bus.on_error_frame(frame, now) {
                self.notes.note(ERROR, "bus", now, || {
                    format!("CAN bus fault: {fault}; holding, brakes")
                });
            }
        }
        let dropped = {
            let s = self.adapter.stats();
            s.bad_frames + s.incomplete_cycles + s.corrupt_cycles
        };
        match self.adapter.feed(frame, now) {
            Some(fb) => self.on_cycle(fb, now, out, state, window),
            None => {
                let s = self.adapter.stats();
                if s.bad_frames + s.incomplete_cycles + s.corrupt_cycles != dropped {
                    let adapter = &self.adapter;
                    self.notes.note(WARNING, "frame", now, || {
                        format!("CAN: {}", adapter.stats().last_error)
                    });
                }
                FrameOutcome::default()
            }
        }
    }

    /// Wire counter → monotonically increasing cycle number; None for a repeated counter.
    fn widen(&mut self, counter: u32) -> Option<i64> {
        match self.last_counter {
            None => self.cycle = counter as i64,
            Some(last) => {
                let modulus = self.adapter.counter_modulus().max(1) as i64;
                let delta = (counter as i64 - last as i64).rem_euclid(modulus);
                if delta == 0 {
                    return None;
                }
                self.cycle += delta;
            }
        }
        self.last_counter = Some(counter);
        Some(self.cycle)
    }

    fn on_cycle(
        &mut self,
        fb: Feedback,
        now: f64,
        out: &mut Vec<Frame>,
        state: &mut Vec<u8>,
        window: &mut Vec<u8>,
    ) -> FrameOutcome {
        let n = self.n;
        if fb.n != n {
            self.notes.note(ERROR, "frame", now, || {
                format!(
                    "CAN: a cycle of {} joints from the adapter, expected {n}; dropped",
                    fb.n
                )
            });
            return FrameOutcome::default();
        }
        let Some(cycle) = self.widen(fb.counter) else {
            self.notes.note(WARNING, "dup", now, || {
                format!("controller repeated cycle {}", fb.counter)
            });
            return FrameOutcome::default();
        };
        if let Some(implausible) = self.plausibility.check(cycle, fb.q(), fb.period_s) {
            self.notes.note(ERROR, "implausible", now, || {
                format!("CAN: cycle dropped, {implausible}")
            });
            return FrameOutcome::default();
        }
        let previous = self.pending;
        if let Some(p) = previous {
            if !p.answered() {
                self.unanswered += 1;
                self.notes.note(WARNING, "unanswered", now, || {
                    format!(
                        "cycle {} got no answer before cycle {cycle} arrived",
                        p.cycle
                    )
                });
            }
        }
        self.cycles += 1;
        self.bus.on_cycle();
        self.feedback = Some(fb);
        self.last_cycle_rx_s = now;
        self.current_zero.update(fb.current(), fb.servo_power);
        if !fb.controller_state.servoing() {
            // On its brakes the arm is where it is: the next hold starts from there.
            self.holding = false;
            self.last_forwarded_q = None;
            self.last_forward = None;
            self.path.clear();
            self.ramp = None;
        }
        // a lock-step controller waits for the answer; a real one starts its next cycle
        let mut budget_s = self.command_age_limit_s();
        if self.config.lockstep_answer_wait_s == 0.0 && fb.period_s > 0.0 {
            budget_s = budget_s.min(self.config.answer_by_period_fraction * fb.period_s);
        }
        self.pending = Some(Cycle {
            cycle,
            counter: fb.counter,
            stamp_s: now,
            answer_by_s: now + budget_s,
            q_rad: fb.q,
            n,
            answer: Answer::None,
        });
        self.monitor_speed(&fb, cycle, now);

        let q_cmd = self.last_sent_q.unwrap_or(fb.q);
        let dq_cmd = self.last_sent_dq.unwrap_or(self.zeros);
        let mut flags = 0u8;
        if fb.estop {
            flags |= FLAG_ESTOP;
        }
        if fb.servo_power {
            flags |= FLAG_SERVO_POWER;
        }
        if let Some(p) = previous {
            if p.cycle == cycle - 1 {
                if p.answer == Answer::Coast {
                    flags |= FLAG_PREV_COAST;
                } else if p.answer != Answer::Command {
                    flags |= FLAG_PREV_HOLD; // a hold, or none (the controller froze)
                }
            }
        }
        let mut current = [0.0; MAX_JOINTS];
        self.current_zero.correct(fb.current(), &mut current[..n]);
        // n is a joint count (checked at construction) and every slice has n values: packs
        let packed = JointState::pack(
            state,
            cycle,
            now,
            fb.controller_state as u8,
            flags,
            fb.period_s,
            fb.q(),
            fb.dq(),
            &current[..n],
            &q_cmd[..n],
            &dq_cmd[..n],
        )
        .is_ok();
        if self.blocked(now).is_some() {
            self.hold(now, out);
            self.lost.record(false, now);
        }
        if self.wants_servo(now) {
            self.watch_standstill(&fb, cycle, now);
        } else {
            self.clear_latched(now);
        }
        let key = (
            fb.controller_state as i64,
            (flags & (FLAG_ESTOP | FLAG_SERVO_POWER)) as i64,
        );
        if !packed {
            return FrameOutcome::default();
        }
        let window_closed = self.window.add(fb.q(), fb.dq(), key, state, now, window);
        FrameOutcome {
            state: true,
            window: window_closed,
        }
    }
}
