//! Outer loop of the paper: desired torque → position/velocity commands for a closed PI loop.
//!
//! The vendor's inner loop is eq. (19): `i_c = -K_p (dq - dq_c) - K_I (q - q_c)`, so the torque it
//! produces is `K i_c = K* [(dq_c - dq) + Υ_I (q_c - q)]` with `K* = K K_p` and
//! `Υ_I = K_p⁻¹ K_I` (eq. 20). Eq. (21) chooses the command so that this torque equals
//! `diag(ω) τ_d` scaled back by `K*`:
//!
//! ```text
//! dq_c + Υ_I q_c = dq + Υ_I q + diag(ω) τ_d                                   (21)
//! ```
//!
//! Writing the command as an offset from the measurement, `e = q_c - q`, eq. (21) is the stable
//! first-order filter `de/dt = -Υ_I e + ω τ_d`. We integrate it exactly over one controller cycle
//! (zero-order hold on τ_d) and send `q_c = q + e`, `dq_c = dq + de/dt`. With ω = 1/K* and the
//! true Υ_I, the inner loop delivers τ = τ_d (eq. 23 with Δω = 0, ΔΥ_I = 0).
//!
//! **ω adapts to the measured motor current, eq. (28).** With estimates ω̂ and Υ̂_I the inner loop
//! delivers `τ = K*[ω̂ τ_d + (Υ_I - Υ̂_I) e]` (eq. 23); holding a load (e at its steady value ω̂
//! τ_d / Υ̂_I) that is `τ = τ_d · K* ω̂ Υ_I / Υ̂_I`: a static gain that is 1 only for exact
//! estimates. A zero-moment arm has nothing else holding it, so a 2 % error in the identified K_I
//! lets a 1,000 kg arm sink (measured on the virtual cell: 0.6 m in 5 s with a spray gun mounted,
//! against 0.5 mm with the exact gains). The drive reports its motor current, so the torque it
//! delivered is measured (`τ_m = K i`, K the datasheet's torque constant) and eq. (28), `dω̂/dt =
//! -Λ τ_d (τ_m - τ_d)`, drives the error to zero. As for the paper's laws below, the regressor is
//! the command the drive actually followed, not the designed τ_d: with the cycle means u₁ =
//! mean(dq_c - dq) and u₂ = mean(q_c - q) of the command that drove the cycle, the estimates
//! predict `τ̂ = (u₁ + Υ̂_I u₂) / ω̂`, which is τ_d when the arm moved as the delay predictor said
//! (control/rt/src/law/delay.rs). When it did not (the hand pushed, the model's inertia is off),
//! τ_d no longer says what the drive was asked for, and a gradient on it learnt the mismatch as a
//! gain error (teach-bench, seed 0: J6's ω̂ ended at 0.67 of the drive's after 59 s of teaching,
//! J1's at 0.93; with τ̂, docs/results/teaching.md). We take the normalised gradient Λ = γ ω̂ / τ̂² per
//! joint, in the log of ω̂, which makes the convergence rate γ independent of the load and
//! keeps ω̂ > 0:
//!
//! ```text
//! ω̂ ← ω̂ · exp(-γ dt · clip((τ_m - τ̂) / τ̂, ±0.5)),   projected onto [ω̂₀/2, 2 ω̂₀]
//! ```
//!
//! with ω̂₀ the commissioned value. Before the first cycle, while the drive still holds the arm at
//! rest (q_c fixed, dq = dq_c = 0), eq. (19) reads `K i = K K_I (q_c - q)`: the held offset and
//! the reported current measure K K_I, and :meth:`OuterLoop.calibrate_from_hold` sets the ω̂ for
//! which the static gain is 1 before the arm is released (from the mean of the hold's last
//! states, :class:`HoldAverage`). It adapts only on a cycle the drive followed as sent (no hold,
//! no coast, the cycle after it not missed: the caller's business) and whose |τ̂| is above
//! `min_torque_nm` (the current's noise would otherwise dominate). A command the tool speed
//! limit scaled is the command the drive followed, so its cycle teaches as any other. γ
//! (`rate_per_s`, about 1/s) is far below Υ_I (~30/s), so the offset filter settles long
//! before ω̂ moves. The operator's hand does not enter τ_m - τ̂ (both are the drive's torque):
//! holding the tool against a stop does not drift ω̂. Υ̂_I and the dynamic parameters (eqs. 29,
//! 30) stay at their identified values.
//!
//! **The paper's laws (28) and (30) together** (:class:`PaperAdaptation`, `[control] strategy =
//! "paper"`). Eq. (23) says the torque the drive delivers is
//!
//! ```text
//! τ = τ_d + K* [(ω̂ - ω) τ_d - (Υ̂_I - Υ_I)(q_c - q)],
//! ```
//!
//! so with e = τ_m - τ_d (measured minus desired), gradient descent on e²/2 is eq. (28),
//! `dω̂/dt = -Λ τ_d e`, and `dΥ̂_I/dt = +Λ_I (q_c - q) e`. The paper prints eq. (30) with a
//! minus sign; with its eq. (26) its Lyapunov derivative (31) is then `-eᵀe` plus a cross term
//! of either sign, so we take the sign for which V̇ ≤ 0 (only the two laws' relative sign
//! matters: the paper's e = τ̂_d - τ_d flips both). Three things keep the laws from being used as
//! printed:
//!
//! - *The drive does not receive eq. (21) as designed.* Commands arrive a cycle late, are held
//!   over a cycle and limited, so `(dq_c - dq) + Υ̂_I (q_c - q) = ω̂ τ_d` holds only roughly,
//!   and a gradient on the designed τ_d and q_c - q learns that mismatch as a gain error (a
//!   one-joint simulation of the drive with a one-cycle command delay ended 20-75 % off). So
//!   the regressors are the ones the drive actually saw, the cycle means u₁ = mean(dq_c - dq)
//!   and u₂ = mean(q_c - q) of the command that drove the cycle (:func:`cycle_means` of
//!   control/rt/src/law/inner_estimate.rs):
//!   eq. (19) says `τ_m = K* (u₁ + Υ_I u₂)`, the estimates predict
//!   `τ̂ = (u₁ + Υ̂_I u₂)/ω̂` (= τ_d when the command went out as designed, which makes this
//!   eqs. 28 and 30), and the laws descend the gradient of `(τ_m - τ̂)²/2`.
//! - *The paper's gains diverge at our rate.* Λ = 0.01 in SI units makes the step of eq. (28)
//!   over one 4 ms cycle Λ τ_d² K* T ≈ 10⁴ (J2: τ_d ≈ 500 N·m, K* ≈ 2.6·10⁴ N·m·s/rad), where a
//!   discrete gradient diverges beyond 2. The laws run as one normalised gradient in the logs of
//!   ω̂ and Υ̂_I (which keeps both positive), the paper's ratio Λ_I/Λ = 2 kept
//!   (`upsilon_ratio`): with φ = ∂τ̂/∂(ln ω̂, ln Υ̂_I) = (-τ̂, Υ̂_I u₂ / ω̂) [N·m],
//!
//! ```text
//!   (ln ω̂, ln Υ̂_I) ← (ln ω̂, ln Υ̂_I) + γ T diag(1, Λ_I/Λ) φ s / |φ|,
//!   s = clip((τ_m - τ̂) / |φ|, ±0.5),
//! ```
//!
//!   outside a dead zone |τ_m - τ̂| ≤ ν (3 standard deviations of the motor torque measured in
//!   the hold before teaching, at least `dead_zone_nm`: below it the error is the current's
//!   noise, the paper's bound ν on the unmodelled part) and with |φ| above the adaptation's
//!   torque floor.
//! - *ω̂(0) = 0 commands no torque*: the arm would fall while ω̂ grows. ω̂(0) is the hold's
//!   calibration (:meth:`OuterLoop.calibrate_from_hold`, which makes the static gain 1 for any
//!   Υ̂_I); Υ̂_I(0) is the commissioned value or the paper's 1.2/s. Both stay within
//!   `bound_factor` of where they started.
//!
//! **What the gradient cannot do quickly.** K_p enters only through u₁, the velocity error,
//! which in teaching is a few per cent of Υ_I u₂ (the offset filter keeps dq_c close to dq; the
//! online estimate measured 1-6 % on the virtual cell). φ then points almost along (-1, 1): the
//! static gain K K_I = Υ_I/ω converges in seconds, but ω̂ and Υ̂_I apart converge with a time
//! constant of about 20 s at u₁ = 10 % of Υ_I u₂, 70 s at 3 % and 200 s at 1 % (γ = 1/s,
//! one joint fed eq. 19's torque: tests/unit/test_paper_adaptation.py). Least squares, which
//! inverts the regressors' covariance, separates them within seconds where the data allow
//! (control/rt/src/law/inner_estimate.rs).
//!
//! The compiled form of the Python it replaced, equal to it to rounding.

