//! Online estimate of the vendor's inner-loop gains from the measured motor current.
//!
//! Eq. (19) is the drive's current command, `i = K_p (dq_c - dq) + K_I (q_c - q)`, and the drive
//! reports its current averaged over each cycle (drivers/can/PROTOCOL.md §2.1). Over the cycle
//! that a command (q_cmd, dq_cmd) drove, between the states at its start (q₀) and end (q₁), the
//! means are, with the controller's reference `q_cmd + dq_cmd (t - t_N)` (§5):
//!
//! ```text
//! mean(dq_c - dq) = dq_cmd - (q₁ - q₀)/T,
//! mean(q_c - q)   = q_cmd + dq_cmd T/2 - (q₀ + q₁)/2,
//! ```
//!
//! so every cycle the drive followed as sent is one linear equation in (K_p, K_I): eq. (26)'s
//! regressors for Δω and Δω_I written on the current (τ_d and q_c - q, since the outer loop
//! sets dq_c - dq = ω̂ τ_d - Υ̂_I (q_c - q)). Per joint, recursive least squares with exponential
//! forgetting (time constant `memory_s`) estimates `θ = (K_p/K_p0, K_I/K_I0, b)`, scaled by
//! the commissioned gains so the three unknowns are of order one, b a current offset the sensor
//! zero missed [A]. It starts at the commissioned values (θ = (1, 1, 0)) with a prior of
//! `prior_rel` relative standard deviation, which the forgetting lets go of: what it reports
//! after guided motion is measured, not told.
//!
//! The paper adapts ω̂ and ω̂_I with the gradient laws (28) and (30) on the same regressors; least
//! squares converges in a few seconds of motion where a gradient with the paper's Λ = 0.01 would
//! take minutes at our rate, and it gives its own uncertainty. Reported as ω̂ = 1/(K K̂_p) with
//! K the datasheet's torque constant (the product measures torque as K i, so that is the ω̂ its
//! eq. (21) needs) and Υ̂_I = K̂_I / K̂_p. The control law keeps using its own ω̂ (eq. 28) and
//! the commissioned Υ_I; this estimate is telemetry and commissioning's check.
//!
//! **Excitation.** In zero-moment teaching the command offset q_c - q follows the slowly changing
//! desired torque, so dq_c - dq is small: on the virtual cell (seed 0, 20 s of raster teaching) the
//! K_p term of the current was 0.001-0.09 A against 0.02 A of noise while the K_I term was
//! 0.07-1.4 A, and K_p (hence ω̂ and Υ̂_I) was not observable on J1-J3 and J6. `[control]
//! inner_loop_dither_a` adds to the desired torque a sinusoid per joint (K times that current,
//! at 4.0 + 0.4 j Hz for joint j + 1, near the offset filter's corner Υ_I/2π ≈ 5 Hz, where the K_p
//! and K_I terms are of one size and 90° apart). With 0.03 A, after 25 s of raster teaching on
//! the virtual cell (seed 0), ω̂ and Υ̂_I were within 1.8 % of the plant's on J3-J6 and 6.7 % on
//! J1-J2, where K_p reads ~6 % low (a bias not yet traced: with the true gains the regression's
//! residual is at the current's noise, 0.025 A). A white dither at the cycle rate excited the
//! zero-moment loop itself and a velocity dither made it shake.
//!
//! The arithmetic follows numpy's to the rounding: a 3-term dot product is summed as numpy's
//! `einsum` sums it on two SIMD lanes, `(x₀y₀ + x₂y₂) + x₁y₁`.

use crate::chain::MAX_JOINTS;

/// A joint's cycle is an outlier beyond this many standard deviations of its prediction.
pub const REJECT_SIGMA: f64 = 5.0;

