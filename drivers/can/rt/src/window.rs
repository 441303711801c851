//! The state windows the CAN driver publishes for readers off the cycle (drivers/can/core.py
//! StateWindowBuilder): each cycle's JointState folded into how many states, the fastest
//! joint speed among them, each joint's lowest and highest position, and the newest state
//! whole ([`crate::messages::StateWindow`]).
//!
//! A window closes at the first state at or after its due time, due times `period_s` apart
//! (one window per `period_s` on average, whatever the cycle), or at once when the key (the
//! controller's state and its e-stop and servo-power flags) changes: the gateway sees an
//! e-stop without waiting for the window. The first state closes a window of its own.

use crate::adapter::MAX_JOINTS;
use crate::messages::StateWindow;

/// NumPy's `np.minimum`: NaN if either is NaN.
fn np_minimum(a: f64, b: f64) -> f64 {
    if a.is_nan() || b.is_nan() {
        f64::NAN
    } else {
        a.min(b)
    }
}

/// NumPy's `np.maximum`: NaN if either is NaN.
fn np_maximum(a: f64, b: f64) -> f64 {
    if a.is_nan() || b.is_nan() {
        f64::NAN
    } else {
        a.max(b)
    }
}

/// Folds each cycle's JointState into the window the readers off the cycle get (module
/// docs). Its state lives in fixed arrays: [`StateWindowBuilder::add`] never allocates.
#[derive(Clone, Debug)]
pub struct StateWindowBuilder {
    /// the windows' average period [s]
    pub period_s: f64,
    /// states in the open window
    states: u32,
    /// the fastest joint speed in the open window [rad/s]
    speed: f64,
    /// joints of the open window (0 before the first state)
    n: usize,
    /// each joint's lowest position in the open window [rad]
    lo: [f64; MAX_JOINTS],
    /// each joint's highest position in the open window [rad]
    hi: [f64; MAX_JOINTS],
    /// the key of the last window closed (None before the first)
    key: Option<(i64, i64)>,
    /// when the open window is due [s]
    due_s: f64,
}

impl StateWindowBuilder {
    /// A builder of windows `period_s` [s] apart on average.
    pub fn new(period_s: f64) -> StateWindowBuilder {
        StateWindowBuilder {
            period_s,
            states: 0,
            speed: 0.0,
            n: 0,
            lo: [0.0; MAX_JOINTS],
            hi: [0.0; MAX_JOINTS],
            key: None,
            due_s: f64::NEG_INFINITY,
        }
    }

