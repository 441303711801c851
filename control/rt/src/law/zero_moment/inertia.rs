//! The nominal rigid body's inertia in the zero-moment law (zero_moment.rs): M(q) and its
//! inverse, refreshed once a joint has moved far enough, for the delay predictor and the
//! friction ramps, and the inertia compensation's torque M(q) q̈.

use super::{invert, max_abs_diff, ZeroMoment};
use crate::chain::{Chain, Work, MAX_JOINTS};

impl ZeroMoment {
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

    /// `inertia_compensation` × M(q) q̈ [N·m] into `tau_inertia`: q̈ the difference of the
    /// measured velocities of consecutive states, low-passed at `inertia_compensation_hz`;
    /// after a gap it starts again from zero. M(q) as last refreshed.
    pub(super) fn inertia_torque(&mut self, dq: &[f64], period_s: f64, consecutive: bool) {
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
}