/// One control cycle: the command that drove it and the measured states around it.
#[derive(Clone, Copy, Debug)]
pub struct Cycle<'a> {
    /// The command (q_cmd [rad], dq_cmd [rad/s]) that drove the cycle.
    pub q_cmd_rad: &'a [f64],
    pub dq_cmd_rad_s: &'a [f64],
    /// The measured positions at the cycle's start and end [rad].
    pub q_start_rad: &'a [f64],
    pub q_end_rad: &'a [f64],
    /// The cycle [s].
    pub period_s: f64,
    /// The measured velocities at the cycle's start and end [rad/s], if known.
    pub dq_start_end_rad_s: Option<(&'a [f64], &'a [f64])>,
    /// The drive's servo ticks per cycle (0: unknown).
    pub ticks: i64,
}

fn check_len(v: &[f64], n: usize, what: &str) -> Result<(), String> {
    if v.len() != n {
        return Err(format!("{what} needs {n} values, got {}", v.len()));
    }
    Ok(())
}

impl Cycle<'_> {
    /// Joint count: the command's length.
    pub fn n(&self) -> usize {
        self.q_cmd_rad.len()
    }

    /// Every per-joint argument has `n` values (the error names the argument).
    pub fn check(&self, n: usize) -> Result<(), String> {
        check_len(self.q_cmd_rad, n, "q_cmd")?;
        check_len(self.dq_cmd_rad_s, n, "dq_cmd")?;
        check_len(self.q_start_rad, n, "q_start")?;
        check_len(self.q_end_rad, n, "q_end")?;
        if let Some((dq0, dq1)) = self.dq_start_end_rad_s {
            check_len(dq0, n, "dq_start")?;
            check_len(dq1, n, "dq_end")?;
        }
        Ok(())
    }
}

/// `(u₁, u₂)` = (mean(dq_c - dq) [rad/s], mean(q_c - q) [rad]) per joint over the cycle the command
/// drove, from the measured positions at its start and end (module docstring); with the drive's
/// servo `ticks` per cycle and the measured velocities, the means its PI saw (it samples the state
/// at each tick's start). Non-finite inputs give non-finite means. `u1`, `u2` have the command's
/// length.
pub fn cycle_means(c: &Cycle, u1: &mut [f64], u2: &mut [f64]) -> Result<(), String> {
    let n = c.n();
    c.check(n)?;
    check_len(u1, n, "u1")?;
    check_len(u2, n, "u2")?;
    let t = c.period_s;
    let (qc, dqc, q0, q1) = (c.q_cmd_rad, c.dq_cmd_rad_s, c.q_start_rad, c.q_end_rad);
    match c.dq_start_end_rad_s {
        Some((dq0, dq1)) if c.ticks != 0 => {
            let ticks = c.ticks as f64;
            let two_ticks = 2.0 * ticks;
            let lag = 0.5 * t * (1.0 - 1.0 / ticks);
            for j in 0..n {
                u1[j] = (dqc[j] - (q1[j] - q0[j]) / t) - (dq0[j] - dq1[j]) / ticks;
                u2[j] = qc[j] + lag * dqc[j] - 0.5 * (q0[j] + q1[j]) + (q1[j] - q0[j]) / two_ticks;
            }
        }
        _ => {
            let half = 0.5 * t;
            for j in 0..n {
                u1[j] = dqc[j] - (q1[j] - q0[j]) / t;
                u2[j] = qc[j] + half * dqc[j] - 0.5 * (q0[j] + q1[j]);
            }
        }
    }
    Ok(())
}

/// `x · y` on three terms, summed as numpy's `einsum` does.
fn dot3(x: &[f64; 3], y: &[f64; 3]) -> f64 {
    (x[0] * y[0] + x[2] * y[2]) + x[1] * y[1]
}