use crate::chain::MAX_JOINTS;

mod adaptation;
mod hold_average;

pub use self::adaptation::{Adaptation, OmegaAdaptation, PaperAdaptation};
pub use self::hold_average::HoldAverage;

/// Python's `max(a, b)`: `b` only if it is greater (a NaN `a` stays).
fn py_max(a: f64, b: f64) -> f64 {
    if b > a {
        b
    } else {
        a
    }
}

/// Python's `min(a, b)`: `b` only if it is smaller (a NaN `a` stays).
fn py_min(a: f64, b: f64) -> f64 {
    if b < a {
        b
    } else {
        a
    }
}

/// Python's `math.hypot(x, y)` (CPython 3.11, Modules/mathmodule.c `vector_norm`): the sum of
/// squares carried in compensated arithmetic and one Newton step, where libm's `hypot` may
/// round the other way (about 1 call in 1,000).
fn py_hypot(x: f64, y: f64) -> f64 {
    const T27: f64 = 134_217_729.0; // 2**27 + 1: Dekker's split
    let vec = [x.abs(), y.abs()];
    let max = vec.iter().fold(0.0, |m, &c| if c > m { c } else { m });
    if max.is_infinite() {
        return max;
    }
    if x.is_nan() || y.is_nan() {
        return f64::NAN;
    }
    if max == 0.0 {
        return max;
    }
    let max_e = frexp_exponent(max);
    let (mut csum, mut frac1) = (1.0f64, 0.0f64);
    if max_e < -1023 {
        // 2**-max_e would overflow: divide by the largest instead
        for v in vec {
            let x = v / max;
            let x = x * x;
            let old = csum;
            csum += x;
            frac1 += (old - csum) + x;
        }
        return max * (csum - 1.0 + frac1).sqrt();
    }
    let scale = power_of_two(-max_e);
    let (mut frac2, mut frac3) = (0.0f64, 0.0f64);
    for v in vec {
        let x = v * scale; // lossless
        let t = x * T27;
        let hi = t - (t - x);
        let lo = x - hi;
        let sq = hi * hi;
        let old = csum;
        csum += sq;
        frac1 += (old - csum) + sq;
        let cross = 2.0 * hi * lo;
        let old = csum;
        csum += cross;
        frac2 += (old - csum) + cross;
        frac3 += lo * lo;
    }
    let h = (csum - 1.0 + (frac1 + frac2 + frac3)).sqrt();
    let t = h * T27;
    let hi = t - (t - h);
    let lo = h - hi;
    for (x, frac) in [
        (-hi * hi, &mut frac1),
        (-2.0 * hi * lo, &mut frac2),
        (-lo * lo, &mut frac3),
    ] {
        let old = csum;
        csum += x;
        *frac += (old - csum) + x;
    }
    let x = csum - 1.0 + (frac1 + frac2 + frac3);
    (h + x / (2.0 * h)) / scale
}

