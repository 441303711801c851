//! The latched monitors the core feeds (core.rs): hand guiding's speed, the standstill while
//! the driver holds, the lost command cycles, and their clearing once the cell is stopped.

use super::notes::{ERROR, INFO};
use super::{fresh, HostCore, MONITORED};
use crate::adapter::Feedback;

impl HostCore {
    /// Hand guiding's speed from this cycle's measured positions, while the lifecycle
    /// teaches or replays and the controller servos; anything else resets the monitor (and
    /// clears a trip: the gateway has left the state the trip stopped).
    pub(super) fn monitor_speed(&mut self, fb: &Feedback, cycle: i64, now: f64) {
        let lc = self.lifecycle;
        let applies = lc.is_some_and(|lc| {
            MONITORED.contains(&lc.state)
                && fresh(
                    lc.stamp_s,
                    self.lifecycle_rx_s,
                    now,
                    self.config.lifecycle_timeout_s,
                )
        });
        let Some(monitor) = self.speed.as_mut() else {
            return;
        };
        if !applies {
            if monitor.trip.is_some() {
                self.notes.always(INFO, "speed", || {
                    format!(
                        "speed monitor cleared: lifecycle {}",
                        lc.map_or("None", |l| l.state.name())
                    )
                });
            }
            monitor.reset();
            return;
        }
        if !fb.controller_state.servoing() || fb.period_s <= 0.0 {
            monitor.gap();
            return;
        }
        let tripped = monitor.trip.is_some();
        monitor.update(cycle, fb.q(), fb.period_s);
        if !tripped {
            if let Some(trip) = monitor.trip.as_ref() {
                self.notes.note(ERROR, "speed", now, || {
                    format!("speed monitor: {}; holding", trip.message())
                });
            }
        }
    }

    /// Monitored standstill (stop_ramp.rs) while the driver holds with the servo on and the
    /// lifecycle wants the servo.
    pub(super) fn watch_standstill(&mut self, fb: &Feedback, cycle: i64, now: f64) {
        let hold_q = match self.hold_q {
            Some(q) if self.holding && fb.controller_state.servoing() => q,
            _ => {
                self.standstill.idle();
                return;
            }
        };
        let monitor = &mut self.standstill;
        monitor.watch(&hold_q[..self.n], now);
        let tripped = monitor.trip.is_some();
        monitor.update(fb.q(), cycle, now);
        if !tripped {
            if let Some(trip) = monitor.trip.as_ref() {
                self.notes.note(ERROR, "standstill", now, || {
                    format!("standstill monitor: {}; brakes", trip.message())
                });
            }
        }
    }

    /// The cell is stopped (STOPPED, FAULT, or a silent gateway): the standstill and
    /// lost-cycle trips clear, and a bus fault once the bus has worked again
    /// (bus_errors.rs); a re-arm is still the operator's.
    pub(super) fn clear_latched(&mut self, now: f64) {
        if self.bus.fault.is_some() && self.bus.clear(now) {
            self.notes.always(INFO, "bus", || {
                "CAN bus fault cleared: the bus works again and the cell is stopped".to_string()
            });
        }
        let state = self.lifecycle.map_or("None", |lc| lc.state.name());
        if self.standstill.trip.is_some() {
            self.notes.always(INFO, "standstill", || {
                format!("standstill monitor cleared: lifecycle {state}")
            });
        }
        self.standstill.reset();
        if self.lost.trip.is_some() {
            self.notes.always(INFO, "lost", || {
                format!("lost cycles cleared: lifecycle {state}")
            });
        }
        self.lost.reset();
    }

    /// The pending cycle was lost (lost_cycles.rs): count it, and say so if it trips.
    pub(super) fn record_lost(&mut self, now: f64) {
        if let Some(trip) = self.lost.record(true, now) {
            self.notes.note(ERROR, "lost", now, || {
                format!("lost command cycles: {}; stopping the arm", trip.message())
            });
        }
    }
}
