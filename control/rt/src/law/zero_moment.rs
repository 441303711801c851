//! The zero-moment law's cycle: one joint state (and the cylinders' pressures) in, one
//! position/velocity command out (issue 48: the per-cycle path compiled).
//!
//! What the motors must give so the operator feels no load (the model's torque at rest less
//! the cylinders', friction where it opposes the motion, damping, soft joint limits, the rest
//! hold, a share of M(q) q̈), turned by eq. (21) into the command the vendor's closed loop
//! accepts. Around it, per cycle:
//!
//! - engagement: before teaching the arm rests in the driver's hold; the hold's mean offset
//!   and current calibrate ω̂ ([`OuterLoop::calibrate_from_hold`]), then the law takes over
//!   bumplessly from the command the robot follows;
//! - eq. (28) (or eqs. 28 and 30) and the online inner-loop estimate on the cycle that just
//!   ended, if the drive followed the command that drove it as sent;
//! - the Smith predictor over the command delay (law/delay.rs) on the datasheet's nominal
//!   rigid body, M(q) recomputed only after a joint moved [`Settings::inertia_step_rad`];
//! - the friction compensation ramped in over the speed the loop delay allows, in full while
//!   a positioning joint slides (law/guided_friction.rs);
//! - hand guiding's speed limit on the tool point and the flange, on the predicted state;
//! - constrained guiding's fixture on the tool (law/guide.rs: the gun's orientation held, the
//!   tool point in a plane or on a line), on the predicted state, its reference taken at
//!   engagement or where a new guide finds the arm;
//! - the stiction dither (`[control] stiction_dither`, off by default): a joint at rest is
//!   held by its static friction, which the model's friction (zero at rest) never offsets, so
//!   the painter's first push must break it away alone, and a joint that barely moves on a
//!   path sticks while the others slide (the demo's J2 on its downward leg: 2.8 s at rest
//!   while the hand's torque on it built to 38 N·m). As Li et al. (Robotica 2025) compensate
//!   start-up torque, each joint at rest gets a sine of a share of its friction level: below
//!   the breakaway it moves nothing by itself, and on every swing towards the push the hand
//!   needs only the rest of the breakaway. Only while the arm is guided (a positioning joint
//!   moves faster than [`STICTION_GATE_RAD_S`], or the friction's guided switch is on,
//!   law/guided_friction.rs) and `stiction_dither_hold_s` after: an arm nobody guides
//!   is left to its stiction (on the virtual cell a dither at rest tripled the weightless
//!   arm's drift, 0.05-0.13 -> 0.32-0.36 mm in 5 s).
//!
//! The pieces (outer loop, predictor, rest hold, guided switch, hold average, estimate) are
//! the control process's own objects, borrowed for the cycle ([`Parts`]); this module holds
//! what only the cycle needs (caches, the engagement's state). The arithmetic is the Python
//! law's it replaced (control/zero_moment_law.py `ZeroMomentController`), in the same order.

#![allow(clippy::needless_range_loop)] // per-joint arithmetic reads as the formulas

use crate::chain::{Chain, Work, MAX_JOINTS};
use crate::law::delay::{self, DelayPredictor};
use crate::law::guide::{Guide, GuideMode};
use crate::law::guided_friction::{GuidedFriction, POSITIONING_JOINTS};
use crate::law::inner_estimate::InnerLoopEstimator;
use crate::law::outer_loop::{HoldAverage, OuterLoop};
use crate::law::rest_hold::RestHold;
use crate::point_model::PointModel;

mod engagement;
mod inertia;
mod regression;
mod settings;
mod tool_speed;

pub use self::settings::Settings;

type Joints = [f64; MAX_JOINTS];
/// The stiction dither fades in and out over this [s]: a step of the friction level's share
/// would jolt the arm.
pub const STICTION_FADE_S: f64 = 0.25;
/// The arm is guided for the stiction dither while a positioning joint moves faster than this
/// [rad/s]: five times the rest speed; the dither alone moved an untouched arm's joints at
/// 3.6 mrad/s at most (the weightless stack test), so it never keeps itself on.
pub const STICTION_GATE_RAD_S: f64 = 0.01;
const SQUARE: usize = MAX_JOINTS * MAX_JOINTS;

/// One joint state as the driver reported it.
pub struct State<'a> {
    pub cycle: i64,
    pub flags: u32,
    /// The cycle's period [s] (0: not said).
    pub period_s: f64,
    pub q: &'a [f64],
    pub dq: &'a [f64],
    /// The command the driver sent last (this state's echo).
    pub q_cmd: &'a [f64],
    pub dq_cmd: &'a [f64],
    pub current_a: &'a [f64],
}