/// C's `frexp` exponent: `v = m 2**e` with 0.5 <= m < 1 (v finite, > 0).
fn frexp_exponent(v: f64) -> i32 {
    let bits = v.to_bits();
    let biased = ((bits >> 52) & 0x7ff) as i32;
    if biased == 0 {
        // subnormal: v = mantissa 2**-1074
        let mantissa = bits & ((1 << 52) - 1);
        64 - mantissa.leading_zeros() as i32 - 1074
    } else {
        biased - 1022
    }
}

/// 2**k exactly, for -1074 <= k <= 1023.
fn power_of_two(k: i32) -> f64 {
    if k >= -1022 {
        f64::from_bits(((k + 1023) as u64) << 52)
    } else {
        f64::from_bits(1u64 << (k + 1074))
    }
}

/// `np.clip(x, lo, hi)`: `minimum(maximum(x, lo), hi)`, NaN in any of them gives NaN.
fn np_clip(x: f64, lo: f64, hi: f64) -> f64 {
    let m = if x.is_nan() || lo.is_nan() {
        f64::NAN
    } else {
        x.max(lo)
    };
    if m.is_nan() || hi.is_nan() {
        f64::NAN
    } else {
        m.min(hi)
    }
}

/// `x` limited to ±`limit`, NaN passing through for the message layer to refuse.
fn limit(x: f64, limit: f64) -> f64 {
    if x > limit {
        limit
    } else if x < -limit {
        -limit
    } else {
        x
    }
}

