//! The velocity a controlled stop's ramp starts from (stop_ramp.rs, core/answers.rs).
//!
//! The ramp continues the command path. Its velocity is the last forwarded command's own,
//! unless a cycle within the last [`PATH_CYCLES`] went by without a forwarded command (the
//! driver coasted or held it, or it was lost on the way): a hold steps the arm's speed to zero,
//! the arm springs back for a few cycles (the vendor loop settles a one-cycle hold in about
//! four), and a law that commands the arm's own predicted state (the zero-moment law) sends
//! that spring-back as its velocity. On the LTC cell J2's commanded velocity read +71 mrad/s
//! a cycle after such a hold while the hand had it moving at −105, and a ramp on it, the
//! enabling device released at that moment, ran the arm 4-14 mm back against where the hand
//! had taken it (tests/stack/test_stack.py, 2026-12-03). Over such a window the ramp starts at
//! the path's own velocity: the last command's position less that of the newest command
//! forwarded before the window's first gap, over the cycles between them.

use crate::adapter::MAX_JOINTS;

/// The window [cycles] in which a gap in the forwarded commands makes the path's velocity the
/// ramp's: the drive's settling after a one-cycle hold (about 4 cycles: p90 of the current's
/// deviation 20, 12, 12, 6, 6, 3.6 A after 49 holds against ~1 A of scatter) and a command
/// delay of up to 4 cycles.
pub const PATH_CYCLES: i64 = 8;
/// How many forwarded commands are kept: one per cycle back to the oldest a path's velocity
/// is taken from (twice the window), and the newest.
const KEPT: usize = 2 * PATH_CYCLES as usize + 1;

/// The last forwarded commands' cycles and positions, newest last. Fixed-size: pushing never
/// allocates.
#[derive(Clone, Copy, Debug)]
pub struct PathHistory {
    cycles: [i64; KEPT],
    q: [[f64; MAX_JOINTS]; KEPT],
    len: usize,
    /// where the next push goes
    next: usize,
}

impl Default for PathHistory {
    fn default() -> Self {
        Self::new()
    }
}

impl PathHistory {
    pub fn new() -> PathHistory {
        PathHistory {
            cycles: [0; KEPT],
            q: [[0.0; MAX_JOINTS]; KEPT],
            len: 0,
            next: 0,
        }
    }

    /// Forget every command (a new servo-on period, the brakes).
    pub fn clear(&mut self) {
        self.len = 0;
        self.next = 0;
    }

    /// A command forwarded for `cycle` (the widened cycle count) at `q_rad` (at most
    /// [`MAX_JOINTS`] taken).
    pub fn push(&mut self, cycle: i64, q_rad: &[f64]) {
        let n = q_rad.len().min(MAX_JOINTS);
        self.cycles[self.next] = cycle;
        self.q[self.next][..n].copy_from_slice(&q_rad[..n]);
        self.next = (self.next + 1) % KEPT;
        self.len = (self.len + 1).min(KEPT);
    }

    /// The `k`-th newest entry (0: the newest), `k < len`.
    fn entry(&self, k: usize) -> (i64, &[f64; MAX_JOINTS]) {
        let i = (self.next + KEPT - 1 - k) % KEPT;
        (self.cycles[i], &self.q[i])
    }

    /// The velocity a ramp from the newest command starts with, into `out` (one per joint of
    /// `dq_last`, that command's own velocity [rad/s]); `period_s` the cycle [s]. The path's
    /// velocity where a gap lies within [`PATH_CYCLES`] of the newest command, else `dq_last`.
    /// Returns whether the path's velocity was taken.
    pub fn start_velocity(&self, dq_last: &[f64], period_s: f64, out: &mut [f64]) -> bool {
        let n = dq_last.len().min(out.len()).min(MAX_JOINTS);
        out[..n].copy_from_slice(&dq_last[..n]);
        if self.len < 2 || period_s <= 0.0 {
            return false;
        }
        let (newest, q_new) = self.entry(0);
        // the command before the oldest gap whose later side lies within the window, and
        // itself within twice the window (a longer gap tells no path's velocity)
        let mut before_gap = None;
        for k in 0..self.len - 1 {
            let (later, _) = self.entry(k);
            let (earlier, _) = self.entry(k + 1);
            if newest - later >= PATH_CYCLES || newest - earlier > 2 * PATH_CYCLES {
                break;
            }
            if later - earlier > 1 {
                before_gap = Some(k + 1);
            }
        }
        let Some(k) = before_gap else {
            return false;
        };
        let (cycle, q_old) = self.entry(k);
        let span = (newest - cycle) as f64 * period_s;
        if !(span > 0.0) {
            return false; // out of order
        }
        for j in 0..n {
            out[j] = (q_new[j] - q_old[j]) / span;
        }
        true
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn velocity(h: &PathHistory, dq_last: f64) -> (bool, f64) {
        let mut out = [0.0; 2];
        let taken = h.start_velocity(&[dq_last, -dq_last], 0.008, &mut out);
        assert_eq!(out[1], -out[0]);
        (taken, out[0])
    }

    #[test]
    fn a_consecutive_path_keeps_the_last_commands_own_velocity() {
        let mut h = PathHistory::new();
        assert_eq!(velocity(&h, 0.3), (false, 0.3));
        for c in 0..20 {
            let q = 0.1 * c as f64 * 0.008;
            h.push(c, &[q, -q]);
        }
        assert_eq!(velocity(&h, 0.3), (false, 0.3));
    }

    #[test]
    fn after_a_gap_the_ramp_starts_at_the_paths_velocity_not_the_spring_back() {
        // moving at 0.1 rad/s; cycles 10-12 not forwarded (the drive held); the command for
        // 13 is where the path had got to, its velocity the arm's spring-back (-0.07)
        let mut h = PathHistory::new();
        for c in 0..10 {
            let q = 0.1 * c as f64 * 0.008;
            h.push(c, &[q, -q]);
        }
        let q13 = 0.1 * 13.0 * 0.008;
        h.push(13, &[q13, -q13]);
        let (taken, v) = velocity(&h, -0.07);
        assert!(taken && (v - 0.1).abs() < 1e-12, "{v}");
        // still within the window seven cycles after the gap
        for c in 14..21 {
            let q = 0.1 * c as f64 * 0.008;
            h.push(c, &[q, -q]);
        }
        let (taken, v) = velocity(&h, -0.07);
        assert!(taken && (v - 0.1).abs() < 1e-12, "{v}");
        // and out of it once the gap is PATH_CYCLES behind the newest command
        h.push(21, &[0.1 * 21.0 * 0.008, -0.1 * 21.0 * 0.008]);
        assert_eq!(velocity(&h, 0.09), (false, 0.09));
    }

    #[test]
    fn a_gap_too_long_or_a_cleared_history_keeps_the_last_velocity() {
        let mut h = PathHistory::new();
        h.push(0, &[0.0, 0.0]);
        h.push(2 * PATH_CYCLES + 1, &[0.5, -0.5]);
        assert_eq!(velocity(&h, 0.2), (false, 0.2));
        h.push(2 * PATH_CYCLES + 3, &[0.6, -0.6]);
        let (taken, v) = velocity(&h, 0.2);
        assert!(taken && (v - 0.1 / (2.0 * 0.008)).abs() < 1e-9, "{v}");
        h.clear();
        assert_eq!(velocity(&h, 0.2), (false, 0.2));
    }
}