/// Per-joint RLS on eq. (19) with exponential forgetting. Feed it one cycle at a time.
#[derive(Clone, Debug)]
pub struct InnerLoopEstimator {
    n: usize,
    kp0: [f64; MAX_JOINTS],
    ki0: [f64; MAX_JOINTS],
    k: [f64; MAX_JOINTS],
    memory_s: f64,
    /// `(K_p/K_p0, K_I/K_I0, b [A])` per joint.
    theta: [[f64; 3]; MAX_JOINTS],
    /// The RLS covariance per joint.
    p: [[[f64; 3]; 3]; MAX_JOINTS],
    /// Without excitation P grows as 1/λ^t: its gain part is capped at twice the prior's.
    cap: f64,
    updates: u64,
    /// Per joint, cycles whose residual was rejected as an outlier.
    rejected: [u64; MAX_JOINTS],
    seconds: f64,
    u1: [f64; MAX_JOINTS],
    u2: [f64; MAX_JOINTS],
}

impl InnerLoopEstimator {
    /// From the commissioned gains K_p0 [A·s/rad], K_I0 [A/rad] and the datasheet's torque
    /// constants K [N·m/A], one per joint; the forgetting's time constant `memory_s` [s] and
    /// the prior's relative standard deviation `prior_rel`.
    pub fn new(
        kp0_a_s_per_rad: &[f64],
        ki0_a_per_rad: &[f64],
        drive_gain_nm_per_a: &[f64],
        memory_s: f64,
        prior_rel: f64,
    ) -> Result<InnerLoopEstimator, String> {
        let n = kp0_a_s_per_rad.len();
        if ki0_a_per_rad.len() != n || drive_gain_nm_per_a.len() != n {
            return Err("inner-loop estimate: K_p0, K_I0 and K need one value per joint".into());
        }
        if n > MAX_JOINTS {
            return Err(format!(
                "inner-loop estimate: at most {MAX_JOINTS} joints, got {n}"
            ));
        }
        let positive = |v: &[f64]| v.iter().all(|&x| x > 0.0);
        if !(positive(kp0_a_s_per_rad) && positive(ki0_a_per_rad) && positive(drive_gain_nm_per_a))
        {
            return Err("inner-loop estimate: commissioned gains must be > 0".into());
        }
        if !(memory_s > 0.0 && prior_rel > 0.0) {
            return Err("inner-loop estimate: memory_s and prior_rel must be > 0".into());
        }
        let fill = |v: &[f64]| {
            let mut a = [0.0; MAX_JOINTS];
            a[..n].copy_from_slice(v);
            a
        };
        let var = prior_rel * prior_rel;
        let prior = [[var, 0.0, 0.0], [0.0, var, 0.0], [0.0, 0.0, 0.1 * 0.1]];
        Ok(InnerLoopEstimator {
            n,
            kp0: fill(kp0_a_s_per_rad),
            ki0: fill(ki0_a_per_rad),
            k: fill(drive_gain_nm_per_a),
            memory_s,
            theta: [[1.0, 1.0, 0.0]; MAX_JOINTS],
            p: [prior; MAX_JOINTS],
            cap: 2.0 * var,
            updates: 0,
            rejected: [0; MAX_JOINTS],
            seconds: 0.0,
            u1: [0.0; MAX_JOINTS],
            u2: [0.0; MAX_JOINTS],
        })
    }

    pub fn n(&self) -> usize {
        self.n
    }

