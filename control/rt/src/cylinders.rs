//! The assist cylinders' joint torques, eqs. (10) and (12) of the paper (control/model/
//! cylinders.py `CylinderTorques`, whose constants the table carries).

use serde_json::Value;

use crate::table::{finite, joint};

/// 1 bar in pascal.
const BAR_TO_PA: f64 = 1e5;

#[derive(Clone, Debug)]
pub struct Cylinder {
    pub joint: usize,
    /// J2's crank (eq. 10); otherwise J3's lever (eq. 12).
    pub crank: bool,
    pub ab_m: f64,
    pub ac_m: f64,
    /// Piston area × |AB| (× |AC| for the crank) [m³ or m⁴].
    pub lever: f64,
    /// +1 or −1: the equation's torque on the joint's positive direction.
    pub sign: f64,
}

impl Cylinder {
    pub fn from_json(v: &Value, n: usize, what: &str) -> Result<Cylinder, String> {
        let sign = finite(v.get("sign"), &format!("{what}.sign"))?;
        if sign != 1.0 && sign != -1.0 {
            return Err(format!("{what}.sign must be 1 or -1"));
        }
        Ok(Cylinder {
            joint: joint(v.get("joint"), n, &format!("{what}.joint"))?,
            crank: v
                .get("crank")
                .and_then(Value::as_bool)
                .ok_or_else(|| format!("{what}.crank must be true or false"))?,
            ab_m: finite(v.get("ab_m"), &format!("{what}.ab_m"))?,
            ac_m: finite(v.get("ac_m"), &format!("{what}.ac_m"))?,
            lever: finite(v.get("lever"), &format!("{what}.lever"))?,
            sign,
        })
    }

    /// The torque [N·m] on its joint at the joint's angle `q` [rad] and pressure `p` [bar].
    pub fn torque(&self, q: f64, p_bar: f64) -> f64 {
        let gain = if self.crank {
            let phi = std::f64::consts::PI - q; // ∠B2A2C2 of eqs. (4)-(8)
            let (ab, ac) = (self.ab_m, self.ac_m);
            let bc = (ab * ab + ac * ac - 2.0 * ab * ac * phi.cos()).sqrt(); // eq. (5)
            self.lever * phi.sin() / bc // eq. (10) / P2
        } else {
            self.lever * q.cos() // eq. (12) / P3
        };
        self.sign * gain * p_bar * BAR_TO_PA
    }
}
