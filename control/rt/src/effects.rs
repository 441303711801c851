//! The identified effects that act at run time, one joint each (control/identification/
//! terms.py; `payload` is part of the rigid weights, `time_delay` and `thermal_drift` have no
//! run-time torque): the compiled form of control/identification/point.py `_effect_fn`.

use serde_json::Value;

use crate::friction::sign;
use crate::table::{finite, joint, numbers};

#[derive(Clone, Debug)]
pub enum Kind {
    /// `a sin(cpr q) + b cos(cpr q)` (unclipped q).
    PositionRipple { cycles_per_rev: f64, a: f64, b: f64 },
    /// `k q + b` (unclipped: a spring's physics).
    Spring { k: f64, b: f64 },
    /// `a exp(−(dq/v)²) sign(dq)`, dq clipped.
    Stribeck { velocity: f64, a: f64 },
    /// `a |rigid_j| sign(dq)`, dq clipped.
    LoadDependentFriction { a: f64 },
    /// `a friction_k`, or `a (rigid_k + friction_k)`.
    WristCoupling {
        from: usize,
        with_rigid: bool,
        a: f64,
    },
}

#[derive(Clone, Debug)]
pub struct Effect {
    pub joint: usize,
    pub kind: Kind,
}

impl Effect {
    pub fn from_json(v: &Value, n: usize, what: &str) -> Result<Effect, String> {
        let j = joint(v.get("joint"), n, &format!("{what}.joint"))?;
        let name = v.get("name").and_then(Value::as_str).unwrap_or("");
        let coef = |what_c: &str| format!("{what}.{what_c}");
        let kind = match name {
            "position_ripple" => {
                let [a, b] = numbers(v.get("coef"), &coef("coef"))?;
                let cycles_per_rev = finite(v.get("cycles_per_rev"), &coef("cycles_per_rev"))?;
                Kind::PositionRipple {
                    cycles_per_rev,
                    a,
                    b,
                }
            }
            "spring" => {
                let [k, b] = numbers(v.get("coef"), &coef("coef"))?;
                Kind::Spring { k, b }
            }
            "stribeck" => {
                let [a] = numbers(v.get("coef"), &coef("coef"))?;
                let velocity = finite(v.get("velocity_rad_s"), &coef("velocity_rad_s"))?;
                if velocity == 0.0 {
                    return Err(format!("{what}.velocity_rad_s must not be 0"));
                }
                Kind::Stribeck { velocity, a }
            }
            "load_dependent_friction" => {
                let [a] = numbers(v.get("coef"), &coef("coef"))?;
                Kind::LoadDependentFriction { a }
            }
            "wrist_coupling" => {
                let [a] = numbers(v.get("coef"), &coef("coef"))?;
                let from = joint(v.get("from_joint"), n, &coef("from_joint"))?;
                let with_rigid = match v.get("source").and_then(Value::as_str) {
                    Some("friction") => false,
                    Some("torque") => true,
                    _ => return Err(format!("{what}.source must be friction or torque")),
                };
                Kind::WristCoupling {
                    from,
                    with_rigid,
                    a,
                }
            }
            other => {
                return Err(format!(
                    "{what}: effect {other:?} cannot be evaluated per cycle"
                ))
            }
        };
        Ok(Effect { joint: j, kind })
    }

    /// The effect's torque on its joint [N·m]: `q`, `dq` as measured, `dq_clipped` its joint's
    /// velocity clipped to the envelope, `rigid` and `friction` the model's per-joint parts.
    pub fn torque(&self, q: &[f64], dq_clipped: f64, rigid: &[f64], friction: &[f64]) -> f64 {
        let j = self.joint;
        match self.kind {
            Kind::PositionRipple {
                cycles_per_rev,
                a,
                b,
            } => {
                let x = cycles_per_rev * q[j];
                a * x.sin() + b * x.cos()
            }
            Kind::Spring { k, b } => k * q[j] + b,
            Kind::Stribeck { velocity, a } => {
                let d = dq_clipped;
                a * ((-((d / velocity) * (d / velocity))).exp() * sign(d))
            }
            Kind::LoadDependentFriction { a } => a * (rigid[j].abs() * sign(dq_clipped)),
            Kind::WristCoupling {
                from,
                with_rigid,
                a,
            } => {
                if with_rigid {
                    a * (rigid[from] + friction[from])
                } else {
                    a * friction[from]
                }
            }
        }
    }
}
