//! The core's clock (core.rs): what is due at a time (deadline answers, servo requests, host
//! heartbeats, a host-clocked link's cycle start), when it is next due, the health period, and
//! the frames that close the link on exit.

use super::notes::{ERROR, INFO};
use super::{next_tick, HostCore};
use crate::adapter::{ControllerState, HostRequest};
use crate::frame::Frame;

impl HostCore {
    /// Deadline answers, servo requests, heartbeats and (host-clocked links) the cycle's
    /// clock frames due at `now`, appended to `out`.
    pub fn on_tick(&mut self, now: f64, out: &mut Vec<Frame>) {
        self.last_now = now;
        if let Some(pending) = self.pending {
            if !pending.answered() && now >= pending.answer_by_s {
                let allowed = self.blocked(now).is_none();
                if !self.coast(now, out) {
                    self.hold(now, out);
                }
                if allowed {
                    self.record_lost(now);
                }
            }
        }
        let (desired, waits_for_zero) = self.desire(now);
        if waits_for_zero {
            let zero = &self.current_zero;
            self.notes.note(INFO, "zero", now, || {
                format!(
                    "servo on waits for the current sensors' zero ({} of {} cycles with the servo power off)",
                    zero.samples, zero.window
                )
            });
        }
        let heartbeat_due = now >= self.next_heartbeat_s;
        if heartbeat_due {
            out.push(self.adapter.heartbeat_frame());
            self.next_heartbeat_s =
                next_tick(self.next_heartbeat_s, self.config.heartbeat_period_s, now);
        }
        if Some(desired) != self.request_sent || heartbeat_due {
            if desired == HostRequest::ServoOn && self.request_sent != Some(desired) {
                // A new servo-on period: nothing forwarded in it yet.
                self.holding = false;
                self.last_forwarded_q = None;
                self.last_forward = None;
                self.path.clear();
            }
            if Some(desired) != self.request_sent {
                self.notes.always(INFO, "request", || {
                    format!("requesting {} from the controller", desired.name())
                });
            }
            self.adapter.request_frames(desired, out);
            self.request_sent = Some(desired);
        }
        if self.reset_wanted {
            self.reset_wanted = false;
            if let Some(fb) = self.feedback {
                if fb.controller_state == ControllerState::Fault {
                    self.notes.always(INFO, "reset", || {
                        format!(
                            "operator reset: asking the controller to leave FAULT ({})",
                            fb.fault
                        )
                    });
                    self.adapter.request_frames(HostRequest::ResetFault, out);
                    self.request_sent = Some(HostRequest::ResetFault); // BRAKE follows next pass
                }
            }
        }
        if let Some(period) = self.adapter.clock_period_s() {
            if now >= self.next_clock_s {
                // Last: the answers and requests above take effect at this cycle's start.
                self.adapter.clock_frames(out);
                self.next_clock_s = next_tick(self.next_clock_s, period, now);
            }
        }
    }

    /// The earliest time [`HostCore::on_tick`] has something due (an answer, a heartbeat, a
    /// clock frame) [s]; -inf when a reset waits. A change of request (a lifecycle message)
    /// arrives through a call of its own; the loop also wakes for those at least every few
    /// milliseconds.
    pub fn next_tick_s(&self) -> f64 {
        if self.reset_wanted {
            return f64::NEG_INFINITY;
        }
        let mut due = self.next_heartbeat_s.min(self.next_clock_s);
        if let Some(p) = self.pending {
            if !p.answered() {
                due = due.min(p.answer_by_s);
            }
        }
        due
    }

    /// True once per health period (and then schedules the next).
    pub fn health_due(&mut self, now: f64) -> bool {
        if now < self.next_health_s {
            return false;
        }
        self.next_health_s = next_tick(self.next_health_s, self.health_period_s, now);
        true
    }

    /// BRAKE, then a hold for the cycle still waiting for its answer (on exit); on a
    /// host-clocked link, then the cycle start that makes them take effect.
    pub fn closing_frames(&mut self, out: &mut Vec<Frame>) {
        self.adapter.request_frames(HostRequest::Brake, out);
        self.request_sent = Some(HostRequest::Brake);
        if let Some(pending) = self.pending {
            let mark = out.len();
            if let Err(exc) = self.hold_frames(&pending, out) {
                out.truncate(mark);
                let now = self.last_now;
                self.notes.note(ERROR, "hold", now, || {
                    format!("cannot build a hold set on exit: {exc}")
                });
            }
        }
        if self.adapter.clock_period_s().is_some() {
            // A host-clocked cycle's frames take effect at its next SYNC: without one the
            // BRAKE would wait for the drives' heartbeat watch (120 ms and 13-22 mm at
            // 120-220 mm/s on the virtual CiA 402 drives, 2026-11-28).
            self.adapter.clock_frames(out);
        }
    }
}