    /// One cycle the drive followed as sent, with the reported mean current [A] and the
    /// current's noise [A]. A cycle with a non-finite input is skipped (returns false); a
    /// joint whose residual is beyond [`REJECT_SIGMA`] of what the noise and the estimate's
    /// uncertainty allow keeps its estimate and counts in [`Self::rejected`].
    pub fn update(&mut self, c: &Cycle, current_a: &[f64], noise_a: f64) -> Result<bool, String> {
        let n = self.n;
        c.check(n)?;
        check_len(current_a, n, "current_a")?;
        cycle_means(c, &mut self.u1[..n], &mut self.u2[..n])?;
        let finite = current_a.iter().enumerate().all(|(j, i)| {
            (self.kp0[j] * self.u1[j]).is_finite()
                && (self.ki0[j] * self.u2[j]).is_finite()
                && i.is_finite()
        });
        if !finite {
            return Ok(false);
        }
        let lam = (-c.period_s / self.memory_s).exp();
        let noise_var = lam * (noise_a * noise_a);
        for (j, &current) in current_a.iter().enumerate() {
            let x = [self.kp0[j] * self.u1[j], self.ki0[j] * self.u2[j], 1.0];
            let p = &mut self.p[j];
            let mut px = [dot3(&p[0], &x), dot3(&p[1], &x), dot3(&p[2], &x)];
            let xpx = dot3(&x, &px);
            let denom = noise_var + xpx;
            let mut gain = [px[0] / denom, px[1] / denom, px[2] / denom];
            let theta = &mut self.theta[j];
            let resid = current - dot3(&x, theta);
            // A cycle the drive did not run as logged must not throw the estimate away.
            let bound = REJECT_SIGMA * (noise_var + xpx).sqrt();
            if resid.abs() > bound {
                self.rejected[j] += 1;
                gain = [0.0; 3];
                px = [0.0; 3];
            }
            for a in 0..3 {
                theta[a] += gain[a] * resid;
            }
            for a in 0..3 {
                for b in 0..3 {
                    p[a][b] = (p[a][b] - gain[a] * px[b]) / lam;
                }
            }
            // keep P symmetric and bounded (no excitation for a while: it grows as 1/λ^t)
            let q = *p;
            for a in 0..3 {
                for b in 0..3 {
                    p[a][b] = 0.5 * (q[a][b] + q[b][a]);
                }
            }
            let trace = p[0][0] + p[1][1];
            if trace > self.cap {
                let scale = self.cap / trace;
                for row in p.iter_mut() {
                    for v in row.iter_mut() {
                        *v *= scale;
                    }
                }
            }
        }
        self.updates += 1;
        self.seconds += c.period_s;
        Ok(true)
    }

    /// K̂_p [A·s/rad] per joint.
    pub fn kp_hat_a_s_per_rad(&self, out: &mut [f64]) {
        for (j, o) in out.iter_mut().enumerate().take(self.n) {
            *o = self.kp0[j] * self.theta[j][0];
        }
    }

    /// K̂_I [A/rad] per joint.
    pub fn ki_hat_a_per_rad(&self, out: &mut [f64]) {
        for (j, o) in out.iter_mut().enumerate().take(self.n) {
            *o = self.ki0[j] * self.theta[j][1];
        }
    }

    /// ω̂ = 1/(K K̂_p) [rad/(s·N·m)] per joint (NaN where K̂_p is not positive).
    pub fn omega_rad_s_per_nm(&self, out: &mut [f64]) {
        for (j, o) in out.iter_mut().enumerate().take(self.n) {
            let kp = self.kp0[j] * self.theta[j][0];
            *o = if kp > 0.0 {
                1.0 / (self.k[j] * kp)
            } else {
                f64::NAN
            };
        }
    }

    /// Υ̂_I = K̂_I / K̂_p [1/s] per joint (NaN where K̂_p is not positive).
    pub fn upsilon_i_per_s(&self, out: &mut [f64]) {
        for (j, o) in out.iter_mut().enumerate().take(self.n) {
            let kp = self.kp0[j] * self.theta[j][0];
            *o = if kp > 0.0 {
                self.ki0[j] * self.theta[j][1] / kp
            } else {
                f64::NAN
            };
        }
    }

    /// Relative standard deviation of (K̂_p, K̂_I) per joint from the RLS covariance.
    pub fn rel_std(&self, out: &mut [[f64; 2]]) {
        // np.maximum(v, 0): NaN stays NaN
        let sd = |v: f64| if v >= 0.0 || v.is_nan() { v } else { 0.0 }.sqrt();
        for (j, o) in out.iter_mut().enumerate().take(self.n) {
            *o = [sd(self.p[j][0][0]), sd(self.p[j][1][1])];
        }
    }

    pub fn kp0_a_s_per_rad(&self) -> &[f64] {
        &self.kp0[..self.n]
    }