/// Discrete eq. (21) with per-joint limits on the offset and the velocity command, and ω̂
/// (and Υ̂_I) adapted by eq. (28) (and 30).
#[derive(Clone, Debug)]
pub struct OuterLoop {
    n: usize,
    /// ω̂₀ and Υ̂_I₀, as commissioned [rad/s per N·m], [1/s]
    omega0: [f64; MAX_JOINTS],
    upsilon_i0: [f64; MAX_JOINTS],
    max_offset_rad: [f64; MAX_JOINTS],
    max_velocity_rad_s: [f64; MAX_JOINTS],
    adaptation: Adaptation,
    /// ω̂ and Υ̂_I now
    omega: [f64; MAX_JOINTS],
    ups: [f64; MAX_JOINTS],
    /// their projection's bounds
    omega_lo: [f64; MAX_JOINTS],
    omega_hi: [f64; MAX_JOINTS],
    ups_lo: [f64; MAX_JOINTS],
    ups_hi: [f64; MAX_JOINTS],
    /// PaperAdaptation's dead zone [N·m] ([`OuterLoop::set_dead_zone`])
    dead_zone: [f64; MAX_JOINTS],
    /// e = q_cmd - q that the next command carries [rad]
    offset: [f64; MAX_JOINTS],
    /// exp(-Υ̂_I dt) for the dt and Υ̂_I it was computed with (NaN dt: none yet)
    decay_dt: f64,
    decay_ups: [f64; MAX_JOINTS],
    decay: [f64; MAX_JOINTS],
}

fn joints(v: &[f64]) -> [f64; MAX_JOINTS] {
    let mut out = [0.0; MAX_JOINTS];
    out[..v.len()].copy_from_slice(v);
    out
}

impl OuterLoop {
    /// `omega` ω = 1/(K K_p) per joint [rad/s per N·m] and `upsilon_i` Υ_I = K_I/K_p [1/s], both
    /// positive; the limits on the offset [rad] and the velocity command [rad/s]; the adaptation
    /// checked for the joint count. An error names what was wrong.
    pub fn new(
        omega: &[f64],
        upsilon_i: &[f64],
        max_offset_rad: &[f64],
        max_velocity_rad_s: &[f64],
        adaptation: Adaptation,
    ) -> Result<OuterLoop, String> {
        let n = omega.len();
        if n > MAX_JOINTS {
            return Err(format!("omega: at most {MAX_JOINTS} joints, got {n}"));
        }
        for (name, v) in [
            ("upsilon_i", upsilon_i),
            ("max_offset_rad", max_offset_rad),
            ("max_velocity_rad_s", max_velocity_rad_s),
        ] {
            if v.len() != n {
                return Err(format!("{name} must have {n} values"));
            }
        }
        // NaN passes, as in the Python module
        if omega.iter().chain(upsilon_i).any(|&v| v <= 0.0) {
            return Err("omega and upsilon_i must be positive (eq. 21)".into());
        }
        match &adaptation {
            Adaptation::None => {}
            Adaptation::Omega(a) => a.check(n)?,
            Adaptation::Paper(a) => a.check(n)?,
        }
        let wide = match &adaptation {
            Adaptation::Paper(a) => a.bound_factor,
            _ => 2.0,
        };
        let mut dead_zone = [0.0; MAX_JOINTS];
        if let Adaptation::Paper(a) = &adaptation {
            dead_zone[..a.dead_zone_nm.len()].copy_from_slice(&a.dead_zone_nm);
        }
        let (omega0, upsilon_i0) = (joints(omega), joints(upsilon_i));
        Ok(OuterLoop {
            n,
            omega0,
            upsilon_i0,
            max_offset_rad: joints(max_offset_rad),
            max_velocity_rad_s: joints(max_velocity_rad_s),
            adaptation,
            omega: omega0,
            ups: upsilon_i0,
            omega_lo: omega0.map(|w| w / wide),
            omega_hi: omega0.map(|w| w * wide),
            ups_lo: upsilon_i0.map(|u| u / wide),
            ups_hi: upsilon_i0.map(|u| u * wide),
            dead_zone,
            offset: [0.0; MAX_JOINTS],
            decay_dt: f64::NAN,
            decay_ups: [0.0; MAX_JOINTS],
            decay: [0.0; MAX_JOINTS],
        })
    }

