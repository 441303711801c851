//! The admittance's M̂ (cycle.rs): the identified model's inertia matrix, computed off the
//! cycle and handed in, or the nominal chain's, and when it is due again.

#![allow(clippy::needless_range_loop)] // per-joint arithmetic reads as the formulas

use super::{AdmittanceCycle, Joints};
use crate::chain::MAX_JOINTS;
use crate::law::zero_moment::{Parts, ZeroMoment};

impl AdmittanceCycle {
    /// M̂ at `q_at` (row-major n × n), computed off the cycle. Err unless finite and sized.
    pub fn set_mass(&mut self, q_at: &[f64], mass: &[f64]) -> Result<(), String> {
        let n = self.n;
        if q_at.len() != n || mass.len() != n * n {
            return Err(format!(
                "admittance mass: needs {n} positions and {n} x {n} values"
            ));
        }
        if !q_at.iter().chain(mass).all(|v| v.is_finite()) {
            return Err("admittance mass: a value is not finite".into());
        }
        self.mass[..n * n].copy_from_slice(mass);
        let mut at = [0.0; MAX_JOINTS];
        at[..n].copy_from_slice(q_at);
        self.mass_at = Some(at);
        Ok(())
    }

    /// Where M̂ should be computed again (the reference `q_r`, when the law has no M̂ of the
    /// identified model within [`Settings::inertia_step_rad`] of it), or None.
    pub fn mass_wanted(&self, q_r: &[f64]) -> Option<Joints> {
        if !self.s.identified_mass {
            return None;
        }
        let stale = match &self.mass_at {
            None => true,
            Some(at) => {
                let mut far = false;
                for j in 0..self.n {
                    let d = (q_r[j] - at[j]).abs();
                    far |= d.is_nan() || d > self.s.inertia_step_rad;
                }
                far
            }
        };
        stale.then(|| {
            let mut at = [0.0; MAX_JOINTS];
            at[..self.n].copy_from_slice(&q_r[..self.n]);
            at
        })
    }

    /// M̂ at `q` into `m`: the identified model's as handed in (the newest, wherever it was
    /// computed), else the nominal chain's with rotor inertias (cached by the zero-moment law).
    pub fn mass_at(
        &self,
        zm: &mut ZeroMoment,
        parts: &mut Parts,
        q: &[f64],
        m: &mut [f64],
    ) -> Result<(), String> {
        let n = self.n;
        if self.s.identified_mass && self.mass_at.is_some() {
            m[..n * n].copy_from_slice(&self.mass[..n * n]);
            return Ok(());
        }
        let (chain, work) = parts
            .chain
            .as_mut()
            .ok_or_else(|| "the admittance needs the nominal chain for M(q)".to_string())?;
        zm.refresh_inertia(chain, work, q)?;
        m[..n * n].copy_from_slice(zm.m());
        Ok(())
    }
}
