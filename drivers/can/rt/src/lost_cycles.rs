//! Lost command cycles, and the policy that stops the arm when there are too many
//! (drivers/can/lost_cycles.py, issue 10).
//!
//! A cycle is *lost* when forwarding was allowed (nothing blocked it: lifecycle, enabling
//! device, controller, monitors) and no valid command for it came by its answer deadline, so
//! the driver answered it itself. One lost cycle costs the operator nothing: the driver coasts
//! on the last command (core.rs). Many say the control process, its host or the zenoh link is
//! failing, and an arm commanded that way is not under control. The rules, in `[can]`:
//!
//! - `lost_cycle_answer`: [`COAST_ANSWER`] (default) answers a lost cycle with the last
//!   forwarded command moved on by its own velocity while that is allowed, then with a hold;
//!   [`HOLD_ANSWER`] holds at once, never extrapolating;
//! - `lost_cycles_max_consecutive` N: N lost cycles in a row trip;
//! - `lost_cycles_max_per_window` M within `lost_cycles_window_s`: M lost cycles within the
//!   window trip (a link that loses every other cycle never reaches N in a row).
//!
//! 0 turns a rule off. A trip latches: forwarding is blocked (`blocked_lost`), the driver
//! stops the arm as for a released enabling device, reports `lost_cycles_trip` in its health,
//! and the gateway faults. It clears when the cell is stopped; the operator re-arms.

use crate::messages::fmt_g;

/// `lost_cycle_answer`: coast on the last forwarded command, then hold.
pub const COAST_ANSWER: &str = "coast";
/// `lost_cycle_answer`: hold at once.
pub const HOLD_ANSWER: &str = "hold";

/// The times [s] of the newest events within a window, oldest first, in a ring allocated
/// once: Python's `deque` of event times, pruned from the front, for a rule "`limit` events
/// within the window". Holding only the newest `capacity` times is enough for that rule:
/// [`RecentTimes::len`] is `min(events in the window, capacity)`, so it reaches a limit
/// <= capacity exactly when Python's deque does.
#[derive(Clone, Debug)]
pub struct RecentTimes {
    times: Vec<f64>,
    head: usize,
    len: usize,
}

impl RecentTimes {
    /// A ring of `capacity` times (at least 1), allocated here and never again.
    pub fn new(capacity: usize) -> RecentTimes {
        RecentTimes {
            times: vec![0.0; capacity.max(1)],
            head: 0,
            len: 0,
        }
    }

    /// Append `now` [s] (dropping the oldest when full), then drop the times more than
    /// `window_s` [s] older than `now`, as Python's `append` and `popleft` loop.
    pub fn push_and_prune(&mut self, now: f64, window_s: f64) {
        let cap = self.times.len();
        if self.len == cap {
            self.head = (self.head + 1) % cap;
            self.len -= 1;
        }
        self.times[(self.head + self.len) % cap] = now;
        self.len += 1;
        while self.len > 0 && now - self.times[self.head] > window_s {
            self.head = (self.head + 1) % cap;
            self.len -= 1;
        }
    }

    /// Times held (events within the window, at most the capacity).
    pub fn len(&self) -> usize {
        self.len
    }

    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    pub fn clear(&mut self) {
        self.head = 0;
        self.len = 0;
    }
}

/// Why the lost-cycle policy tripped.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LostCyclesTrip {
    /// "consecutive" or "window"
    pub rule: &'static str,
    /// lost cycles counted by that rule
    pub count: i64,
    /// the window of the per-window rule [s]
    pub window_s: f64,
}

impl LostCyclesTrip {
    pub fn message(&self) -> String {
        if self.rule == "consecutive" {
            format!("{} command cycles lost in a row", self.count)
        } else {
            format!(
                "{} command cycles lost within {} s",
                self.count,
                fmt_g(self.window_s)
            )
        }
    }
}

/// The counters of the module docs; [`LostCycles::record`] once per answered cycle. Never
/// allocates after construction.
#[derive(Clone, Debug)]
pub struct LostCycles {
    /// N: lost cycles in a row that trip (0: rule off)
    pub max_consecutive: i64,
    /// M: lost cycles within the window that trip (0: rule off)
    pub max_per_window: i64,
    /// the window of the M rule [s]
    pub window_s: f64,
    /// the latched trip
    pub trip: Option<LostCyclesTrip>,
    /// lost cycles since start (health)
    pub lost: i64,
    /// lost cycles in a row now
    pub consecutive: i64,
    recent: RecentTimes,
}

impl LostCycles {
    /// The policy; Err (Python's ValueError) for a negative limit or a window not > 0 [s].
    pub fn new(
        max_consecutive: i64,
        max_per_window: i64,
        window_s: f64,
    ) -> Result<LostCycles, String> {
        if max_consecutive < 0 || max_per_window < 0 || window_s.is_nan() || window_s <= 0.0 {
            return Err(format!(
                "lost-cycle limits {max_consecutive}, {max_per_window} must be >= 0 and the \
                 window {} s > 0",
                crate::messages::py_repr(window_s)
            ));
        }
        Ok(LostCycles {
            max_consecutive,
            max_per_window,
            window_s,
            trip: None,
            lost: 0,
            consecutive: 0,
            recent: RecentTimes::new(max_per_window as usize),
        })
    }

