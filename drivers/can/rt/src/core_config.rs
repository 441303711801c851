//! The part of the `[can]` section the host core uses (drivers/can/config.py
//! `CanDriverConfig`), read from the JSON of `dataclasses.asdict(CanDriverConfig)`.
//!
//! Python validated the section when it loaded it; [`CoreConfig::from_json`] checks again
//! every value the core relies on (the same bounds as `CanDriverConfig.__post_init__`), so a
//! JSON that did not come from there cannot make the cycle divide by zero or index past a
//! joint. Errors name the key: `[can].deadline_s: ...`.

use serde_json::Value;

use crate::adapter::MAX_JOINTS;

/// How a lost cycle is answered (`[can] lost_cycle_answer`, lost_cycles.py).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum LostCycleAnswer {
    /// "coast": the last forwarded command moved on by its own velocity while it answered one
    /// of the `coast_max_cycles` cycles before, then a hold.
    Coast,
    /// "hold": a hold set at once, never extrapolating.
    Hold,
}

impl LostCycleAnswer {
    /// The config's spelling.
    pub fn name(self) -> &'static str {
        match self {
            LostCycleAnswer::Coast => "coast",
            LostCycleAnswer::Hold => "hold",
        }
    }
}

/// What the host core needs of `[can]` (every duration in seconds; the field comments are
/// CanDriverConfig's, shortened).
#[derive(Clone, Debug, PartialEq)]
pub struct CoreConfig {
    /// Number of robot joints the driver reports and commands (1..=16).
    pub joints: usize,
    /// A JointCommand older than this is never forwarded; an unanswered cycle is answered at
    /// this age at the latest [s].
    pub deadline_s: f64,
    /// An unanswered cycle is answered this far into the controller's period at the latest [1].
    pub answer_by_period_fraction: f64,
    /// 0: a real controller. > 0: a lock-step virtual controller, which advances only when
    /// answered: the answer deadline and a command's age limit are this long instead [s].
    pub lockstep_answer_wait_s: f64,
    /// The gateway's lifecycle message counts as fresh for this long [s].
    pub lifecycle_timeout_s: f64,
    /// The Modbus driver's IoState counts as fresh for this long [s].
    pub io_timeout_s: f64,
    /// The controller link is up while a complete cycle arrived within this time [s].
    pub controller_timeout_s: f64,
    /// Period of the host heartbeat and of the repeated host request [s].
    pub heartbeat_period_s: f64,
    /// One StateWindow per this long [s].
    pub state_window_s: f64,
    /// Per joint: a command with |q_cmd − q| beyond this is rejected [rad].
    pub max_following_error_rad: Vec<f64>,
    /// Per joint: a command with |dq_cmd| beyond this is rejected [rad/s].
    pub max_velocity_rad_s: Vec<f64>,
    /// Cycles of the current sensors' zero window (0: off) [cycles].
    pub current_zero_cycles: usize,
    /// Cycles skipped after the servo power goes off before they count towards the zero.
    pub current_zero_settle_cycles: usize,
    /// Hand guiding's speed limit of the tool point and the flange; 0: no monitor [m/s].
    pub hand_guiding_max_speed_m_s: f64,
    /// A command closer than this to a joint's limit is rejected [rad].
    pub joint_limit_margin_rad: f64,
    /// Per joint: the controlled stop's deceleration [rad/s²].
    pub stop_deceleration_rad_s2: Vec<f64>,
    /// Monitored standstill: settling time [s], band [rad], cycles out of it in a row.
    pub standstill_settle_s: f64,
    pub standstill_band_rad: f64,
    pub standstill_confirm_cycles: usize,
    /// This many CAN error frames within `bus_error_window_s` latch a bus fault.
    pub bus_error_limit: usize,
    pub bus_error_window_s: f64,
    /// How a lost cycle is answered.
    pub lost_cycle_answer: LostCycleAnswer,
    /// A late cycle coasts only on the command forwarded for one of this many cycles before it.
    pub coast_max_cycles: i64,
    /// Lost-cycle trips: this many in a row, or per window (0 turns a rule off).
    pub lost_cycles_max_consecutive: usize,
    pub lost_cycles_max_per_window: usize,
    pub lost_cycles_window_s: f64,
    /// A cycle whose measured position moved faster than this is dropped; 0: off [rad/s].
    pub feedback_max_joint_speed_rad_s: f64,
}

