//! Plausibility of the measured positions (drivers/can/plausibility.py, issue 10): a cycle
//! whose joint position jumped further than the arm can move is not a measurement.
//!
//! LTC-1's feedback frames carry no CRC of their own, so a broken node, a glitching encoder
//! or a forger can put a wrong position into a complete, well-formed cycle; published, the
//! control process would follow it. So each cycle's positions are compared with the last
//! cycle accepted: a joint that moved more than `max_speed_rad_s` × the time between them
//! (the counter's cycles × the reported period), plus `tolerance_rad` for quantisation, drops
//! the cycle like a corrupt one. The reference stays the last accepted cycle, so one wrong
//! cycle costs one cycle, and an offset that stays (a re-homed encoder) is taken once the
//! allowance has grown to it.

use crate::adapter::MAX_JOINTS;

/// Quantisation allowance of Python's default `tolerance_rad` [rad].
pub const DEFAULT_TOLERANCE_RAD: f64 = 1e-4;

/// Per-joint position steps against the arm's maximum speed. `max_speed_rad_s` 0 turns the
/// check off. The reference lives in a fixed array: [`FeedbackPlausibility::check`] allocates
/// only the text of a refusal.
#[derive(Clone, Debug)]
pub struct FeedbackPlausibility {
    /// the fastest any joint moves [rad/s]; <= 0: off
    pub max_speed_rad_s: f64,
    /// added to every allowance [rad]
    pub tolerance_rad: f64,
    /// cycles refused (monotonic)
    pub dropped: u64,
    /// the reference positions [rad]: the last cycle accepted (`n` of them; 0: none yet)
    q: [f64; MAX_JOINTS],
    n: usize,
    cycle: i64,
}

impl FeedbackPlausibility {
    /// A check at `max_speed_rad_s` [rad/s] with `tolerance_rad` [rad] (Python's default:
    /// [`DEFAULT_TOLERANCE_RAD`]).
    pub fn new(max_speed_rad_s: f64, tolerance_rad: f64) -> FeedbackPlausibility {
        FeedbackPlausibility {
            max_speed_rad_s,
            tolerance_rad,
            dropped: 0,
            q: [0.0; MAX_JOINTS],
            n: 0,
            cycle: 0,
        }
    }

    /// None when `q_rad` [rad] of widened cycle number `cycle` is plausible at the reported
    /// period `period_s` [s], and it becomes the reference; else why not (the reference
    /// stays). A cycle of another joint count than the reference's becomes the reference
    /// (Python would fail on the shapes).
    pub fn check(&mut self, cycle: i64, q_rad: &[f64], period_s: f64) -> Option<String> {
        if self.max_speed_rad_s <= 0.0 {
            return None;
        }
        let n = q_rad.len().min(MAX_JOINTS);
        let q = &q_rad[..n];
        if self.n == 0 || self.n != n || period_s <= 0.0 || cycle <= self.cycle {
            self.take(cycle, q);
            return None;
        }
        let allowed =
            self.max_speed_rad_s * (cycle - self.cycle) as f64 * period_s + self.tolerance_rad;
        // np.argmax of the steps: the first NaN, else the first largest
        let mut worst = 0;
        for k in 0..n {
            let (step, best) = ((q[k] - self.q[k]).abs(), (q[worst] - self.q[worst]).abs());
            if best.is_nan() {
                break;
            }
            if step.is_nan() || step > best {
                worst = k;
            }
        }
        let step = (q[worst] - self.q[worst]).abs();
        if step <= allowed {
            self.take(cycle, q);
            return None;
        }
        self.dropped += 1;
        Some(format!(
            "cycle {cycle}: J{} measured {:+.4} rad, {step:.4} rad from cycle {}'s {:+.4}; the \
             arm moves at most {allowed:.4} rad in that time ({} rad/s)",
            worst + 1,
            q[worst],
            self.cycle,
            self.q[worst],
            crate::messages::fmt_g(self.max_speed_rad_s)
        ))
    }

    fn take(&mut self, cycle: i64, q: &[f64]) {
        self.q[..q.len()].copy_from_slice(q);
        self.n = q.len();
        self.cycle = cycle;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const PERIOD_S: f64 = 0.004;

    #[test]
    fn steps_within_the_speed_are_taken_and_a_jump_drops_one_cycle() {
        let mut p = FeedbackPlausibility::new(5.0, DEFAULT_TOLERANCE_RAD); // 0.02 rad a cycle
        let q = [0.0; 6];
        assert_eq!(p.check(1, &q, PERIOD_S), None);
        assert_eq!(p.check(2, &[0.019; 6], PERIOD_S), None);
        let mut glitch = [0.019; 6];
        glitch[3] += 0.5;
        let why = p.check(3, &glitch, PERIOD_S).unwrap();
        assert!(why.contains("J4") && why.contains("cycle 3"), "{why}");
        assert_eq!(
            why,
            "cycle 3: J4 measured +0.5190 rad, 0.5000 rad from cycle 2's +0.0190; the arm \
             moves at most 0.0201 rad in that time (5 rad/s)"
        );
        // two cycles from the reference: 0.04 + 0.0001
        assert_eq!(p.check(4, &[0.05; 6], PERIOD_S), None);
        assert_eq!(p.dropped, 1);
    }

    #[test]
    fn the_allowance_grows_with_the_cycles_between_so_a_lasting_offset_is_taken() {
        let mut p = FeedbackPlausibility::new(5.0, DEFAULT_TOLERANCE_RAD);
        assert_eq!(p.check(10, &[0.0, 0.0], PERIOD_S), None);
        let offset = [0.1, 0.0]; // re-homed: five cycles' worth
        let taken: Vec<bool> = (11..17)
            .map(|c| p.check(c, &offset, PERIOD_S).is_none())
            .collect();
        // cycle 15: 5 cycles × 0.02 rad + tolerance
        assert_eq!(taken, [false, false, false, false, true, true]);
    }

    #[test]
    fn without_a_period_or_with_the_check_off_everything_is_taken() {
        for period_s in [0.0, -1.0] {
            let mut p = FeedbackPlausibility::new(5.0, DEFAULT_TOLERANCE_RAD);
            assert_eq!(p.check(1, &[0.0; 3], PERIOD_S), None);
            assert_eq!(p.check(2, &[9.0; 3], period_s), None);
        }
        let mut off = FeedbackPlausibility::new(0.0, DEFAULT_TOLERANCE_RAD);
        assert_eq!(off.check(1, &[0.0; 3], PERIOD_S), None);
        assert_eq!(off.check(2, &[9.0; 3], PERIOD_S), None);
    }

    #[test]
    fn a_nan_position_is_refused_and_named() {
        let mut p = FeedbackPlausibility::new(5.0, DEFAULT_TOLERANCE_RAD);
        assert_eq!(p.check(1, &[0.0; 3], PERIOD_S), None);
        let why = p.check(2, &[0.0, f64::NAN, 0.3], PERIOD_S).unwrap();
        assert!(why.contains("J2"), "{why}");
        assert_eq!(
            p.check(3, &[0.0; 3], PERIOD_S),
            None,
            "the reference stayed"
        );
    }
}
