//! Why the core does not forward a JointCommand (core.rs): the checks a command must pass, the
//! problem each refusal names, and the count and note of every refusal by reason.

use super::notes::{INFO, WARNING};
use super::{HostCore, REJECT_REASONS};
use crate::adapter::FrameError;
use crate::messages::fmt_g;

/// Why a JointCommand is not forwarded, with what its note says, formatted only when the
/// note is kept.
pub(super) enum Problem {
    Joints {
        n: usize,
        expected: usize,
    },
    Blocked {
        reason: &'static str,
        cycle: i64,
    },
    NotCurrent {
        cycle: i64,
        current: Option<i64>,
    },
    Answered {
        cycle: i64,
    },
    Stale {
        cycle: i64,
        age_s: f64,
    },
    FollowingError {
        k: usize,
        error: f64,
        limit: f64,
    },
    OutsideLimits {
        k: usize,
        q: f64,
        lower: f64,
        upper: f64,
    },
    Velocity {
        k: usize,
        speed: f64,
        limit: f64,
    },
    Frame(FrameError),
}

impl Problem {
    pub(super) fn reason(&self) -> &'static str {
        match self {
            Problem::Joints { .. } => "bad_message",
            Problem::Blocked { reason, .. } => reason,
            Problem::NotCurrent { .. } | Problem::Answered { .. } => "late_cycle",
            Problem::Stale { .. } => "stale",
            Problem::FollowingError { .. }
            | Problem::OutsideLimits { .. }
            | Problem::Velocity { .. }
            | Problem::Frame(_) => "out_of_range",
        }
    }

    pub(super) fn detail(&self) -> String {
        match self {
            Problem::Joints { n, expected } => format!("{n} joints, expected {expected}"),
            Problem::Blocked { cycle, .. } => format!("cycle {cycle}"),
            Problem::NotCurrent { cycle, current } => match current {
                Some(c) => format!("for cycle {cycle}, current cycle is {c}"),
                None => format!("for cycle {cycle}, current cycle is None"),
            },
            Problem::Answered { cycle } => format!("cycle {cycle} was already answered"),
            Problem::Stale { cycle, age_s } => format!("cycle {cycle} is {:.1} ms old", age_s * 1e3),
            Problem::FollowingError { k, error, limit } => format!(
                "joint {}: |q_cmd - q| = {error:.4} rad > {} rad",
                k + 1,
                fmt_g(*limit)
            ),
            Problem::OutsideLimits { k, q, lower, upper } => format!(
                "joint {}: q_cmd = {q:.4} rad outside the driver's limits [{lower:.4}, {upper:.4}] rad",
                k + 1
            ),
            Problem::Velocity { k, speed, limit } => format!(
                "joint {}: |dq_cmd| = {speed:.4} rad/s > {} rad/s",
                k + 1,
                fmt_g(*limit)
            ),
            Problem::Frame(exc) => exc.0.clone(),
        }
    }
}

impl HostCore {
    /// Why the command (`cycle`, `state_stamp_s`, `q`, `dq`) must not be forwarded, or None.
    pub(super) fn check_command(
        &self,
        cycle: i64,
        state_stamp_s: f64,
        q: &[f64],
        dq: &[f64],
        now: f64,
    ) -> Option<Problem> {
        let n = self.n;
        if q.len() != n || dq.len() != n {
            return Some(Problem::Joints {
                n: q.len(),
                expected: n,
            });
        }
        if let Some(reason) = self.blocked(now) {
            return Some(Problem::Blocked { reason, cycle });
        }
        let pending = match self.pending {
            Some(p) if cycle == (p.cycle & 0xFFFF_FFFF) => p,
            other => {
                return Some(Problem::NotCurrent {
                    cycle,
                    current: other.map(|p| p.cycle),
                })
            }
        };
        if pending.answered() {
            return Some(Problem::Answered { cycle });
        }
        let age_s = now - state_stamp_s.min(pending.stamp_s);
        if age_s > self.command_age_limit_s() {
            return Some(Problem::Stale { cycle, age_s });
        }
        // the worst joint, as numpy's argmax (the first of equals) picks it
        let worst = |value: &dyn Fn(usize) -> f64| -> (usize, f64) {
            let mut best = (0, value(0));
            for k in 1..n {
                let v = value(k);
                if v > best.1 {
                    best = (k, v);
                }
            }
            best
        };
        let q_meas = pending.q();
        if (0..n).any(|k| (q[k] - q_meas[k]).abs() > self.max_fe[k]) {
            let (k, _) = worst(&|k| (q[k] - q_meas[k]).abs() - self.max_fe[k]);
            return Some(Problem::FollowingError {
                k,
                error: (q[k] - q_meas[k]).abs(),
                limit: self.max_fe[k],
            });
        }
        let outside = |k: usize| (self.lower[k] - q[k]).max(q[k] - self.upper[k]);
        if (0..n).any(|k| outside(k) > 0.0) {
            let (k, _) = worst(&outside);
            return Some(Problem::OutsideLimits {
                k,
                q: q[k],
                lower: self.lower[k],
                upper: self.upper[k],
            });
        }
        if (0..n).any(|k| dq[k].abs() > self.max_dq[k]) {
            let (k, _) = worst(&|k| dq[k].abs() - self.max_dq[k]);
            return Some(Problem::Velocity {
                k,
                speed: dq[k].abs(),
                limit: self.max_dq[k],
            });
        }
        None
    }

    pub(super) fn reject(&mut self, problem: &Problem, now: f64) {
        self.reject_with(problem.reason(), now, || problem.detail());
    }

    pub(super) fn reject_with(
        &mut self,
        reason: &'static str,
        now: f64,
        detail: impl FnOnce() -> String,
    ) {
        if let Some(k) = REJECT_REASONS.iter().position(|r| *r == reason) {
            self.rejected[k] += 1;
        }
        let level = if reason.starts_with("blocked_") {
            INFO
        } else {
            WARNING
        };
        self.notes.note(level, reason, now, || {
            format!("JointCommand not forwarded ({reason}): {}", detail())
        });
    }
}