/// The process's pieces the cycle borrows.
pub struct Parts<'a> {
    pub outer: &'a mut OuterLoop,
    pub predictor: &'a mut DelayPredictor,
    pub rest_hold: &'a mut RestHold,
    pub guided: &'a mut GuidedFriction,
    pub hold: &'a mut HoldAverage,
    pub inner: Option<&'a mut InnerLoopEstimator>,
    pub model: &'a mut PointModel,
    /// The nominal rigid body and its work arrays, when the settings need it.
    pub chain: Option<(&'a Chain, &'a mut Work)>,
}

/// What the cycle keeps between states (module docs).
pub struct ZeroMoment {
    pub s: Settings,
    pub engaged: bool,
    /// States answered with a hold while waiting for the arm to rest before engaging.
    pub waited: usize,
    pub last_cycle: Option<i64>,
    tau_d: Joints,
    ramps: Joints,
    friction_level: Joints,
    speed_target: f64,
    /// (q it was computed at, M(q)⁻¹, M(q)).
    m_at: Option<Joints>,
    m_inv: [f64; SQUARE],
    m: [f64; SQUARE],
    /// (q they were computed at, the tool point's linear Jacobian over the flange's: 6 × n).
    jac_at: Option<Joints>,
    jac: [f64; 6 * MAX_JOINTS],
    /// Commands sent, oldest first (the one that drove a cycle is delay + 1 back).
    sent: Vec<(Joints, Joints)>,
    prev_state: Option<(Joints, Joints)>,
    dither_phase: f64,
    /// the stiction dither's phase [rad], its gain (0..1, fading in and out with the
    /// guiding), the time since the arm was last guided [s], its torque of the last cycle [N·m]
    stiction_phase: f64,
    stiction_gain: f64,
    since_guided_s: f64,
    stiction: Joints,
    ddq_f: Joints,
    dq_last: Option<Joints>,
    tau_inertia: Joints,
    /// Constrained guiding (law/guide.rs) and its torque of the last cycle [N·m].
    pub guide: Guide,
    tau_guide: Joints,
}

fn max_abs_diff(a: &[f64], b: &[f64]) -> f64 {
    // np.max(np.abs(a - b)): NaN if any difference is NaN
    let mut m = f64::NEG_INFINITY;
    for (x, y) in a.iter().zip(b) {
        let d = (x - y).abs();
        if d.is_nan() {
            return f64::NAN;
        }
        m = m.max(d);
    }
    m
}

/// `a⁻¹` (n × n row-major) by Gauss-Jordan elimination with partial pivoting; Err when
/// singular (numpy's `LinAlgError`).
pub fn invert(a: &[f64], n: usize, out: &mut [f64]) -> Result<(), String> {
    let mut m = [0.0; SQUARE];
    m[..n * n].copy_from_slice(&a[..n * n]);
    out[..n * n].fill(0.0);
    for i in 0..n {
        out[i * n + i] = 1.0;
    }
    for c in 0..n {
        let mut p = c;
        for r in c + 1..n {
            if m[r * n + c].abs() > m[p * n + c].abs() {
                p = r;
            }
        }
        let pivot = m[p * n + c];
        if pivot == 0.0 || !pivot.is_finite() {
            return Err("the nominal mass matrix is singular".into());
        }
        if p != c {
            for k in 0..n {
                m.swap(p * n + k, c * n + k);
                out.swap(p * n + k, c * n + k);
            }
        }
        let inv = 1.0 / pivot;
        for k in 0..n {
            m[c * n + k] *= inv;
            out[c * n + k] *= inv;
        }
        for r in 0..n {
            if r == c {
                continue;
            }
            let f = m[r * n + c];
            if f != 0.0 {
                for k in 0..n {
                    m[r * n + k] -= f * m[c * n + k];
                    out[r * n + k] -= f * out[c * n + k];
                }
            }
        }
    }
    Ok(())
}

