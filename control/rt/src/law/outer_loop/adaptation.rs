//! Which law adapts the outer loop's gains, and its settings (outer_loop.rs): eq. (28) alone
//! ([`OmegaAdaptation`]) or the paper's eqs. (28) and (30) together ([`PaperAdaptation`]),
//! each checked for the joint count as the Python it replaced checked it.

/// Settings of eq. (28) alone: ω̂ on `τ̂ = (u₁ + Υ̂_I u₂) / ω̂`.
#[derive(Clone, Debug, PartialEq)]
pub struct OmegaAdaptation {
    /// γ: how fast ω̂ converges [1/s]
    pub rate_per_s: f64,
    /// per joint: no adaptation while |τ̂| is below this [N·m]
    pub min_torque_nm: Vec<f64>,
}

impl OmegaAdaptation {
    /// The settings are usable for `n` joints: a rate >= 0, n torque floors > 0.
    pub fn check(&self, n: usize) -> Result<(), String> {
        if !(self.rate_per_s.is_finite() && self.rate_per_s >= 0.0) {
            return Err(format!(
                "adaptation rate {} must be >= 0",
                py_float(self.rate_per_s)
            ));
        }
        if self.min_torque_nm.len() != n || !self.min_torque_nm.iter().all(|&v| v > 0.0) {
            return Err(format!("adaptation min_torque_nm needs {n} values > 0"));
        }
        Ok(())
    }
}

/// Settings of eqs. (28) and (30) together (law/outer_loop.rs, "The paper's laws").
#[derive(Clone, Debug, PartialEq)]
pub struct PaperAdaptation {
    /// γ: how fast the estimates converge [1/s] (the paper's Λ, normalised)
    pub rate_per_s: f64,
    /// per joint: no adaptation while |φ| is below this [N·m]
    pub min_torque_nm: Vec<f64>,
    /// Λ_I / Λ (the paper: 0.02 / 0.01)
    pub upsilon_ratio: f64,
    /// per joint: the dead zone's floor on |τ_m - τ̂| [N·m]; empty: none
    pub dead_zone_nm: Vec<f64>,
    /// ω̂ and Υ̂_I stay within this factor of where they started
    pub bound_factor: f64,
}

impl PaperAdaptation {
    /// The paper's ratio Λ_I / Λ = 0.02 / 0.01.
    pub const UPSILON_RATIO: f64 = 2.0;
    /// The default bound on ω̂ and Υ̂_I either side of where they started.
    pub const BOUND_FACTOR: f64 = 50.0;

    /// The settings are usable for `n` joints ([`OmegaAdaptation::check`], a ratio >= 0, no
    /// or n dead zones >= 0, a bound factor > 1).
    pub fn check(&self, n: usize) -> Result<(), String> {
        OmegaAdaptation {
            rate_per_s: self.rate_per_s,
            min_torque_nm: self.min_torque_nm.clone(),
        }
        .check(n)?;
        if !(self.upsilon_ratio.is_finite() && self.upsilon_ratio >= 0.0) {
            return Err(format!(
                "adaptation upsilon_ratio {} must be >= 0",
                py_float(self.upsilon_ratio)
            ));
        }
        let zones = &self.dead_zone_nm;
        if !zones.is_empty() && (zones.len() != n || !zones.iter().all(|&v| v >= 0.0)) {
            return Err(format!("adaptation dead_zone_nm needs {n} values >= 0"));
        }
        if !(self.bound_factor.is_finite() && self.bound_factor > 1.0) {
            return Err(format!(
                "adaptation bound_factor {} must be > 1",
                py_float(self.bound_factor)
            ));
        }
        Ok(())
    }
}

/// Which of the laws adapts the loop's gains, if any.
#[derive(Clone, Debug, PartialEq)]
pub enum Adaptation {
    None,
    Omega(OmegaAdaptation),
    Paper(PaperAdaptation),
}

impl Adaptation {
    /// The per-joint torque floor [N·m], where an adaptation is set.
    pub(super) fn min_torque_nm(&self) -> Option<&[f64]> {
        match self {
            Adaptation::None => None,
            Adaptation::Omega(a) => Some(&a.min_torque_nm),
            Adaptation::Paper(a) => Some(&a.min_torque_nm),
        }
    }
}

/// A float as Python's `str` writes it in the messages (`1.0`, `nan`, `-inf`).
fn py_float(x: f64) -> String {
    if x.is_nan() {
        "nan".into()
    } else if x.is_infinite() {
        if x > 0.0 { "inf" } else { "-inf" }.into()
    } else if x == x.trunc() && x.abs() < 1e16 {
        format!("{x:.1}")
    } else {
        format!("{x}")
    }
}