    pub fn n(&self) -> usize {
        self.n
    }

    /// ω̂ per joint now [rad/s per N·m].
    pub fn omega(&self) -> &[f64] {
        &self.omega[..self.n]
    }

    /// Υ̂_I per joint now [1/s].
    pub fn upsilon_i(&self) -> &[f64] {
        &self.ups[..self.n]
    }

    /// ω̂₀, as constructed [rad/s per N·m].
    pub fn omega0(&self) -> &[f64] {
        &self.omega0[..self.n]
    }

    /// Υ̂_I₀, as constructed [1/s].
    pub fn upsilon_i0(&self) -> &[f64] {
        &self.upsilon_i0[..self.n]
    }

    pub fn max_offset_rad(&self) -> &[f64] {
        &self.max_offset_rad[..self.n]
    }

    pub fn max_velocity_rad_s(&self) -> &[f64] {
        &self.max_velocity_rad_s[..self.n]
    }

    pub fn adaptation(&self) -> &Adaptation {
        &self.adaptation
    }

    /// PaperAdaptation's dead zone per joint [N·m] (zeros otherwise).
    pub fn dead_zone_nm(&self) -> &[f64] {
        &self.dead_zone[..self.n]
    }

    /// e = q_cmd - q that the next command carries [rad].
    pub fn offset_rad(&self) -> &[f64] {
        &self.offset[..self.n]
    }

    /// Set the offset the next command carries (n values) [rad], as given.
    pub fn set_offset_rad(&mut self, offset_rad: &[f64]) {
        self.offset[..self.n].copy_from_slice(offset_rad);
    }

    /// PaperAdaptation's dead zone from the motor torque's noise measured at rest (n values)
    /// [N·m]: 3 standard deviations per joint, at least the configured floor. Other laws: no
    /// effect.
    pub fn set_dead_zone(&mut self, noise_std_nm: &[f64]) {
        if let Adaptation::Paper(a) = &self.adaptation {
            for (j, &s) in noise_std_nm[..self.n].iter().enumerate() {
                let floor = a.dead_zone_nm.get(j).copied().unwrap_or(0.0);
                self.dead_zone[j] = py_max(floor, 3.0 * s);
            }
        }
    }

    /// Take over from the command the robot currently follows (bumpless transfer): the offset
    /// (n values) [rad] clipped to its limits. ω̂ keeps what it learnt: it is the drive's, not
    /// the engagement's.
    pub fn reset(&mut self, offset_rad: &[f64]) {
        for (j, &e) in offset_rad[..self.n].iter().enumerate() {
            let m = self.max_offset_rad[j];
            self.offset[j] = np_clip(e, -m, m);
        }
    }

    /// Eq. (28) (OmegaAdaptation) or eqs. (28) and (30) (PaperAdaptation) for a cycle the
    /// drive followed as sent: its means u₁ = mean(dq_c - dq) [rad/s] and u₂ = mean(q_c - q)
    /// [rad], and the motor torque measured over it [N·m], n values each. A joint whose
    /// values are NaN takes no step.
    pub fn adapt(&mut self, u1_rad_s: &[f64], u2_rad: &[f64], tau_m_nm: &[f64], dt_s: f64) {
        match &self.adaptation {
            Adaptation::None => {}
            Adaptation::Omega(a) => {
                let step = a.rate_per_s * dt_s;
                for j in 0..self.n {
                    let (u1, u2, tm, floor) =
                        (u1_rad_s[j], u2_rad[j], tau_m_nm[j], a.min_torque_nm[j]);
                    let w = self.omega[j];
                    let tau_hat = (u1 + self.ups[j] * u2) / w;
                    if tau_hat > floor || tau_hat < -floor {
                        let r = (tm - tau_hat) / tau_hat;
                        if r.is_nan() {
                            continue;
                        }
                        let r = r.clamp(-0.5, 0.5);
                        self.omega[j] = self.project(j, w * (-step * r).exp());
                    }
                }
            }
            Adaptation::Paper(a) => {
                let step = a.rate_per_s * dt_s;
                for j in 0..self.n {
                    let (u1, u2, tm) = (u1_rad_s[j], u2_rad[j], tau_m_nm[j]);
                    let (floor, nu) = (a.min_torque_nm[j], self.dead_zone[j]);
                    let (w, mut u) = (self.omega[j], self.ups[j]);
                    let p2 = u * u2 / w;
                    let p1 = -(u1 / w + p2); // -τ̂
                    let r = tm + p1; // τ_m - τ̂
                    let norm = py_hypot(p1, p2);
                    if !(norm > floor && (r > nu || r < -nu)) {
                        continue; // NaN: no step
                    }
                    let s = (r / norm).clamp(-0.5, 0.5);
                    self.omega[j] = self.project(j, w * (step * p1 / norm * s).exp());
                    u *= (step * a.upsilon_ratio * p2 / norm * s).exp();
                    self.ups[j] = py_min(py_max(u, self.ups_lo[j]), self.ups_hi[j]);
                }
            }
        }
    }