    pub fn ki0_a_per_rad(&self) -> &[f64] {
        &self.ki0[..self.n]
    }

    pub fn drive_gain_nm_per_a(&self) -> &[f64] {
        &self.k[..self.n]
    }

    pub fn memory_s(&self) -> f64 {
        self.memory_s
    }

    /// `(K_p/K_p0, K_I/K_I0, b [A])` per joint.
    pub fn theta(&self) -> &[[f64; 3]] {
        &self.theta[..self.n]
    }

    /// The RLS covariance per joint.
    pub fn p(&self) -> &[[[f64; 3]; 3]] {
        &self.p[..self.n]
    }

    /// Cycles taken (skipped ones excluded).
    pub fn updates(&self) -> u64 {
        self.updates
    }

    /// Per joint, cycles whose residual was rejected as an outlier.
    pub fn rejected(&self) -> &[u64] {
        &self.rejected[..self.n]
    }

    /// Time covered by the cycles taken [s].
    pub fn seconds(&self) -> f64 {
        self.seconds
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const KP: [f64; 2] = [200.0, 10.0];
    const KI: [f64; 2] = [6400.0, 320.0];
    const K: [f64; 2] = [40.0, 10.0];

    fn cycle<'a>(q_cmd: &'a [f64], dq_cmd: &'a [f64], q0: &'a [f64], q1: &'a [f64]) -> Cycle<'a> {
        Cycle {
            q_cmd_rad: q_cmd,
            dq_cmd_rad_s: dq_cmd,
            q_start_rad: q0,
            q_end_rad: q1,
            period_s: 0.004,
            dq_start_end_rad_s: None,
            ticks: 0,
        }
    }

    #[test]
    fn cycle_means_follow_the_reference_over_the_cycle() {
        let (mut u1, mut u2) = ([0.0; 1], [0.0; 1]);
        let c = cycle(&[0.1], &[2.0], &[0.0], &[0.004]);
        cycle_means(&c, &mut u1, &mut u2).unwrap();
        assert!((u1[0] - (2.0 - 1.0)).abs() < 1e-12);
        assert!((u2[0] - (0.1 + 0.004 - 0.002)).abs() < 1e-12);
        // with 4 ticks and the velocities: the means the drive's PI saw at each tick's start
        let c = Cycle {
            dq_start_end_rad_s: Some((&[1.0], &[1.0])),
            ticks: 4,
            ..c
        };
        cycle_means(&c, &mut u1, &mut u2).unwrap();
        assert!((u1[0] - 1.0).abs() < 1e-12);
        let want = 0.1 + 0.5 * 0.004 * 0.75 * 2.0 - 0.002 + 0.004 / 8.0;
        assert!((u2[0] - want).abs() < 1e-12);
        let bad = cycle(&[0.1], &[2.0, 1.0], &[0.0], &[0.0]);
        let err = cycle_means(&bad, &mut u1, &mut u2).unwrap_err();
        assert!(err.contains("dq_cmd"), "{err}");
    }

    #[test]
    fn bad_settings_are_refused() {
        let e = InnerLoopEstimator::new(&KP, &KI[..1], &K, 30.0, 1.0).unwrap_err();
        assert!(e.contains("one value per joint"), "{e}");
        let e = InnerLoopEstimator::new(&KP, &[-1.0, 1.0], &K, 30.0, 1.0).unwrap_err();
        assert!(e.contains("> 0"), "{e}");
        let e = InnerLoopEstimator::new(&KP, &KI, &K, f64::NAN, 1.0).unwrap_err();
        assert!(e.contains("memory_s"), "{e}");
        let many = [1.0; MAX_JOINTS + 1];
        assert!(InnerLoopEstimator::new(&many, &many, &many, 30.0, 1.0).is_err());
    }

    /// A PI loop with gains off the commissioned ones, driven by a sinusoidal command offset
    /// and a moving arm: the estimate finds its gains; a non-finite cycle is skipped and an
    /// outlier rejected.
    #[test]
    fn the_gains_are_found_from_an_exact_pi_loop() {
        let (kp, ki, b) = ([KP[0] * 1.3, KP[1] * 0.7], [KI[0] * 0.8, KI[1] * 1.2], 0.05);
        let mut est = InnerLoopEstimator::new(&KP, &KI, &K, 30.0, 1.0).unwrap();
        let t_s = 0.004;
        for c in 0..5000 {
            let t = c as f64 * t_s;
            let (mut q_cmd, mut dq_cmd, mut q0, mut q1) = ([0.0; 2], [0.0; 2], [0.0; 2], [0.0; 2]);
            let mut current = [0.0; 2];
            for j in 0..2 {
                let w = 3.0 + j as f64;
                q0[j] = (0.5 * t).sin() + 0.01 * j as f64;
                q1[j] = (0.5 * (t + t_s)).sin() + 0.01 * j as f64;
                q_cmd[j] = q0[j] + 1e-3 * (w * t).sin();
                dq_cmd[j] = 0.5 * (0.5 * t).cos() + 0.05 * (1.7 * w * t).cos();
                let (u1, u2) = (
                    dq_cmd[j] - (q1[j] - q0[j]) / t_s,
                    q_cmd[j] + 0.5 * t_s * dq_cmd[j] - 0.5 * (q0[j] + q1[j]),
                );
                current[j] = kp[j] * u1 + ki[j] * u2 + b;
            }
            if c == 100 {
                current[0] = f64::NAN;
            }
            if c == 3000 {
                current[1] += 50.0;
            }
            let taken = est
                .update(&cycle(&q_cmd, &dq_cmd, &q0, &q1), &current, 0.02)
                .unwrap();
            assert_eq!(taken, c != 100);
        }
        assert_eq!(est.updates(), 4999);
        assert_eq!(est.rejected(), &[0, 1]);
        let (mut kp_hat, mut ki_hat, mut omega, mut ups) = ([0.0; 2], [0.0; 2], [0.0; 2], [0.0; 2]);
        est.kp_hat_a_s_per_rad(&mut kp_hat);
        est.ki_hat_a_per_rad(&mut ki_hat);
        est.omega_rad_s_per_nm(&mut omega);
        est.upsilon_i_per_s(&mut ups);
        for j in 0..2 {
            assert!((kp_hat[j] / kp[j] - 1.0).abs() < 1e-3, "{kp_hat:?}");
            assert!((ki_hat[j] / ki[j] - 1.0).abs() < 1e-3, "{ki_hat:?}");
            assert!((omega[j] * K[j] * kp[j] - 1.0).abs() < 1e-3);
            assert!((ups[j] * kp[j] / ki[j] - 1.0).abs() < 1e-3);
        }
        let mut sd = [[0.0; 2]; 2];
        est.rel_std(&mut sd);
        assert!(sd.iter().flatten().all(|&v| v < 0.05), "{sd:?}");
        assert!((est.seconds() - 4999.0 * t_s).abs() < 1e-9);
    }

    #[test]
    fn without_excitation_the_covariance_stays_capped() {
        let mut est = InnerLoopEstimator::new(&KP, &KI, &K, 1.0, 0.5).unwrap();
        let z = [0.0; 2];
        for _ in 0..5000 {
            est.update(&cycle(&z, &z, &z, &z), &z, 0.02).unwrap();
        }
        for p in est.p() {
            assert!(p[0][0] + p[1][1] <= 2.0 * 0.25 * (1.0 + 1e-12));
        }
        assert_eq!(est.theta()[0][..2], [1.0, 1.0]);
        // a non-positive K̂_p has no ω̂ or Υ̂_I
        est.theta[1][0] = -0.1;
        let (mut omega, mut ups) = ([0.0; 2], [0.0; 2]);
        est.omega_rad_s_per_nm(&mut omega);
        est.upsilon_i_per_s(&mut ups);
        assert!(omega[1].is_nan() && ups[1].is_nan() && omega[0].is_finite());
    }
}