impl Default for CoreConfig {
    /// CanDriverConfig's defaults, 6 joints.
    fn default() -> CoreConfig {
        let n = 6;
        CoreConfig {
            joints: n,
            deadline_s: 0.010,
            answer_by_period_fraction: 0.5,
            lockstep_answer_wait_s: 0.0,
            lifecycle_timeout_s: 0.25,
            io_timeout_s: 0.25,
            controller_timeout_s: 0.1,
            heartbeat_period_s: 0.1,
            state_window_s: 0.02,
            max_following_error_rad: vec![0.05; n],
            max_velocity_rad_s: vec![1.0; n],
            current_zero_cycles: 0,
            current_zero_settle_cycles: 5,
            hand_guiding_max_speed_m_s: 0.25,
            joint_limit_margin_rad: 0.01,
            stop_deceleration_rad_s2: vec![2.0; n],
            standstill_settle_s: 0.5,
            standstill_band_rad: 0.02,
            standstill_confirm_cycles: 3,
            bus_error_limit: 10,
            bus_error_window_s: 1.0,
            lost_cycle_answer: LostCycleAnswer::Coast,
            coast_max_cycles: 1,
            lost_cycles_max_consecutive: 50,
            lost_cycles_max_per_window: 100,
            lost_cycles_window_s: 2.0,
            feedback_max_joint_speed_rad_s: 10.0,
        }
    }
}

fn err(key: &str, message: impl std::fmt::Display) -> String {
    format!("[can].{key}: {message}")
}

fn get<'a>(obj: &'a serde_json::Map<String, Value>, key: &str) -> Result<&'a Value, String> {
    obj.get(key).ok_or_else(|| err(key, "missing"))
}

/// A finite number (a JSON integer counts; a boolean does not).
fn number(obj: &serde_json::Map<String, Value>, key: &str) -> Result<f64, String> {
    let v = get(obj, key)?;
    match v.as_f64() {
        Some(x) if x.is_finite() => Ok(x),
        _ => Err(err(key, format!("{v} is not a finite number"))),
    }
}

/// A number in (lo, hi].
fn number_in(
    obj: &serde_json::Map<String, Value>,
    key: &str,
    lo: f64,
    hi: f64,
) -> Result<f64, String> {
    let x = number(obj, key)?;
    if lo < x && x <= hi {
        Ok(x)
    } else {
        Err(err(key, format!("{x} outside ({lo}, {hi}]")))
    }
}

/// A number in [lo, hi].
fn number_within(
    obj: &serde_json::Map<String, Value>,
    key: &str,
    lo: f64,
    hi: f64,
) -> Result<f64, String> {
    let x = number(obj, key)?;
    if lo <= x && x <= hi {
        Ok(x)
    } else {
        Err(err(key, format!("{x} outside {lo}..{hi}")))
    }
}

/// A whole number in lo..=hi (gateway/config.py require_count, with a lower bound).
fn count(obj: &serde_json::Map<String, Value>, key: &str, lo: u64, hi: u64) -> Result<u64, String> {
    let v = get(obj, key)?;
    match v.as_u64() {
        Some(x) if lo <= x && x <= hi => Ok(x),
        _ => Err(err(key, format!("{v} not a whole number in {lo}..{hi}"))),
    }
}

