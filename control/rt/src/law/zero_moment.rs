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

use serde_json::Value;

use crate::chain::{Chain, Work, MAX_JOINTS};
use crate::law::delay::{self, DelayPredictor};
use crate::law::guide::{Guide, GuideMode, GuideSettings};
use crate::law::guided_friction::{GuidedFriction, POSITIONING_JOINTS};
use crate::law::inner_estimate::{self, cycle_means, InnerLoopEstimator};
use crate::law::outer_loop::{Adaptation, HoldAverage, OuterLoop};
use crate::law::rest_hold::RestHold;
use crate::point_model::PointModel;
use crate::table::{finite, vector};

type Joints = [f64; MAX_JOINTS];
/// The stiction dither fades in and out over this [s]: a step of the friction level's share
/// would jolt the arm.
pub const STICTION_FADE_S: f64 = 0.25;
/// The arm is guided for the stiction dither while a positioning joint moves faster than this
/// [rad/s]: five times the rest speed; the dither alone moved an untouched arm's joints at
/// 3.6 mrad/s at most (the weightless stack test), so it never keeps itself on.
pub const STICTION_GATE_RAD_S: f64 = 0.01;
const SQUARE: usize = MAX_JOINTS * MAX_JOINTS;

/// The law's settings ([control] of the cell config, the robot's datasheet), as
/// control/zero_moment_law.py writes them for [`Settings::from_json`].
#[derive(Clone, Debug)]
pub struct Settings {
    pub n: usize,
    /// The cycle when a state does not say [s].
    pub default_cycle_period_s: f64,
    /// States at rest in the hold before engaging, and the most to wait for them.
    pub engage_rest_states: usize,
    pub engage_max_wait_states: usize,
    /// A joint slower than this is at rest [rad/s].
    pub rest_rad_s: f64,
    /// The JointState flags: the previous command was held / coasted by the driver.
    pub flag_prev_hold: u32,
    pub flag_prev_coast: u32,
    /// Joint torque per motor ampere [N·m/A]: the datasheet's constant over the torque
    /// channel's gain the identification measured (1 where it measured none).
    pub k_nm_per_a: Vec<f64>,
    /// What the torque channel reads at zero torque, over that gain [N·m] (zeros where the
    /// identification measured none): the joint torque is `k_nm_per_a · i - torque_offset_nm`.
    pub torque_offset_nm: Vec<f64>,
    pub friction_deadband_rad_s: f64,
    pub friction_compensation: f64,
    pub wall_stiffness_nm_per_rad: f64,
    pub damping_nm_s_per_rad: Vec<f64>,
    /// The soft joint limits [rad].
    pub lower_rad: Vec<f64>,
    pub upper_rad: Vec<f64>,
    pub friction_ramp_factor: f64,
    pub command_delay_cycles: usize,
    pub inertia_compensation: f64,
    pub inertia_compensation_hz: f64,
    /// Hand guiding's speed limit on the tool point and the flange [m/s] (0: none).
    pub max_tool_speed_m_s: f64,
    pub speed_feedback_gain: f64,
    /// M(q) is recomputed after a joint moved this far [rad]; the speed limit's Jacobians
    /// after this far.
    pub inertia_step_rad: f64,
    pub speed_jacobian_step_rad: f64,
    /// The low speeds the friction level at engagement is the most of [rad/s].
    pub friction_level_speeds_rad_s: Vec<f64>,
    pub nominal_pressures_bar: Vec<f64>,
    /// The tool point in the link-6 (tool) frame [m].
    pub tool_in_6_m: [f64; 3],
    pub drive_servo_rate_hz: f64,
    /// The inner-loop dither's torque amplitude per joint [N·m] (empty: none).
    pub dither_nm: Vec<f64>,
    /// The stiction dither (module docs): its amplitude as a share of each joint's friction
    /// level (0: off), its frequency [Hz], and how long it goes on after the arm was last
    /// guided [s].
    pub stiction_dither: f64,
    pub stiction_dither_hz: f64,
    pub stiction_dither_hold_s: f64,
    /// The delay predictor's drive model (K K_p, Υ_I) when it is not the law's estimates.
    pub drive_model: Option<(Vec<f64>, Vec<f64>)>,
    /// Constrained guiding's fixture (law/guide.rs) and the mode the law starts in.
    pub guide: GuideSettings,
    pub guide_mode: GuideMode,
}