    /// Take one cycle's measured positions `q` [rad] and velocities `dq` [rad/s], its key
    /// (`(controller state, flags & (FLAG_ESTOP | FLAG_SERVO_POWER))`), its JointState bytes
    /// `state` and the time `now` [s]. True when the window closes: then `out` holds the
    /// window's bytes (cleared first; not reallocated when its capacity holds
    /// [`StateWindow::size`]`(n, state.len())`), else `out` is untouched.
    pub fn add(
        &mut self,
        q: &[f64],
        dq: &[f64],
        key: (i64, i64),
        state: &[u8],
        now: f64,
        out: &mut Vec<u8>,
    ) -> bool {
        let n = q.len().min(MAX_JOINTS);
        // np.abs(dq).max(): NaN if any is NaN
        let speed = dq.iter().fold(f64::NEG_INFINITY, |m, v| {
            if m.is_nan() || v.is_nan() {
                f64::NAN
            } else {
                m.max(v.abs())
            }
        });
        if self.states == 0 || self.n != n {
            self.lo[..n].copy_from_slice(&q[..n]);
            self.hi[..n].copy_from_slice(&q[..n]);
            self.n = n;
            self.speed = speed;
            self.states = 0;
        } else {
            for ((lo, hi), &v) in self.lo.iter_mut().zip(&mut self.hi).zip(&q[..n]) {
                *lo = np_minimum(*lo, v);
                *hi = np_maximum(*hi, v);
            }
            // Python's max(a, b): b only if it is greater
            if speed > self.speed {
                self.speed = speed;
            }
        }
        self.states += 1;
        if now < self.due_s && Some(key) == self.key {
            return false;
        }
        // a window of 1..16 joints always packs; a state of another size closes no window
        let packed = StateWindow::pack(
            out,
            self.states,
            self.speed,
            &self.lo[..n],
            &self.hi[..n],
            state,
        )
        .is_ok();
        // on the period's own grid, so windows come every period_s on average whatever the
        // cycle; a gap (or the first window) starts the grid again
        let due = self.due_s + self.period_s;
        self.key = Some(key);
        self.due_s = if due > now { due } else { now + self.period_s };
        self.states = 0;
        packed
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::messages::JointState;

    const WINDOW_S: f64 = 0.02;
    const PERIOD_S: f64 = 0.004;

    /// A JointState's bytes (test_joint_state_watch.py `state`): joint 4 moves at `speed`.
    fn state(cycle: i64, stamp_s: f64, speed: f64, q: &[f64; 6]) -> Vec<u8> {
        let mut dq = [1e-5; 6];
        dq[3] = speed;
        let mut out = Vec::new();
        JointState::pack(
            &mut out, cycle, stamp_s, 1, 2, PERIOD_S, q, &dq, &[0.0; 6], q, &[0.0; 6],
        )
        .unwrap();
        out
    }

    #[test]
    fn the_window_builder_closes_on_time_and_at_once_on_a_controller_change() {
        // test_joint_state_watch.py
        let mut b = StateWindowBuilder::new(WINDOW_S);
        let (q, dq) = ([0.0; 6], [0.0; 6]);
        let mut out = Vec::with_capacity(512);
        let closes: Vec<bool> = (0..12)
            .map(|k| {
                let t = k as f64 * PERIOD_S;
                b.add(&q, &dq, (1, 2), &state(k, t, 0.0, &q), t, &mut out)
            })
            .collect();
        let mut want = vec![true, false, false, false, false, true];
        want.extend([false; 4]);
        want.extend([true, false]);
        assert_eq!(closes, want);
        assert!(b.add(&q, &dq, (3, 2), &state(12, 0.048, 0.0, &q), 0.048, &mut out));
        let window = StateWindow::from_bytes(&out).unwrap();
        assert_eq!(window.states, 2, "the e-stop did not wait for the window");
        // 8 ms cycles: windows of 3 and 2 cycles, 50 per second on average
        let mut b = StateWindowBuilder::new(WINDOW_S);
        let period = 0.008;
        let closed = (0..1250)
            .filter(|&k| {
                let t = k as f64 * period;
                b.add(&q, &dq, (1, 2), &state(k, t, 0.0, &q), t, &mut out)
            })
            .count();
        assert_eq!(closed, 500);
    }

    #[test]
    fn a_window_carries_every_state_in_it() {
        // test_joint_state_watch.py _window: one window, closed by the last state
        let mut b = StateWindowBuilder::new(1e9);
        let q0 = [-0.5, -0.3, -0.1, 0.1, 0.3, 0.5];
        let mut out = Vec::new();
        let mut last = Vec::new();
        for k in 0..6 {
            let mut q = q0;
            q[1] += 0.01 * k as f64;
            q[4] -= 0.02 * k as f64;
            let speed = if k == 3 { 0.7 } else { 0.0 };
            let data = state(k, 0.01 + 0.004 * k as f64, speed, &q);
            let key = if k < 5 { (1, 2) } else { (2, 2) };
            let st = JointState::from_bytes(&data).unwrap();
            let closed = b.add(&st.q_rad, &st.dq_rad_s, key, &data, st.stamp_s, &mut out);
            assert_eq!(closed, k == 0 || k == 5, "cycle {k}");
            last = data;
        }
        let w = StateWindow::from_bytes(&out).unwrap();
        assert_eq!(w.states, 5, "the first state closed a window of its own");
        assert_eq!(w.max_speed_rad_s, 0.7);
        assert_eq!(w.q_lo_rad[1], q0[1] + 0.01);
        assert_eq!(w.q_hi_rad[1], q0[1] + 0.05);
        assert_eq!(w.q_lo_rad[4], q0[4] - 0.1);
        assert_eq!(w.q_hi_rad[4], q0[4] - 0.02);
        assert_eq!(w.newest, last);
    }

    #[test]
    fn adding_never_reallocates_a_reserved_buffer() {
        let mut b = StateWindowBuilder::new(WINDOW_S);
        let q = [0.0; 6];
        let data = state(1, 0.0, 0.0, &q);
        let mut out = Vec::with_capacity(StateWindow::size(6, data.len()));
        let before = out.as_ptr();
        for k in 0..100 {
            b.add(&q, &q, (1, 2), &data, k as f64 * PERIOD_S, &mut out);
        }
        assert_eq!((out.as_ptr(), out.len()), (before, out.capacity()));
    }
}
