//! The zero-moment law's settings (zero_moment.rs), read from the JSON
//! control/zero_moment_law.py writes: the cell config's [control] and the robot's datasheet,
//! each checked as it is read.

use serde_json::Value;

use crate::chain::MAX_JOINTS;
use crate::law::guide::{GuideMode, GuideSettings};
use crate::table::{finite, vector};

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
    pub(super) fn needs_friction_level(&self) -> bool {
        self.friction_ramp_factor != 0.0 || self.stiction_dither > 0.0
    }
}