/// Per joint, or one number for every joint; each finite and > 0.
fn per_joint(
    obj: &serde_json::Map<String, Value>,
    key: &str,
    joints: usize,
) -> Result<Vec<f64>, String> {
    let v = get(obj, key)?;
    let values: Vec<f64> = match v {
        Value::Number(_) => vec![number(obj, key)?; joints],
        Value::Array(items) => {
            let mut out = Vec::with_capacity(items.len());
            for (k, item) in items.iter().enumerate() {
                match item.as_f64() {
                    Some(x) => out.push(x),
                    None => {
                        return Err(err(
                            &format!("{key}[{k}]"),
                            format!("{item} is not a number"),
                        ))
                    }
                }
            }
            out
        }
        _ => return Err(err(key, format!("{v} is neither a number nor a list"))),
    };
    if values.len() != joints {
        return Err(err(
            key,
            format!("has {} values for {joints} joints", values.len()),
        ));
    }
    for (k, x) in values.iter().enumerate() {
        if !(x.is_finite() && *x > 0.0) {
            return Err(err(
                &format!("{key}[{k}]"),
                format!("{x} must be finite and > 0"),
            ));
        }
    }
    Ok(values)
}

impl CoreConfig {
    /// The core's settings from the JSON object of `dataclasses.asdict(CanDriverConfig)`
    /// (keys the core does not use, like `transport` and `cia402`, are ignored). Err names
    /// the key that is missing or out of range.
    pub fn from_json(v: &Value) -> Result<CoreConfig, String> {
        let o = v
            .as_object()
            .ok_or_else(|| "[can]: the config must be a JSON object".to_string())?;
        let joints = count(o, "joints", 1, MAX_JOINTS as u64)? as usize;
        let lost_cycle_answer = match get(o, "lost_cycle_answer")?.as_str() {
            Some("coast") => LostCycleAnswer::Coast,
            Some("hold") => LostCycleAnswer::Hold,
            _ => {
                return Err(err(
                    "lost_cycle_answer",
                    format!("{} is neither 'coast' nor 'hold'", o["lost_cycle_answer"]),
                ))
            }
        };
        Ok(CoreConfig {
            joints,
            deadline_s: number_in(o, "deadline_s", 0.0, 0.1)?,
            answer_by_period_fraction: number_in(o, "answer_by_period_fraction", 0.0, 1.0)?,
            lockstep_answer_wait_s: number_within(o, "lockstep_answer_wait_s", 0.0, 0.2)?,
            lifecycle_timeout_s: number_in(o, "lifecycle_timeout_s", 0.0, 5.0)?,
            io_timeout_s: number_in(o, "io_timeout_s", 0.0, 5.0)?,
            controller_timeout_s: number_in(o, "controller_timeout_s", 0.0, 5.0)?,
            heartbeat_period_s: number_in(o, "heartbeat_period_s", 0.0, 1.0)?,
            state_window_s: number_in(o, "state_window_s", 0.0, 0.05)?,
            max_following_error_rad: per_joint(o, "max_following_error_rad", joints)?,
            max_velocity_rad_s: per_joint(o, "max_velocity_rad_s", joints)?,
            current_zero_cycles: count(o, "current_zero_cycles", 0, 100_000)? as usize,
            current_zero_settle_cycles: count(o, "current_zero_settle_cycles", 0, 100_000)?
                as usize,
            hand_guiding_max_speed_m_s: number_within(o, "hand_guiding_max_speed_m_s", 0.0, 1.0)?,
            joint_limit_margin_rad: number_within(o, "joint_limit_margin_rad", 0.0, 0.2)?,
            stop_deceleration_rad_s2: per_joint(o, "stop_deceleration_rad_s2", joints)?,
            standstill_settle_s: number_in(o, "standstill_settle_s", 0.0, 10.0)?,
            standstill_band_rad: number_in(o, "standstill_band_rad", 0.0, 0.5)?,
            standstill_confirm_cycles: count(o, "standstill_confirm_cycles", 1, 1000)? as usize,
            bus_error_limit: count(o, "bus_error_limit", 1, 10_000)? as usize,
            bus_error_window_s: number_in(o, "bus_error_window_s", 0.0, 60.0)?,
            lost_cycle_answer,
            coast_max_cycles: count(o, "coast_max_cycles", 1, 10)? as i64,
            lost_cycles_max_consecutive: count(o, "lost_cycles_max_consecutive", 0, 100_000)?
                as usize,
            lost_cycles_max_per_window: count(o, "lost_cycles_max_per_window", 0, 100_000)?
                as usize,
            lost_cycles_window_s: number_in(o, "lost_cycles_window_s", 0.0, 60.0)?,
            feedback_max_joint_speed_rad_s: number_within(
                o,
                "feedback_max_joint_speed_rad_s",
                0.0,
                1000.0,
            )?,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use serde_json::json;

    /// `dataclasses.asdict(CanDriverConfig(transport=...))` as Python writes it.
    fn asdict() -> Value {
        json!({"adapter": "ltc_dbc", "joints": 6, "transport": {"interface": "virtual", "channel": "x"},
            "deadline_s": 0.01, "answer_by_period_fraction": 0.5, "lockstep_answer_wait_s": 0.0, "lifecycle_timeout_s": 0.25,
            "io_timeout_s": 0.25, "controller_timeout_s": 0.1, "heartbeat_period_s": 0.1,
            "state_window_s": 0.02, "max_following_error_rad": [0.05, 0.05, 0.05, 0.05, 0.05, 0.05],
            "max_velocity_rad_s": [1.0, 1.0, 1.0, 1.0, 1.0, 1.0], "current_zero_cycles": 0,
            "current_zero_settle_cycles": 5, "current_zero_file": "", "hand_guiding_max_speed_m_s": 0.25,
            "joint_limit_margin_rad": 0.01, "stop_deceleration_rad_s2": [2.0, 2.0, 2.0, 2.0, 2.0, 2.0],
            "standstill_settle_s": 0.5, "standstill_band_rad": 0.02, "standstill_confirm_cycles": 3,
            "bus_error_limit": 10, "bus_error_window_s": 1.0, "lost_cycle_answer": "coast",
            "coast_max_cycles": 1, "lost_cycles_max_consecutive": 50, "lost_cycles_max_per_window": 100,
            "lost_cycles_window_s": 2.0, "feedback_max_joint_speed_rad_s": 10.0,
            "cia402": {"eds": "", "node_ids": [], "host_node_id": 127}})
    }

    #[test]
    fn core_config_reads_pythons_asdict_and_equals_the_defaults() {
        assert_eq!(
            CoreConfig::from_json(&asdict()).unwrap(),
            CoreConfig::default()
        );
    }

    #[test]
    fn core_config_errors_name_the_key() {
        let mut v = asdict();
        v.as_object_mut().unwrap().remove("deadline_s");
        assert!(CoreConfig::from_json(&v)
            .unwrap_err()
            .starts_with("[can].deadline_s: missing"));
        let mut v = asdict();
        v["max_velocity_rad_s"] = json!([1.0, 1.0]);
        assert!(CoreConfig::from_json(&v)
            .unwrap_err()
            .contains("max_velocity_rad_s: has 2 values"));
        let mut v = asdict();
        v["stop_deceleration_rad_s2"] = json!(3.0); // one number for all
        assert_eq!(
            CoreConfig::from_json(&v).unwrap().stop_deceleration_rad_s2,
            vec![3.0; 6]
        );
        v["max_following_error_rad"] = json!([0.05, 0.05, 0.0, 0.05, 0.05, 0.05]);
        assert!(CoreConfig::from_json(&v)
            .unwrap_err()
            .contains("max_following_error_rad[2]"));
        let mut v = asdict();
        v["lost_cycle_answer"] = json!("brake");
        assert!(CoreConfig::from_json(&v)
            .unwrap_err()
            .contains("lost_cycle_answer"));
        let mut v = asdict();
        v["joints"] = json!(17);
        assert!(CoreConfig::from_json(&v)
            .unwrap_err()
            .contains("[can].joints"));
        let mut v = asdict();
        v["coast_max_cycles"] = json!(true);
        assert!(CoreConfig::from_json(&v)
            .unwrap_err()
            .contains("coast_max_cycles"));
        assert!(CoreConfig::from_json(&json!([1])).is_err());
    }
}
