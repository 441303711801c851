//! One joint's friction at one state, for each family the identification fits: the compiled
//! form of control/identification/friction_law.py `friction_basis` and control/model/friction.py
//! eq. 15 at a single state, equal to them to rounding (tests/unit/test_control_rt_model.py).

use serde_json::Value;

use crate::table::{finite, numbers};

/// `np.sign`: 0 at 0, NaN stays NaN.
pub fn sign(x: f64) -> f64 {
    if x > 0.0 {
        1.0
    } else if x < 0.0 {
        -1.0
    } else {
        x // 0.0, -0.0 or NaN
    }
}

#[derive(Clone, Debug)]
pub enum Friction {
    /// Eq. (15) as read by control/model/friction.py: the ten coefficients, then 1/(2 q_sgn),
    /// 1/q_e, 1/R (`eq15_row`).
    Eq15([f64; 13]),
    /// Eq. (14): f1..f4 position terms, Coulomb, Stribeck, viscous; q_e.
    Eq14([f64; 7], f64),
    /// `tc tanh(dq / 2 q_e) + tv dq + offset`; q_e.
    Simple([f64; 3], f64),
    /// A joint fitted plainly: `coulomb sign(dq) + viscous dq + offset`.
    Plain([f64; 3]),
}

impl Friction {
    pub fn from_json(v: &Value, what: &str) -> Result<Friction, String> {
        let kind = v.get("kind").and_then(Value::as_str);
        let coef = |k: &str| format!("{what}.{k}");
        match kind {
            Some("eq15") => Ok(Friction::Eq15(numbers(v.get("row"), &coef("row"))?)),
            Some("eq14") => Ok(Friction::Eq14(
                numbers(v.get("coef"), &coef("coef"))?,
                positive(v.get("q_e_rad_s"), &coef("q_e_rad_s"))?,
            )),
            Some("simple") => Ok(Friction::Simple(
                numbers(v.get("coef"), &coef("coef"))?,
                positive(v.get("q_e_rad_s"), &coef("q_e_rad_s"))?,
            )),
            Some("plain") => Ok(Friction::Plain(numbers(v.get("coef"), &coef("coef"))?)),
            _ => Err(format!("{what}.kind must be eq15, eq14, simple or plain")),
        }
    }

    /// The torque [N·m] at `q` [rad], `dq` [rad/s] (already clipped to the envelope).
    pub fn torque(&self, q: f64, dq: f64) -> f64 {
        match self {
            Friction::Eq15(r) => {
                let [ts, tc, f1, f2, f3, f4, f5, f6, v1, v2, half_inv_sign, inv_qe, inv_r] = *r;
                let s = (dq * half_inv_sign).tanh();
                let qr = q * inv_r;
                let coulomb_like = ts * (-dq.abs() * inv_qe).exp()
                    + tc
                    + f1 * qr.sin()
                    + f2 * qr.cos()
                    + f3 * (2.0 * qr).sin()
                    + f4 * (2.0 * qr).cos()
                    + f5 * q.sin()
                    + f6 * q.cos();
                coulomb_like * s + (v1 * dq + v2 * dq * dq.abs())
            }
            Friction::Eq14([f1, f2, f3, f4, fc, fs, fv], qe) => {
                let sgn = sign(dq);
                f1 * q.sin()
                    + f2 * q.cos()
                    + f3 * (2.0 * q).sin()
                    + f4 * (2.0 * q).cos()
                    + fc * sgn
                    + fs * (-dq.abs() / qe).exp() * sgn
                    + fv * dq
            }
            Friction::Simple([tc, tv, off], qe) => tc * (dq / (2.0 * qe)).tanh() + tv * dq + off,
            Friction::Plain([c, v, o]) => c * sign(dq) + v * dq + o,
        }
    }
}

fn positive(v: Option<&Value>, what: &str) -> Result<f64, String> {
    let x = finite(v, what)?;
    if x > 0.0 {
        Ok(x)
    } else {
        Err(format!("{what} must be > 0"))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use serde_json::json;

    #[test]
    fn each_family_gives_its_formula() {
        let simple = Friction::from_json(
            &json!({"kind": "simple", "coef": [2.0, 0.5, 0.1], "q_e_rad_s": 0.02}),
            "f",
        )
        .unwrap();
        let want = 2.0 * (0.3f64 / 0.04).tanh() + 0.5 * 0.3 + 0.1;
        assert!((simple.torque(1.0, 0.3) - want).abs() < 1e-15);
        let plain = Friction::Plain([3.0, 1.0, -0.2]);
        assert_eq!(plain.torque(0.0, -0.5), -3.0 - 0.5 - 0.2);
        assert_eq!(plain.torque(0.0, 0.0), -0.2, "no Coulomb at rest");
        assert!(plain.torque(0.0, f64::NAN).is_nan());
        // eq. (15) with only τ_c and τ_s: (τ_s e^{-|dq|/q_e} + τ_c) tanh(dq / 2 q_sgn)
        let mut row = [0.0; 13];
        row[0] = 4.0;
        row[1] = 10.0;
        row[10] = 1.0 / (2.0 * 0.01);
        row[11] = 1.0 / 0.05;
        row[12] = 1.0 / 100.0;
        let eq15 = Friction::Eq15(row);
        let want = (4.0 * (-0.1f64 / 0.05).exp() + 10.0) * (0.1f64 / 0.02).tanh();
        assert!((eq15.torque(0.7, 0.1) - want).abs() < 1e-12);
    }

    #[test]
    fn a_bad_entry_is_refused_naming_it() {
        let e = Friction::from_json(
            &json!({"kind": "eq14", "coef": [1.0], "q_e_rad_s": 1.0}),
            "friction[2]",
        );
        assert!(e.unwrap_err().contains("friction[2].coef"));
        let e = Friction::from_json(
            &json!({"kind": "simple", "coef": [1.0, 2.0, 3.0], "q_e_rad_s": 0.0}),
            "friction[0]",
        );
        assert!(e.unwrap_err().contains("friction[0].q_e_rad_s must be > 0"));
        let e = Friction::from_json(&json!({"kind": "lugre"}), "friction[1]");
        assert!(e.unwrap_err().contains("friction[1].kind"));
    }
}