    /// ω̂ from the drive holding the arm at rest: there eq. (19) is `K i = K K_I (q_c - q)`,
    /// so the measured `tau_m_nm` over the held `offset_rad` = q_c - q is K K_I, and the static
    /// gain K K_I ω̂ / Υ̂_I of eq. (23) is 1 for ω̂ = Υ̂_I (q_c - q) / τ_m (n values each).
    /// Joints below the adaptation's torque floor, or whose torque and offset disagree in
    /// sign, keep their ω̂; the result is projected as eq. (28) projects. No adaptation: no
    /// effect.
    pub fn calibrate_from_hold(&mut self, offset_rad: &[f64], tau_m_nm: &[f64]) {
        let Some(floors) = self.adaptation.min_torque_nm() else {
            return;
        };
        for j in 0..self.n {
            let (e, tm, floor) = (offset_rad[j], tau_m_nm[j], floors[j]);
            if (tm > floor || tm < -floor) && e * tm > 0.0 {
                self.omega[j] = self.project(j, self.ups[j] * e / tm);
            }
        }
    }

    /// `omega` projected onto joint j's bounds (ω̂₀/2 to 2 ω̂₀; PaperAdaptation:
    /// `bound_factor` either side of ω̂₀); NaN stays NaN.
    fn project(&self, j: usize, omega: f64) -> f64 {
        py_min(py_max(omega, self.omega_lo[j]), self.omega_hi[j])
    }

    /// exp(-Υ̂_I dt) per joint, recomputed when dt or Υ̂_I changed since the last cycle.
    fn refresh_decay(&mut self, dt_s: f64) {
        let n = self.n;
        if self.decay_dt != dt_s || self.decay_ups[..n] != self.ups[..n] {
            self.decay_dt = dt_s;
            self.decay_ups = self.ups;
            for j in 0..n {
                self.decay[j] = (-self.ups[j] * dt_s).exp();
            }
        }
    }

    /// One controller cycle of eq. (21) over `dt_s` [s] at the state (`q_rad`, `dq_rad_s`)
    /// for the desired torque `tau_d_nm` [N·m] (n values each): writes the command to send now
    /// (`q_cmd`, `dq_cmd`) and per joint whether the offset or velocity limit was hit
    /// (`saturated`), and keeps the next cycle's offset. NaN passes through the limits, for
    /// the message layer to refuse. The command's offset is [`OuterLoop::offset_rad`] as it
    /// was before the call.
    #[allow(clippy::too_many_arguments)]
    pub fn step(
        &mut self,
        q_rad: &[f64],
        dq_rad_s: &[f64],
        tau_d_nm: &[f64],
        dt_s: f64,
        q_cmd: &mut [f64],
        dq_cmd: &mut [f64],
        saturated: &mut [bool],
    ) {
        self.refresh_decay(dt_s);
        for j in 0..self.n {
            let (e, omega, ups, tau) = (self.offset[j], self.omega[j], self.ups[j], tau_d_nm[j]);
            let (max_e, max_v) = (self.max_offset_rad[j], self.max_velocity_rad_s[j]);
            let target = omega * tau / ups; // steady-state offset
            let e_next = target + (e - target) * self.decay[j];
            let dq_c = dq_rad_s[j] + (-ups * e + omega * tau);
            saturated[j] = e_next.abs() > max_e || dq_c.abs() > max_v;
            self.offset[j] = limit(e_next, max_e);
            dq_cmd[j] = limit(dq_c, max_v);
            q_cmd[j] = q_rad[j] + e;
        }
    }
}

#[cfg(test)]
#[path = "outer_loop_tests.rs"]
mod tests;
