//! What the cell allows now (core.rs): the servo request, whether forwarding is allowed or the
//! reason it is blocked, whether a stop is an ordinary one the drives stay powered through, and
//! how old a command may be.

use super::{fresh, HostCore, LifecycleIn};
use crate::adapter::HostRequest;
use crate::messages::{Lifecycle, COMMANDING};

impl HostCore {
    /// The lifecycle, fresh at `now`.
    fn fresh_lifecycle(&self, now: f64) -> Option<LifecycleIn> {
        self.lifecycle.filter(|lc| {
            fresh(
                lc.stamp_s,
                self.lifecycle_rx_s,
                now,
                self.config.lifecycle_timeout_s,
            )
        })
    }

    /// What the power stage should be asked for now.
    pub fn desired_request(&self, now: f64) -> HostRequest {
        self.desire(now).0
    }

    /// The request, and whether it is BRAKE only because the current sensors' zero is still
    /// being measured (the first SERVO_ON waits for it).
    pub(super) fn desire(&self, now: f64) -> (HostRequest, bool) {
        let Some(lc) = self.fresh_lifecycle(now) else {
            return (HostRequest::Brake, false);
        };
        if self.standstill.trip.is_some() {
            return (HostRequest::Brake, false); // the drives do not hold the arm: nothing else is left
        }
        if self.speed.as_ref().is_some_and(|s| s.trip.is_some()) {
            // A hand that outran the limit fights a rigid hold until the controller faults on
            // its following error and cuts the power: the arm is then free for the brakes'
            // engagement time. The brakes at once instead.
            return (HostRequest::Brake, false);
        }
        if self.bus.fault.is_some() {
            return (HostRequest::Brake, false); // stopped until the operator re-arms (bus_errors.rs)
        }
        if lc.state == Lifecycle::Stopped && (self.ramp.is_some() || self.ramp_due(now)) {
            return (HostRequest::ServoOn, false); // stop category 1: the brakes once the ramp has ended
        }
        if lc.state == Lifecycle::Ready || COMMANDING.contains(&lc.state) {
            if !self.current_zero.ready {
                return (HostRequest::Brake, true);
            }
            return (HostRequest::ServoOn, false);
        }
        (HostRequest::Brake, false)
    }

    /// The controller link is up: a complete cycle arrived within `controller_timeout_s`
    /// (plus `lockstep_answer_wait_s`: a lock-step controller's next cycle waits for our
    /// answer to the last one).
    pub fn link_ok(&self, now: f64) -> bool {
        let allowed_s = self.config.controller_timeout_s + self.config.lockstep_answer_wait_s;
        (now - self.last_cycle_rx_s) < allowed_s
    }

    /// The reason forwarding is not allowed right now (one of
    /// [`REJECT_REASONS`](super::REJECT_REASONS)), or None if it is.
    pub fn blocked(&self, now: f64) -> Option<&'static str> {
        match self.fresh_lifecycle(now) {
            Some(lc) if COMMANDING.contains(&lc.state) => {}
            _ => return Some("blocked_lifecycle"),
        }
        match self.io {
            Some(io)
                if io.enabling
                    && io.estop_ok
                    && fresh(io.stamp_s, self.io_rx_s, now, self.config.io_timeout_s) => {}
            _ => return Some("blocked_enabling"),
        }
        match self.feedback {
            Some(fb) if fb.controller_state.servoing() && self.link_ok(now) => {}
            _ => return Some("blocked_controller"),
        }
        if self.speed.as_ref().is_some_and(|s| s.trip.is_some()) {
            return Some("blocked_speed");
        }
        if self.bus.fault.is_some() {
            return Some("blocked_bus");
        }
        if self.lost.trip.is_some() {
            return Some("blocked_lost");
        }
        None
    }

    /// Forwarding is blocked by an ordinary stop, the drives to stay powered through it: the
    /// enabling device released, or the lifecycle gone to READY or STOPPED, with the
    /// lifecycle and I/O fresh, the e-stop chain closed, the controller servoing and no
    /// monitor tripped; or the lost-cycle rule tripped (lost_cycles.rs: only the command
    /// source failed). Anything else is a fault, held at once.
    pub(super) fn controlled_stop(&self, now: f64) -> bool {
        let (Some(lc), Some(io), Some(fb)) = (self.lifecycle, self.io, self.feedback) else {
            return false;
        };
        let cfg = &self.config;
        if !(fresh(
            lc.stamp_s,
            self.lifecycle_rx_s,
            now,
            cfg.lifecycle_timeout_s,
        ) && fresh(io.stamp_s, self.io_rx_s, now, cfg.io_timeout_s)
            && io.estop_ok
            && fb.controller_state.servoing()
            && self.link_ok(now)
            && self.speed.as_ref().is_none_or(|s| s.trip.is_none())
            && self.standstill.trip.is_none()
            && self.bus.fault.is_none())
        {
            return false;
        }
        matches!(lc.state, Lifecycle::Ready | Lifecycle::Stopped)
            || (COMMANDING.contains(&lc.state) && (!io.enabling || self.lost.trip.is_some()))
    }

    /// The gateway's lifecycle, fresh, is one that keeps the drives powered.
    pub(super) fn wants_servo(&self, now: f64) -> bool {
        self.fresh_lifecycle(now)
            .is_some_and(|lc| lc.state == Lifecycle::Ready || COMMANDING.contains(&lc.state))
    }

    /// How old a command may be when it is forwarded [s]: `deadline_s`, or against a lock-step
    /// virtual controller (which waits for the answer) `lockstep_answer_wait_s`.
    pub(super) fn command_age_limit_s(&self) -> f64 {
        if self.config.lockstep_answer_wait_s > 0.0 {
            self.config.lockstep_answer_wait_s
        } else {
            self.config.deadline_s
        }
    }
}