impl ZeroMoment {
    pub fn new(s: Settings) -> ZeroMoment {
        let cap = s.command_delay_cycles + 1;
        let guide = Guide::new(s.guide, s.guide_mode);
        ZeroMoment {
            speed_target: s.max_tool_speed_m_s,
            s,
            engaged: false,
            waited: 0,
            last_cycle: None,
            tau_d: [0.0; MAX_JOINTS],
            ramps: [0.0; MAX_JOINTS],
            friction_level: [0.0; MAX_JOINTS],
            m_at: None,
            m_inv: [0.0; SQUARE],
            m: [0.0; SQUARE],
            jac_at: None,
            jac: [0.0; 6 * MAX_JOINTS],
            sent: Vec::with_capacity(cap),
            prev_state: None,
            dither_phase: 0.0,
            stiction_phase: 0.0,
            stiction_gain: 0.0,
            since_guided_s: f64::INFINITY,
            stiction: [0.0; MAX_JOINTS],
            ddq_f: [0.0; MAX_JOINTS],
            dq_last: None,
            tau_inertia: [0.0; MAX_JOINTS],
            guide,
            tau_guide: [0.0; MAX_JOINTS],
        }
    }

    fn n(&self) -> usize {
        self.s.n
    }

    /// The desired torque of the last cycle [N·m].
    pub fn tau_d(&self) -> &[f64] {
        &self.tau_d[..self.n()]
    }

    /// Per joint, the speed over which the friction compensation ramps in this cycle [rad/s].
    pub fn ramps(&self) -> &[f64] {
        &self.ramps[..self.n()]
    }

    pub fn set_ramps(&mut self, ramps: &[f64]) {
        let n = self.n();
        self.ramps[..n].copy_from_slice(&ramps[..n]);
    }

    /// The model's friction level at the engagement's pose [N·m].
    pub fn friction_level(&self) -> &[f64] {
        &self.friction_level[..self.n()]
    }

    /// The inertia compensation's torque of the last cycle [N·m].
    pub fn tau_inertia(&self) -> &[f64] {
        &self.tau_inertia[..self.n()]
    }

    /// The constrained guiding's torque of the last cycle [N·m].
    pub fn guide_torque(&self) -> &[f64] {
        &self.tau_guide[..self.n()]
    }

    /// The stiction dither's torque of the last cycle [N·m].
    pub fn stiction_torque(&self) -> &[f64] {
        &self.stiction[..self.n()]
    }

    /// The stiction dither (module docs) for a cycle of `dt_s` [s] whose measured joint
    /// velocities are `dq` [rad/s], `guided` whether the arm is being guided now
    /// (law/guided_friction.rs): while it is and for `stiction_dither_hold_s` after, on each
    /// joint at rest (|dq| at most `rest_rad_s`, fading out to twice that), a sine of
    /// `stiction_dither` × the joint's friction level at `stiction_dither_hz`, the joints'
    /// phases spread over the period; it fades in and out over [`STICTION_FADE_S`].
    fn stiction_dither(&mut self, dq: &[f64], guided: bool, dt_s: f64) {
        let n = self.n();
        self.stiction[..n].fill(0.0);
        let share = self.s.stiction_dither;
        if share <= 0.0 {
            return;
        }
        self.since_guided_s = if guided {
            0.0
        } else {
            self.since_guided_s + dt_s
        };
        let target = if self.since_guided_s < self.s.stiction_dither_hold_s {
            1.0
        } else {
            0.0
        };
        let step = dt_s / STICTION_FADE_S;
        self.stiction_gain += (target - self.stiction_gain).clamp(-step, step);
        if self.stiction_gain <= 0.0 {
            return;
        }
        let turn = 2.0 * std::f64::consts::PI;
        self.stiction_phase =
            (self.stiction_phase + turn * self.s.stiction_dither_hz * dt_s) % turn;
        let rest = self.s.rest_rad_s;
        let amplitude = self.stiction_gain * share;
        for j in 0..n {
            let fade = (2.0 - dq[j].abs() / rest).clamp(0.0, 1.0);
            let phase = self.stiction_phase + turn * j as f64 / n as f64;
            self.stiction[j] = fade * amplitude * self.friction_level[j] * phase.sin();
        }
    }

    /// The tool speed the commands of the last cycle were held to [m/s].
    pub fn speed_target_m_s(&self) -> f64 {
        self.speed_target
    }

    pub fn set_speed_target(&mut self, m_s: f64) {
        self.speed_target = m_s;
    }

    pub fn disengage(&mut self) {
        self.engaged = false;
        self.waited = 0;
    }

    /// The joint torque a state's motor currents report [N·m]: `k_nm_per_a · i -
    /// torque_offset_nm` (the datasheet's K and the measured torque channel, [`Settings`]).
    pub fn motor_torque(&self, current_a: &[f64], out: &mut [f64]) {
        for j in 0..self.n() {
            out[j] = self.s.k_nm_per_a[j] * current_a[j] - self.s.torque_offset_nm[j];
        }
    }