fn count(v: &Value, key: &str) -> Result<usize, String> {
    let x = finite(v.get(key), key)?;
    if x < 0.0 || x.fract() != 0.0 {
        return Err(format!("{key}: {x} is not a count"));
    }
    Ok(x as usize)
}

/// A number that may be absent (0).
fn optional(v: &Value, key: &str) -> Result<f64, String> {
    match v.get(key) {
        None | Some(Value::Null) => Ok(0.0),
        x => finite(x, key),
    }
}

fn joints(v: &Value, key: &str, n: usize) -> Result<Vec<f64>, String> {
    let x = vector(v.get(key), key)?;
    if x.len() != n {
        return Err(format!("{key} needs {n} values, got {}", x.len()));
    }
    Ok(x)
}

impl Settings {
    pub fn from_json(v: &Value) -> Result<Settings, String> {
        let n = count(v, "n")?;
        if n == 0 || n > MAX_JOINTS {
            return Err(format!("n: {n} joints, 1..={MAX_JOINTS} taken"));
        }
        let tool = vector(v.get("tool_in_6_m"), "tool_in_6_m")?;
        if tool.len() != 3 {
            return Err("tool_in_6_m needs 3 values".into());
        }
        let dither = vector(v.get("dither_nm"), "dither_nm")?;
        if !dither.is_empty() && dither.len() != n {
            return Err(format!("dither_nm needs {n} values or none"));
        }
        let guide_mode = match v.get("guide") {
            None | Some(Value::Null) => GuideMode::Free,
            Some(Value::String(name)) => GuideMode::parse(name)?,
            Some(other) => return Err(format!("guide: {other} is not a name")),
        };
        let guide = GuideSettings {
            stiffness_n_per_m: optional(v, "guide_stiffness_n_per_m")?,
            damping_n_s_per_m: optional(v, "guide_damping_n_s_per_m")?,
            rot_stiffness_nm_per_rad: optional(v, "guide_rot_stiffness_nm_per_rad")?,
            rot_damping_nm_s_per_rad: optional(v, "guide_rot_damping_nm_s_per_rad")?,
            axis: match v.get("guide_axis") {
                None | Some(Value::Null) => 0,
                Some(_) => count(v, "guide_axis")?,
            },
        };
        guide.check()?;
        let drive_model = match v.get("drive_model") {
            None | Some(Value::Null) => None,
            Some(d) => Some((joints(d, "k_star", n)?, joints(d, "upsilon", n)?)),
        };
        let s = Settings {
            n,
            default_cycle_period_s: finite(
                v.get("default_cycle_period_s"),
                "default_cycle_period_s",
            )?,
            engage_rest_states: count(v, "engage_rest_states")?,
            engage_max_wait_states: count(v, "engage_max_wait_states")?,
            rest_rad_s: finite(v.get("rest_rad_s"), "rest_rad_s")?,
            flag_prev_hold: count(v, "flag_prev_hold")? as u32,
            flag_prev_coast: count(v, "flag_prev_coast")? as u32,
            k_nm_per_a: joints(v, "k_nm_per_a", n)?,
            torque_offset_nm: match v.get("torque_offset_nm") {
                None => vec![0.0; n],
                Some(_) => joints(v, "torque_offset_nm", n)?,
            },
            friction_deadband_rad_s: finite(
                v.get("friction_deadband_rad_s"),
                "friction_deadband_rad_s",
            )?,
            friction_compensation: finite(v.get("friction_compensation"), "friction_compensation")?,
            wall_stiffness_nm_per_rad: finite(
                v.get("wall_stiffness_nm_per_rad"),
                "wall_stiffness_nm_per_rad",
            )?,
            damping_nm_s_per_rad: joints(v, "damping_nm_s_per_rad", n)?,
            lower_rad: joints(v, "lower_rad", n)?,
            upper_rad: joints(v, "upper_rad", n)?,
            friction_ramp_factor: finite(v.get("friction_ramp_factor"), "friction_ramp_factor")?,
            command_delay_cycles: count(v, "command_delay_cycles")?,
            inertia_compensation: finite(v.get("inertia_compensation"), "inertia_compensation")?,
            inertia_compensation_hz: finite(
                v.get("inertia_compensation_hz"),
                "inertia_compensation_hz",
            )?,
            max_tool_speed_m_s: finite(v.get("max_tool_speed_m_s"), "max_tool_speed_m_s")?,
            speed_feedback_gain: finite(v.get("speed_feedback_gain"), "speed_feedback_gain")?,
            inertia_step_rad: finite(v.get("inertia_step_rad"), "inertia_step_rad")?,
            speed_jacobian_step_rad: finite(
                v.get("speed_jacobian_step_rad"),
                "speed_jacobian_step_rad",
            )?,
            friction_level_speeds_rad_s: vector(
                v.get("friction_level_speeds_rad_s"),
                "friction_level_speeds_rad_s",
            )?,
            nominal_pressures_bar: vector(v.get("nominal_pressures_bar"), "nominal_pressures_bar")?,
            tool_in_6_m: [tool[0], tool[1], tool[2]],
            drive_servo_rate_hz: finite(v.get("drive_servo_rate_hz"), "drive_servo_rate_hz")?,
            dither_nm: dither,
            stiction_dither: optional(v, "stiction_dither")?,
            stiction_dither_hz: optional(v, "stiction_dither_hz")?,
            stiction_dither_hold_s: optional(v, "stiction_dither_hold_s")?,
            drive_model,
            guide,
            guide_mode,
        };
        if !(0.0..1.0).contains(&s.stiction_dither) {
            return Err(format!(
                "stiction_dither: {} is not a share of the friction level in [0, 1)",
                s.stiction_dither
            ));
        }
        if s.stiction_dither > 0.0 && !(s.stiction_dither_hz > 0.0) {
            return Err(format!(
                "stiction_dither_hz: {} Hz; a dither needs a frequency > 0",
                s.stiction_dither_hz
            ));
        }
        Ok(s)
    }

