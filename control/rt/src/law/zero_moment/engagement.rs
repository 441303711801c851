//! Before the zero-moment law takes over (zero_moment.rs): the states the driver holds the arm
//! in go into the hold's average, the law waits until the arm has rested long enough, then
//! calibrates ω̂ from the hold and takes over bumplessly from the command the robot follows.

use super::{Parts, State, ZeroMoment};
use crate::chain::MAX_JOINTS;
use crate::law::outer_loop::HoldAverage;
use crate::point_model::PointModel;

fn max_abs(a: &[f64]) -> f64 {
    let mut m = f64::NEG_INFINITY;
    for x in a {
        if x.is_nan() {
            return f64::NAN;
        }
        m = m.max(x.abs());
    }
    m
}

impl ZeroMoment {
    /// A state while the arm is held (by the driver, or by this law waiting to engage): at
    /// rest, its held offset and current go into the hold's average for the next engagement;
    /// moving, the average restarts.
    pub fn observe_hold(&self, st: &State, hold: &mut HoldAverage) -> Result<(), String> {
        let n = self.n();
        let held = st.flags & self.s.flag_prev_hold != 0
            || (self.waited > 0 && st.flags & self.s.flag_prev_coast == 0);
        if held && max_abs(st.dq) <= self.s.rest_rad_s {
            let mut offset = [0.0; MAX_JOINTS];
            let mut tau = [0.0; MAX_JOINTS];
            for j in 0..n {
                offset[j] = st.q_cmd[j] - st.q[j];
            }
            self.motor_torque(st.current_a, &mut tau[..n]);
            hold.add(&offset[..n], &tau[..n])
        } else {
            hold.clear();
            Ok(())
        }
    }

    /// Before engaging: take `st` into the hold's average; true while the arm has not rested
    /// long enough to calibrate ω̂ (and at most `engage_max_wait_states`).
    pub fn still_waiting(&mut self, st: &State, hold: &mut HoldAverage) -> Result<bool, String> {
        self.observe_hold(st, hold)?;
        let resting = hold.len() >= self.s.engage_rest_states;
        if !resting && self.waited < self.s.engage_max_wait_states {
            self.waited += 1;
            return Ok(true);
        }
        self.waited = 0;
        Ok(false)
    }

    /// The model's friction at `q` just above rest, per joint [N·m]: the most of it over the
    /// low speeds both ways; 0 where the model is undefined (NaN), inf as the largest float
    /// (numpy's `nan_to_num`).
    pub fn friction_level_at(&self, model: &mut PointModel, q: &[f64], out: &mut [f64]) {
        let n = self.n();
        let mut level = [0.0; MAX_JOINTS];
        let mut stat = [0.0; MAX_JOINTS];
        let mut fr = [0.0; MAX_JOINTS];
        let mut v = [0.0; MAX_JOINTS];
        'speeds: for &speed in &self.s.friction_level_speeds_rad_s {
            for sign in [1.0, -1.0] {
                v[..n].fill(sign * speed);
                let p = &self.s.nominal_pressures_bar;
                if model
                    .cycle_torques(q, &v[..n], p, &mut stat[..n], &mut fr[..n])
                    .is_err()
                {
                    level[..n].fill(f64::NAN);
                    break 'speeds;
                }
                for j in 0..n {
                    // np.maximum: NaN wins
                    let a = fr[j].abs();
                    level[j] = if level[j].is_nan() || a.is_nan() {
                        f64::NAN
                    } else {
                        level[j].max(a)
                    };
                }
            }
        }
        for j in 0..n {
            let x = level[j];
            out[j] = if x.is_nan() {
                0.0
            } else if x == f64::INFINITY {
                f64::MAX
            } else {
                x
            };
        }
    }

    /// Engage: calibrate ω̂ from the hold, take over bumplessly from the command the robot
    /// follows now (the driver's hold), restart every piece's history.
    pub(super) fn engage(&mut self, parts: &mut Parts, st: &State) -> Result<(), String> {
        let n = self.n();
        if !parts.hold.is_empty() {
            let mut offset = [0.0; MAX_JOINTS];
            let mut tau = [0.0; MAX_JOINTS];
            parts.hold.mean(&mut offset[..n], &mut tau[..n])?;
            parts.outer.calibrate_from_hold(&offset[..n], &tau[..n]);
            if parts.hold.len() >= 2 {
                // the paper's dead zone: the torque's noise at rest
                parts.hold.torque_std(&mut tau[..n])?;
                parts.outer.set_dead_zone(&tau[..n]);
            }
        }
        parts.hold.clear();
        let mut offset = [0.0; MAX_JOINTS];
        for j in 0..n {
            offset[j] = st.q_cmd[j] - st.q[j];
        }
        parts.outer.reset(&offset[..n]);
        parts.predictor.reset();
        parts.rest_hold.reset();
        parts.guided.reset();
        self.sent.clear();
        self.prev_state = None;
        self.dq_last = None;
        if self.s.needs_friction_level() {
            let mut level = [0.0; MAX_JOINTS];
            self.friction_level_at(parts.model, st.q, &mut level[..n]);
            self.friction_level = level;
        }
        self.stiction_phase = 0.0;
        self.stiction_gain = 0.0;
        self.since_guided_s = f64::INFINITY;
        self.guide.restart();
        self.engaged = true;
        self.last_cycle = Some(st.cycle - 1);
        Ok(())
    }
}