    /// Per joint, the speed over which the friction compensation ramps in: `factor` × the
    /// loop delay × the friction level × (M⁻¹)ⱼⱼ.
    fn friction_ramps(&mut self, period_s: f64) {
        let n = self.n();
        let lag = (self.s.command_delay_cycles as f64 + 1.0) * period_s;
        for j in 0..n {
            self.ramps[j] =
                self.s.friction_ramp_factor * lag * self.friction_level[j] * self.m_inv[j * n + j];
        }
    }

    /// The command offset `q_c - q` [rad] at which the vendor loop, following a path at (q,
    /// dq), gives the model's torque there: eq. (21)'s steady state `ω̂ τ / Υ̂_I`.
    pub fn hold_offset(
        &self,
        model: &mut PointModel,
        outer: &OuterLoop,
        q: &[f64],
        dq: &[f64],
        p_bar: &[f64],
        out: &mut [f64],
    ) -> Result<(), String> {
        let n = self.n();
        let mut stat = [0.0; MAX_JOINTS];
        let mut fr = [0.0; MAX_JOINTS];
        model.cycle_torques(q, dq, p_bar, &mut stat[..n], &mut fr[..n])?;
        for j in 0..n {
            out[j] = outer.omega()[j] * (stat[j] + fr[j]) / outer.upsilon_i()[j];
        }
        Ok(())
    }

    /// The desired torque at the predicted (q, dq), then eq. (21) over `dt_s`.
    #[allow(clippy::too_many_arguments)]
    fn cycle_command(
        &mut self,
        parts: &mut Parts,
        q: &[f64],
        dq: &[f64],
        p_bar: &[f64],
        dt_s: f64,
        q_cmd: &mut [f64],
        dq_cmd: &mut [f64],
    ) -> Result<(), String> {
        let n = self.n();
        let s = &self.s;
        let dead = s.friction_deadband_rad_s;
        let mut dq_f = [0.0; MAX_JOINTS];
        for j in 0..n {
            let v = dq[j];
            dq_f[j] = if v > dead {
                v - dead
            } else if v < -dead {
                v + dead
            } else {
                0.0
            };
        }
        let mut stat = [0.0; MAX_JOINTS];
        let mut fr = [0.0; MAX_JOINTS];
        parts
            .model
            .cycle_torques(q, &dq_f[..n], p_bar, &mut stat[..n], &mut fr[..n])?;
        let mut hold = [0.0; MAX_JOINTS];
        if parts.rest_hold.active() {
            parts.rest_hold.torque_nm(q, &mut hold[..n])?;
        }
        let (gain, k) = (s.friction_compensation, s.wall_stiffness_nm_per_rad);
        let mut tau = [0.0; MAX_JOINTS];
        for j in 0..n {
            let ramp = self.ramps[j];
            let share = if ramp <= 0.0 {
                gain
            } else {
                gain * (dq_f[j].abs() / ramp).min(1.0)
            };
            let f = fr[j];
            let friction = if f * dq[j] > 0.0 { share * f } else { 0.0 };
            let mut t = stat[j] + friction - s.damping_nm_s_per_rad[j] * dq[j]
                + hold[j]
                + self.tau_inertia[j]
                + self.stiction[j]
                + self.tau_guide[j];
            if q[j] > s.upper_rad[j] {
                t -= k * (q[j] - s.upper_rad[j]);
            }
            if q[j] < s.lower_rad[j] {
                t += k * (s.lower_rad[j] - q[j]);
            }
            tau[j] = t;
        }
        if !s.dither_nm.is_empty() {
            self.dither_phase += 2.0 * std::f64::consts::PI * dt_s;
            for (j, d) in s.dither_nm.iter().enumerate() {
                tau[j] += d * ((4.0 + 0.4 * j as f64) * self.dither_phase + j as f64).sin();
            }
        }
        self.tau_d[..n].copy_from_slice(&tau[..n]);
        let mut saturated = [false; MAX_JOINTS];
        parts
            .outer
            .step(q, dq, &tau[..n], dt_s, q_cmd, dq_cmd, &mut saturated[..n]);
        Ok(())
    }