    /// The law needs the nominal rigid body (M(q), the tool's Jacobian).
    pub fn needs_chain(&self) -> bool {
        self.guide_mode != GuideMode::Free
            || self.command_delay_cycles > 0
            || self.max_tool_speed_m_s > 0.0
            || self.friction_ramp_factor != 0.0
            || self.inertia_compensation != 0.0
    }

    /// The law needs each joint's friction level (the ramps, the stiction dither).
    fn needs_friction_level(&self) -> bool {
        self.friction_ramp_factor != 0.0 || self.stiction_dither > 0.0
    }
}

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

/// Python's `round` (half to even) of a float to an integer.
fn round_even(x: f64) -> i64 {
    x.round_ties_even() as i64
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

    /// M(q)⁻¹ and M(q) of the nominal rigid body with rotor inertias, recomputed once a joint
    /// has moved more than `inertia_step_rad` since the last time.
    pub fn refresh_inertia(
        &mut self,
        chain: &Chain,
        work: &mut Work,
        q: &[f64],
    ) -> Result<(), String> {
        let n = self.n();
        let stale = match &self.m_at {
            None => true,
            Some(at) => max_abs_diff(q, &at[..n]) > self.s.inertia_step_rad,
        };
        if stale {
            chain.mass_matrix(q, true, work, &mut self.m[..n * n]);
            invert(&self.m, n, &mut self.m_inv)?;
            let mut at = [0.0; MAX_JOINTS];
            at[..n].copy_from_slice(q);
            self.m_at = Some(at);
        }
        Ok(())
    }

    /// M(q)⁻¹ as last refreshed (n × n row-major).
    pub fn m_inv(&self) -> &[f64] {
        let n = self.n();
        &self.m_inv[..n * n]
    }

    /// M(q) as last refreshed (n × n row-major).
    pub fn m(&self) -> &[f64] {
        let n = self.n();
        &self.m[..n * n]
    }

    /// The tool point's and the flange's linear velocity Jacobians (6 × n, world axes),
    /// recomputed once a joint has moved `speed_jacobian_step_rad`. The flange sits `r = R p`
    /// behind the tool point (p the tool point in the link-6 frame), so `v_flange = v_tool -
    /// ω × r = (J_v + [r]× J_ω) dq`.
    pub fn refresh_speed_jacobians(&mut self, chain: &Chain, work: &mut Work, q: &[f64]) {
        let n = self.n();
        let stale = match &self.jac_at {
            None => true,
            Some(at) => max_abs_diff(q, &at[..n]) > self.s.speed_jacobian_step_rad,
        };
        if !stale {
            return;
        }
        let mut jac = [0.0; 6 * MAX_JOINTS];
        let pose = chain.tool_jacobian(q, work, &mut jac[..6 * n]);
        let p = self.s.tool_in_6_m;
        let r: [f64; 3] = std::array::from_fn(|i| {
            // numpy's R @ p: ((R[i,0] p0 + R[i,1] p1) + R[i,2] p2)
            pose.r[i][0] * p[0] + pose.r[i][1] * p[1] + pose.r[i][2] * p[2]
        });
        let skew = [[0.0, -r[2], r[1]], [r[2], 0.0, -r[0]], [-r[1], r[0], 0.0]];
        for k in 0..n {
            for i in 0..3 {
                self.jac[i * n + k] = jac[i * n + k];
                let mut w = 0.0;
                for (m, s) in skew[i].iter().enumerate() {
                    w += s * jac[(3 + m) * n + k];
                }
                self.jac[(3 + i) * n + k] = jac[i * n + k] + w;
            }
        }
        let mut at = [0.0; MAX_JOINTS];
        at[..n].copy_from_slice(q);
        self.jac_at = Some(at);
    }

    /// The faster of the tool point and the flange at (q, dq) [m/s].
    pub fn point_speed(&mut self, chain: &Chain, work: &mut Work, q: &[f64], dq: &[f64]) -> f64 {
        self.refresh_speed_jacobians(chain, work, q);
        let n = self.n();
        let mut v = [0.0; 6];
        for (i, vi) in v.iter_mut().enumerate() {
            let mut s = 0.0;
            for k in 0..n {
                s += self.jac[i * n + k] * dq[k];
            }
            *vi = s;
        }
        let tool = py_hypot3(v[0], v[1], v[2]);
        let flange = py_hypot3(v[3], v[4], v[5]);
        // Python's max(a, b): b only if b > a (NaN a stays)
        if flange > tool {
            flange
        } else {
            tool
        }
    }

    /// The speed the commands are held to this cycle [m/s]: the limit, less
    /// `speed_feedback_gain` × what the arm's speed at (q, dq) exceeds it by (not below 0).
    pub fn speed_target(&mut self, chain: &Chain, work: &mut Work, q: &[f64], dq: &[f64]) -> f64 {
        let limit = self.s.max_tool_speed_m_s;
        let excess = self.point_speed(chain, work, q, dq) - limit;
        if excess.is_nan() || excess <= 0.0 {
            return limit;
        }
        let t = limit - self.s.speed_feedback_gain * excess;
        if t > 0.0 {
            t
        } else {
            0.0
        }
    }

    /// The factor (≤ 1) on `dq` that keeps the tool point and the flange within this cycle's
    /// speed target.
    pub fn tool_speed_scale(
        &mut self,
        chain: &Chain,
        work: &mut Work,
        q: &[f64],
        dq: &[f64],
    ) -> f64 {
        let fastest = self.point_speed(chain, work, q, dq);
        let limit = self.speed_target;
        if fastest <= limit {
            1.0
        } else {
            limit / fastest
        }
    }

    /// `inertia_compensation` × M(q) q̈ [N·m] into `tau_inertia`: q̈ the difference of the
    /// measured velocities of consecutive states, low-passed at `inertia_compensation_hz`;
    /// after a gap it starts again from zero. M(q) as last refreshed.
    fn inertia_torque(&mut self, dq: &[f64], period_s: f64, consecutive: bool) {
        let n = self.n();
        match (&self.dq_last, consecutive) {
            (Some(last), true) => {
                let k = 1.0
                    - (-2.0 * std::f64::consts::PI * self.s.inertia_compensation_hz * period_s)
                        .exp();
                for j in 0..n {
                    self.ddq_f[j] += k * ((dq[j] - last[j]) / period_s - self.ddq_f[j]);
                }
            }
            _ => self.ddq_f[..n].fill(0.0),
        }
        let mut last = [0.0; MAX_JOINTS];
        last[..n].copy_from_slice(dq);
        self.dq_last = Some(last);
        for i in 0..n {
            let mut s = 0.0;
            for k in 0..n {
                s += self.m[i * n + k] * self.ddq_f[k];
            }
            self.tau_inertia[i] = self.s.inertia_compensation * s;
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

    /// Feed the cycle that just ended to the estimate and the loop's adaptation (eq. 28, or
    /// eqs. 28 and 30) if the drive followed the command that drove it as sent.
    fn cycle_regression(
        &mut self,
        parts: &mut Parts,
        st: &State,
        followed: bool,
        period_s: f64,
    ) -> Result<(), String> {
        let n = self.n();
        let prev = self.prev_state;
        let mut q_now = [0.0; MAX_JOINTS];
        let mut dq_now = [0.0; MAX_JOINTS];
        q_now[..n].copy_from_slice(st.q);
        dq_now[..n].copy_from_slice(st.dq);
        self.prev_state = Some((q_now, dq_now));
        let Some((q0, dq0)) = prev.filter(|_| followed) else {
            self.sent.clear();
            return Ok(());
        };
        if self.sent.len() < self.s.command_delay_cycles + 1 {
            return Ok(());
        }
        let (q_cmd, dq_cmd) = self.sent[0];
        let rate = self.s.drive_servo_rate_hz;
        let ticks = if rate != 0.0 {
            round_even(period_s * rate)
        } else {
            0
        };
        let cycle = inner_estimate::Cycle {
            q_cmd_rad: &q_cmd[..n],
            dq_cmd_rad_s: &dq_cmd[..n],
            q_start_rad: &q0[..n],
            q_end_rad: st.q,
            period_s,
            dq_start_end_rad_s: Some((&dq0[..n], st.dq)),
            ticks,
        };
        if let Some(est) = parts.inner.as_deref_mut() {
            est.update(&cycle, st.current_a, 0.02)?;
        }
        if !matches!(parts.outer.adaptation(), Adaptation::None) {
            let mut u1 = [0.0; MAX_JOINTS];
            let mut u2 = [0.0; MAX_JOINTS];
            cycle_means(&cycle, &mut u1[..n], &mut u2[..n])?;
            let mut tau_m = [0.0; MAX_JOINTS];
            self.motor_torque(st.current_a, &mut tau_m[..n]);
            parts.outer.adapt(&u1[..n], &u2[..n], &tau_m[..n], period_s);
        }
        Ok(())
    }

    fn regressing(&self, parts: &Parts) -> bool {
        parts.inner.is_some() || !matches!(parts.outer.adaptation(), Adaptation::None)
    }

    /// Engage: calibrate ω̂ from the hold, take over bumplessly from the command the robot
    /// follows now (the driver's hold), restart every piece's history.
    fn engage(&mut self, parts: &mut Parts, st: &State) -> Result<(), String> {
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

/// The length of (a, b, c) (Python's `math.hypot` to rounding).
fn py_hypot3(a: f64, b: f64, c: f64) -> f64 {
    (a * a + b * b + c * c).sqrt()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn invert_gives_the_inverse() {
        let a = [4.0, 1.0, 0.5, 1.0, 3.0, 0.2, 0.5, 0.2, 2.0];
        let mut inv = [0.0; 9];
        invert(&a, 3, &mut inv).unwrap();
        for i in 0..3 {
            for k in 0..3 {
                let mut s = 0.0;
                for m in 0..3 {
                    s += a[i * 3 + m] * inv[m * 3 + k];
                }
                let want = if i == k { 1.0 } else { 0.0 };
                assert!((s - want).abs() < 1e-14, "{i}{k}: {s}");
            }
        }
        assert!(invert(&[1.0, 2.0, 2.0, 4.0], 2, &mut inv).is_err());
    }

    #[test]
    fn python_round_is_half_to_even() {
        assert_eq!(round_even(2.5), 2);
        assert_eq!(round_even(3.5), 4);
        assert_eq!(round_even(8.0), 8);
    }
}