    /// Take one answered cycle (`lost`: the driver answered it itself while forwarding was
    /// allowed) at `now` [s]; returns the trip when this cycle made one (a standing trip is
    /// kept, not returned again).
    pub fn record(&mut self, lost: bool, now: f64) -> Option<LostCyclesTrip> {
        if !lost {
            self.consecutive = 0;
            return None;
        }
        self.lost += 1;
        self.consecutive += 1;
        self.recent.push_and_prune(now, self.window_s);
        if self.trip.is_some() {
            return None;
        }
        let in_window = self.recent.len() as i64;
        if self.max_consecutive > 0 && self.consecutive >= self.max_consecutive {
            self.trip = Some(LostCyclesTrip {
                rule: "consecutive",
                count: self.consecutive,
                window_s: self.window_s,
            });
        } else if self.max_per_window > 0 && in_window >= self.max_per_window {
            self.trip = Some(LostCyclesTrip {
                rule: "window",
                count: in_window,
                window_s: self.window_s,
            });
        }
        self.trip
    }

    /// The cell is stopped: clear a trip and the counts towards one.
    pub fn reset(&mut self) {
        self.trip = None;
        self.consecutive = 0;
        self.recent.clear();
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn n_lost_in_a_row_trip_and_a_forwarded_cycle_breaks_the_run() {
        let mut lost = LostCycles::new(3, 0, 1.0).unwrap();
        assert!(lost.record(true, 0.0).is_none() && lost.record(true, 0.004).is_none());
        assert!(
            lost.record(false, 0.008).is_none(),
            "a command came: the run starts again"
        );
        assert!(lost.record(true, 0.012).is_none() && lost.record(true, 0.016).is_none());
        let trip = lost.record(true, 0.020).unwrap();
        assert_eq!(trip.message(), "3 command cycles lost in a row");
        assert!(lost.record(false, 0.024).is_none());
        assert_eq!(lost.trip, Some(trip), "a trip stays");
        lost.reset();
        assert!(lost.trip.is_none());
        assert_eq!(lost.lost, 5);
    }

    #[test]
    fn m_lost_within_the_window_trip_when_none_are_in_a_row() {
        let mut lost = LostCycles::new(3, 4, 1.0).unwrap();
        for k in 0..3 {
            // every other cycle lost, 0.3 s apart: 3 within a second
            assert!(lost.record(true, 0.3 * k as f64).is_none());
            assert!(lost.record(false, 0.3 * k as f64 + 0.004).is_none());
        }
        assert!(
            lost.record(true, 1.2).is_none(),
            "the first one has left the window"
        );
        let trip = lost.record(true, 1.25).unwrap();
        assert_eq!(trip.rule, "window");
        assert!(trip.message().contains("4 command cycles lost within 1 s"));
    }

    #[test]
    fn zero_turns_a_rule_off_and_nonsense_is_refused() {
        let mut lost = LostCycles::new(0, 0, 1.0).unwrap();
        assert!((0..1000).all(|k| lost.record(true, 0.001 * k as f64).is_none()));
        assert!(LostCycles::new(1, 1, 0.0).unwrap_err().contains("window"));
        assert!(LostCycles::new(-1, 1, 1.0).is_err());
        assert!(LostCycles::new(1, 1, f64::NAN).is_err());
        assert_eq!((COAST_ANSWER, HOLD_ANSWER), ("coast", "hold"));
    }

    #[test]
    fn a_trip_after_a_reset_counts_afresh_and_the_ring_matches_a_deque() {
        let mut lost = LostCycles::new(0, 3, 0.5).unwrap();
        assert!(lost.record(true, 0.0).is_none() && lost.record(true, 0.1).is_none());
        assert!(lost.record(true, 0.2).is_some());
        for k in 0..10 {
            lost.record(true, 0.3 + 0.01 * k as f64); // latched: counted, no new trip
        }
        lost.reset();
        assert!(lost.record(true, 0.5).is_none() && lost.record(true, 0.6).is_none());
        assert_eq!(lost.record(true, 0.7).map(|t| t.count), Some(3));
        // the ring against Python's deque, over events of every spacing
        let mut ring = RecentTimes::new(4);
        let mut deque: std::collections::VecDeque<f64> = Default::default();
        let mut t = 0.0;
        for k in 0..500u32 {
            t += [0.01, 0.2, 0.05, 0.6, 0.0][(k * 7 % 5) as usize];
            ring.push_and_prune(t, 0.5);
            deque.push_back(t);
            while deque.front().is_some_and(|&f| t - f > 0.5) {
                deque.pop_front();
            }
            assert_eq!(ring.len(), deque.len().min(4));
        }
    }
}