    /// `(q_cmd, dq_cmd)` answering `st` with cylinder pressures `p_bar` [bar]. Err where the
    /// model cannot be evaluated at `st` (the caller sends nothing and disengages); a NaN in
    /// the result is left for the message layer to refuse.
    pub fn answer(
        &mut self,
        parts: &mut Parts,
        st: &State,
        p_bar: &[f64],
        q_cmd: &mut [f64],
        dq_cmd: &mut [f64],
    ) -> Result<(), String> {
        let n = self.n();
        let period = if st.period_s != 0.0 {
            st.period_s
        } else {
            self.s.default_cycle_period_s
        };
        if !self.engaged {
            if self.still_waiting(st, parts.hold)? {
                q_cmd[..n].copy_from_slice(st.q_cmd);
                dq_cmd[..n].fill(0.0);
                return Ok(());
            }
            self.engage(parts, st)?;
        }
        let gap = st.cycle - self.last_cycle.unwrap_or(st.cycle - 1);
        let dt = period * gap.clamp(1, 50) as f64;
        self.last_cycle = Some(st.cycle);
        let both = self.s.flag_prev_hold | self.s.flag_prev_coast;
        let followed = gap == 1 && st.flags & both == 0;
        if self.regressing(parts) {
            self.cycle_regression(parts, st, followed, period)?;
        }
        let mut q = [0.0; MAX_JOINTS];
        let mut dq = [0.0; MAX_JOINTS];
        q[..n].copy_from_slice(st.q);
        dq[..n].copy_from_slice(st.dq);
        if let Some((chain, work)) = parts.chain.as_mut() {
            self.refresh_inertia(chain, work, st.q)?;
            if self.s.friction_ramp_factor != 0.0 {
                self.friction_ramps(period);
                if parts.guided.update(st.dq, &self.ramps[..n], dt)? {
                    self.ramps[..n].fill(0.0);
                }
            }
            let mut k_star = [0.0; MAX_JOINTS];
            let mut ups = [0.0; MAX_JOINTS];
            match &self.s.drive_model {
                Some((k, u)) => {
                    k_star[..n].copy_from_slice(k);
                    ups[..n].copy_from_slice(u);
                }
                None => {
                    for j in 0..n {
                        k_star[j] = 1.0 / parts.outer.omega()[j];
                        ups[j] = parts.outer.upsilon_i()[j];
                    }
                }
            }
            if self.s.inertia_compensation != 0.0 {
                self.inertia_torque(st.dq, period, gap == 1);
            }
            let cycle = delay::Cycle {
                q: st.q,
                dq: st.dq,
                echo_q: st.q_cmd,
                echo_dq: st.dq_cmd,
                period_s: period,
                consecutive: gap == 1,
            };
            let drive = delay::Drive {
                m_inv: &self.m_inv[..n * n],
                k_star: &k_star[..n],
                upsilon: &ups[..n],
            };
            parts
                .predictor
                .predict(&cycle, &drive, &mut q[..n], &mut dq[..n])
                .map_err(|e| e.to_string())?;
            if self.s.max_tool_speed_m_s > 0.0 {
                self.speed_target = self.speed_target(chain, work, &q[..n], &dq[..n]);
            }
            // the fixture on the state the command acts at, like the rest of the torque
            self.guide
                .torque(chain, work, &q[..n], &dq[..n], &mut self.tau_guide[..n]);
        } else if self.guide.mode() != GuideMode::Free {
            return Err("constrained guiding needs the nominal chain".into());
        }
        let moving = st.dq[..n.min(POSITIONING_JOINTS)]
            .iter()
            .any(|v| v.abs() > STICTION_GATE_RAD_S);
        self.stiction_dither(st.dq, moving || parts.guided.guided(), dt);
        self.cycle_command(parts, &q[..n], &dq[..n], p_bar, dt, q_cmd, dq_cmd)?;
        if self.s.max_tool_speed_m_s > 0.0 {
            if let Some((chain, work)) = parts.chain.as_mut() {
                // hand guiding's speed limit, in the command path: a velocity command the tool
                // or the flange would exceed it with is scaled down (the operator meets a wall)
                let scale = self.tool_speed_scale(chain, work, &q[..n], &dq_cmd[..n]);
                if scale < 1.0 {
                    for v in dq_cmd[..n].iter_mut() {
                        *v *= scale;
                    }
                }
            }
        }
        if self.regressing(parts) {
            if self.sent.len() == self.s.command_delay_cycles + 1 {
                self.sent.remove(0);
            }
            let mut a = [0.0; MAX_JOINTS];
            let mut b = [0.0; MAX_JOINTS];
            a[..n].copy_from_slice(&q_cmd[..n]);
            b[..n].copy_from_slice(&dq_cmd[..n]);
            self.sent.push((a, b));
        }
        Ok(())
    }
}

#[cfg(test)]
#[path = "zero_moment_tests.rs"]
mod tests;
