//! Sensorless admittance: the second lead-through strategy (issue 9; the paper's refs. [25, 26]).
//!
//! The zero-moment law of the paper asks the closed velocity loop for the model's torque and lets
//! the operator's hand move the arm. Through a stiff vendor loop that sees each command a cycle
//! late, the hand's push is resisted until the next command catches up, and the operator pays
//! the arm's whole inertia. Admittance turns it round: the vendor loop keeps the arm on a
//! reference the product integrates, and the hand's torque is *measured* as what the drives give
//! beyond the model (no force sensor):
//!
//! ```text
//! τ̂_h = M̂(q) q̈_r + g(q) + f(q, q̇_r) − τ_cyl(q, p) − K i − b                        (A1)
//! ```
//!
//! with `K i` the motor torque in the datasheet's unit (the identified model is in that unit too,
//! so a drive-gain error scales τ̂_h and nothing else), q̈_r the reference acceleration of the
//! cycle the current was measured over (known exactly: the product computed it), and `b` the
//! residual at rest when teaching engages (the operator's hand on the handle but not pushing),
//! which takes the model's static error at that pose and the current sensors' offsets out. τ̂_h is
//! low-passed (the motor current's noise is several N·m on the big joints) and passes a dead zone
//! of the model's uncertainty (the rest hold's band, control/rt/src/law/rest_hold.rs): below it the
//! arm stays where it is, however long. Like a joint's friction, the zone has a static and a
//! kinetic width: a joint at rest breaks away only when the push exceeds :data:`NOISE_SIGMAS`
//! standard deviations of the filtered estimate's noise (measured on the currents while the arm
//! rests in the hold before teaching engages; at least the configured band), so noise alone seldom
//! moves it; once one joint moves, the arm is being guided and every joint follows every push
//! beyond the configured band (the model's held-out RMS), which is all the painter pays while
//! guiding the tool, until every joint is back inside it or the reference has crept slower than
//! :data:`SETTLE_RAD_S` for :data:`SETTLE_S`. The reference then follows
//!
//! ```text
//! α M̂(q) q̈_r + D q̇_r = dz(τ̂_h) + τ_walls                                           (A2)
//! ```
//!
//! so the operator moves α of the arm's inertia (M̂: the identified model's, or the nominal rigid
//! body's with rotor inertias) against a viscous damping D. A hand that does not push beyond the
//! dead zone is no hand: there the damping is `rest_factor` × D, blended in linearly as the
//! push falls from the band's width above it to nothing, so the arm a painter lets go of stops
//! in a fraction of a second instead of coasting on its small virtual mass, and a model error
//! at the edge of the band creeps `rest_factor` times slower. The command sent is the reference
//! plus the offset at which the vendor loop delivers the model's torque (eq. 21's steady state,
//! `ω̂ τ / Υ̂_I`).
//!
//! Discretisation: per controller cycle, low-pass by exact first order, then semi-implicit Euler
//! on (A2) with the damping implicit, `q̇_r ← (α M̂ q̇_r + dt τ) / (α M̂ + dt D)`, which is
//! stable for any dt and any D ≥ 0.
//!
//! numpy's semantics are kept where they show: `maximum`, `minimum`, `clip` and `sign` let NaN
//! through, the linear solve refuses an exactly singular matrix (numpy's `LinAlgError`), and
//! `round` in the probe's length rounds half to even as Python's does. The buffers are
//! allocated in `new`; the per-cycle methods allocate nothing. The Python
//! `AdmittanceController` (control/admittance_law.py) drives it once per cycle.

use crate::chain::MAX_JOINTS;

/// The dead zone is at least this many standard deviations of the filtered estimate's noise
/// at rest: a Gaussian sample passes 3.5 σ once in ~2,000 (about every 10 s at 250 Hz).
pub const NOISE_SIGMAS: f64 = 3.5;
/// A guided arm whose reference has been slower than this on every joint [rad/s] for
/// [`SETTLE_S`] is at rest again (it needs the static dead zone to break away).
pub const SETTLE_RAD_S: f64 = 2e-3;
/// See [`SETTLE_RAD_S`] [s].
pub const SETTLE_S: f64 = 0.3;
/// The engagement probe's ramps to and from its cruise speed [s].
pub const PROBE_RAMP_S: f64 = 0.05;
/// A probe side needs this many sliding cruise samples for its median.
pub const PROBE_MIN_SAMPLES: usize = 3;
/// The most samples a probe may have (4 quarters and the final stop); numpy would try to
/// allocate any length, this refuses a length no cell could mean.
pub const PROBE_MAX_SAMPLES: usize = 100_000_000;

/// numpy's `maximum`: NaN from either side.
fn np_max(a: f64, b: f64) -> f64 {
    if a.is_nan() || b.is_nan() {
        f64::NAN
    } else if b > a {
        b
    } else {
        a
    }
}

/// numpy's `minimum`: NaN from either side.
fn np_min(a: f64, b: f64) -> f64 {
    if a.is_nan() || b.is_nan() {
        f64::NAN
    } else if b < a {
        b
    } else {
        a
    }
}

/// numpy's `sign`: 0 at ±0, NaN at NaN.
fn np_sign(x: f64) -> f64 {
    if x > 0.0 {
        1.0
    } else if x < 0.0 {
        -1.0
    } else if x == 0.0 {
        0.0
    } else {
        f64::NAN
    }
}

/// numpy's `clip`: `minimum(maximum(x, lo), hi)`.
fn np_clip(x: f64, lo: f64, hi: f64) -> f64 {
    np_min(np_max(x, lo), hi)
}

/// The low-pass's coefficient for one step of `dt_s`: exact first order at `filter_hz`.
fn filter_coefficient(filter_hz: f64, dt_s: f64) -> f64 {
    1.0 - (-2.0 * std::f64::consts::PI * filter_hz * dt_s).exp()
}

/// Solves `a x = b` (a row-major n × n, overwritten; x into b) by Gaussian elimination with
/// partial pivoting, as LAPACK's `gesv` behind `numpy.linalg.solve`; Err where a pivot is
/// exactly 0 (numpy raises `LinAlgError("Singular matrix")` there).
fn solve_in_place(a: &mut [f64], b: &mut [f64], n: usize) -> Result<(), String> {
    for k in 0..n {
        // the first largest |a[i][k]| below the diagonal (BLAS idamax)
        let mut p = k;
        let mut best = a[k * n + k].abs();
        for i in k + 1..n {
            let v = a[i * n + k].abs();
            if v > best {
                best = v;
                p = i;
            }
        }
        if a[p * n + k] == 0.0 {
            return Err("Singular matrix".to_string());
        }
        if p != k {
            for j in k..n {
                a.swap(p * n + j, k * n + j);
            }
            b.swap(p, k);
        }
        let pivot = a[k * n + k];
        for i in k + 1..n {
            let l = a[i * n + k] / pivot;
            for j in k + 1..n {
                a[i * n + j] -= l * a[k * n + j];
            }
            b[i] -= l * b[k];
        }
    }
    for i in (0..n).rev() {
        let mut s = b[i];
        for j in i + 1..n {
            s -= a[i * n + j] * b[j];
        }
        b[i] = s / a[i * n + i];
    }
    Ok(())
}

/// A Cartesian speed limit: `(q_r, dq) -> scale` in (0, 1] on the proposed speed `dq`.
pub type SpeedLimit<'a> = &'a mut dyn FnMut(&[f64], &[f64]) -> f64;

/// (A1) after the model, and (A2): the reference the vendor loop follows.
///
/// `alpha` the mass fraction α, `damping` D per joint [N·m·s/rad], `base_band` the configured
/// dead zone per joint [N·m] (`band` the static one, widened by [`Admittance::reset`] to the
/// measured noise), `filter_hz` the low-pass of τ̂_h, `max_velocity` per joint [rad/s],
/// `rest_factor` the damping's factor where no hand pushes beyond the dead zone.
#[derive(Clone, Debug)]
pub struct Admittance {
    n: usize,
    rest_factor: f64,
    alpha: f64,
    filter_hz: f64,
    damping: Vec<f64>,
    max_velocity: Vec<f64>,
    base_band: Vec<f64>,
    band: Vec<f64>,
    /// The arm is guided: a joint broke away (pushed beyond `band`) and not every joint is
    /// back inside `base_band` since.
    moving: bool,
    /// How long the guided reference has been slower than [`SETTLE_RAD_S`] [s].
    slow_s: f64,
    q_r: Vec<f64>,
    dq_r: Vec<f64>,
    ddq_r: Vec<f64>,
    /// The low-passed hand torque estimate [N·m].
    tau_h: Vec<f64>,
    // per-cycle work: the push beyond the dead zone, the right-hand side (then the new
    // speed), the system's matrix
    pushed: Vec<f64>,
    dq_new: Vec<f64>,
    lhs: Vec<f64>,
}

impl Admittance {
    /// Checks the settings as the Python it replaced did (same order, same messages; NaN
    /// damping, band or maximum velocity pass, as there).
    pub fn new(
        mass_fraction: f64,
        damping: &[f64],
        band_nm: &[f64],
        filter_hz: f64,
        max_velocity: &[f64],
        rest_factor: f64,
    ) -> Result<Admittance, String> {
        if !(rest_factor.is_finite() && rest_factor >= 1.0) {
            return Err(format!(
                "admittance rest damping factor {} must be >= 1",
                py_float(rest_factor)
            ));
        }
        if !(mass_fraction.is_finite() && 0.0 < mass_fraction && mass_fraction <= 2.0) {
            return Err(format!(
                "admittance mass fraction {} not in (0, 2]",
                py_float(mass_fraction)
            ));
        }
        if !(filter_hz.is_finite() && filter_hz > 0.0) {
            return Err(format!(
                "admittance filter {} Hz must be > 0",
                py_float(filter_hz)
            ));
        }
        let n = damping.len();
        if !(band_nm.len() == n && max_velocity.len() == n) {
            return Err(
                "admittance damping, band and max velocity need one value per joint".to_string(),
            );
        }
        if n > MAX_JOINTS {
            return Err(format!(
                "admittance damping has {n} joints, at most {MAX_JOINTS}"
            ));
        }
        if damping.iter().any(|&d| d < 0.0)
            || band_nm.iter().any(|&b| b < 0.0)
            || max_velocity.iter().any(|&v| v <= 0.0)
        {
            return Err("admittance damping, band >= 0 and max velocity > 0 per joint".to_string());
        }
        Ok(Admittance {
            n,
            rest_factor,
            alpha: mass_fraction,
            filter_hz,
            damping: damping.to_vec(),
            max_velocity: max_velocity.to_vec(),
            base_band: band_nm.to_vec(),
            band: band_nm.to_vec(),
            moving: false,
            slow_s: 0.0,
            q_r: vec![0.0; n],
            dq_r: vec![0.0; n],
            ddq_r: vec![0.0; n],
            tau_h: vec![0.0; n],
            pushed: vec![0.0; n],
            dq_new: vec![0.0; n],
            lhs: vec![0.0; n * n],
        })
    }

    pub fn n(&self) -> usize {
        self.n
    }
    pub fn rest_factor(&self) -> f64 {
        self.rest_factor
    }
    pub fn alpha(&self) -> f64 {
        self.alpha
    }
    pub fn filter_hz(&self) -> f64 {
        self.filter_hz
    }
    pub fn damping(&self) -> &[f64] {
        &self.damping
    }
    pub fn max_velocity(&self) -> &[f64] {
        &self.max_velocity
    }
    /// The configured dead zone [N·m].
    pub fn base_band(&self) -> &[f64] {
        &self.base_band
    }
    /// The static dead zone [N·m]: the configured one, at least [`NOISE_SIGMAS`] of the
    /// measured noise after a reset with it.
    pub fn band(&self) -> &[f64] {
        &self.band
    }
    pub fn moving(&self) -> bool {
        self.moving
    }
    pub fn q_r(&self) -> &[f64] {
        &self.q_r
    }
    /// Moves the reference (the controller holds it within the offset limit of the arm).
    pub fn set_q_r(&mut self, q_rad: &[f64]) {
        self.q_r.copy_from_slice(q_rad);
    }
    pub fn dq_r(&self) -> &[f64] {
        &self.dq_r
    }
    pub fn ddq_r(&self) -> &[f64] {
        &self.ddq_r
    }
    pub fn tau_h(&self) -> &[f64] {
        &self.tau_h
    }

    /// The standard deviation of τ̂_h after the low-pass, for white noise of `raw_std_nm`
    /// per sample at steps of `dt_s`, into `out` (any length, as `raw_std_nm`): a first-order
    /// filter of coefficient a keeps a / (2 − a) of a white sequence's variance.
    pub fn filtered_noise(&self, raw_std_nm: &[f64], dt_s: f64, out: &mut [f64]) {
        let a = filter_coefficient(self.filter_hz, dt_s);
        let k = (a / (2.0 - a)).sqrt();
        for (o, &s) in out.iter_mut().zip(raw_std_nm) {
            *o = s * k;
        }
    }

    /// Starts at rest at `q_rad`; with `noise_std_nm`, the filtered estimate's noise per
    /// joint [N·m] ([`Admittance::filtered_noise`]), the static dead zone is at least
    /// [`NOISE_SIGMAS`] of it.
    pub fn reset(&mut self, q_rad: &[f64], noise_std_nm: Option<&[f64]>) {
        self.band.copy_from_slice(&self.base_band);
        self.moving = false;
        self.slow_s = 0.0;
        if let Some(noise) = noise_std_nm {
            for (b, &s) in self.band.iter_mut().zip(noise) {
                *b = np_max(*b, NOISE_SIGMAS * s);
            }
        }
        self.q_r.copy_from_slice(q_rad);
        self.dq_r.fill(0.0);
        self.ddq_r.fill(0.0);
        self.tau_h.fill(0.0);
    }

    /// The push beyond the dead zone per joint into `out`: an arm at rest needs `band` on a
    /// joint to break away, a guided one follows every push beyond `base_band` while one
    /// joint has it; updates `moving`.
    pub fn dead_zone(&mut self, tau: &[f64], out: &mut [f64]) {
        let broke = tau.iter().zip(&self.band).any(|(t, b)| t.abs() > *b);
        let over_any = tau
            .iter()
            .zip(&self.base_band)
            .any(|(t, b)| t.abs() - b > 0.0);
        self.moving = (self.moving || broke) && over_any;
        for ((o, &t), &b) in out.iter_mut().zip(tau).zip(&self.base_band) {
            *o = if self.moving {
                np_sign(t) * np_max(t.abs() - b, 0.0)
            } else {
                0.0
            };
        }
    }

    /// The first half of a step: the low-pass takes in one cycle's raw hand torque estimate
    /// (A1) [N·m], the dead zone and (A2) with the walls' torque and M̂ at the reference
    /// (`mass` row-major n × n) give the new reference speed, clipped to the maximum
    /// ([`Admittance::proposed`]); τ̂_h and `moving` are updated, the reference waits for
    /// [`Admittance::commit`]. Err where α M̂ + dt D is singular (τ̂_h and `moving` updated
    /// all the same, as in Python).
    pub fn propose(
        &mut self,
        tau_h_raw: &[f64],
        tau_walls: &[f64],
        mass: &[f64],
        dt_s: f64,
    ) -> Result<(), String> {
        let n = self.n;
        let a = filter_coefficient(self.filter_hz, dt_s);
        for (h, &raw) in self.tau_h.iter_mut().zip(tau_h_raw) {
            *h += a * (raw - *h);
        }
        // taken out and put back (no allocation): dead_zone borrows self mutably
        let (tau_h, mut pushed) = (
            std::mem::take(&mut self.tau_h),
            std::mem::take(&mut self.pushed),
        );
        self.dead_zone(&tau_h, &mut pushed);
        (self.tau_h, self.pushed) = (tau_h, pushed);
        for i in 0..n {
            let drive = self.pushed[i] + tau_walls[i];
            // the push's share of the band: 0 (no hand) → rest_factor × D, ≥ 1 → D
            let share = np_min(self.pushed[i].abs() / np_max(self.base_band[i], 1e-9), 1.0);
            let damping = self.damping[i] * (self.rest_factor - (self.rest_factor - 1.0) * share);
            let mut rhs = 0.0;
            for j in 0..n {
                let m = self.alpha * mass[i * n + j];
                rhs += m * self.dq_r[j];
                // numpy adds dt × diag(D): dt × 0 off the diagonal
                self.lhs[i * n + j] = m + dt_s * if i == j { damping } else { 0.0 };
            }
            self.dq_new[i] = rhs + dt_s * drive;
        }
        solve_in_place(&mut self.lhs, &mut self.dq_new, n)?;
        for (v, &vmax) in self.dq_new.iter_mut().zip(&self.max_velocity) {
            *v = np_clip(*v, -vmax, vmax);
        }
        Ok(())
    }

    /// The reference speed [`Admittance::propose`] gave, before any speed limit [rad/s].
    pub fn proposed(&self) -> &[f64] {
        &self.dq_new
    }

    /// The second half of a step: the proposed speed times `scale` (a Cartesian speed
    /// limit's factor; 1 without one) becomes the reference's, integrated by the trapezoid
    /// rule over `dt_s`; a guided arm that has crept slower than [`SETTLE_RAD_S`] for
    /// [`SETTLE_S`] is at rest again.
    pub fn commit(&mut self, scale: f64, dt_s: f64) {
        let mut fastest = 0.0f64;
        let mut nan = false;
        for i in 0..self.n {
            let v = self.dq_new[i] * scale;
            self.ddq_r[i] = (v - self.dq_r[i]) / dt_s;
            self.q_r[i] += dt_s * 0.5 * (self.dq_r[i] + v);
            self.dq_r[i] = v;
            nan |= v.is_nan();
            fastest = fastest.max(v.abs());
        }
        // a model error past the kinetic band at a new pose does not keep it creeping
        // (numpy's max is NaN with a NaN in it, and NaN < SETTLE_RAD_S is false)
        if self.moving && !nan && fastest < SETTLE_RAD_S {
            self.slow_s += dt_s;
            if self.slow_s >= SETTLE_S {
                self.moving = false;
            }
        } else {
            self.slow_s = 0.0;
        }
    }

    /// One cycle: [`Admittance::propose`], the speed limit's factor at (q_r, proposed speed)
    /// if there is one, [`Admittance::commit`]; the new reference is `q_r()`, `dq_r()`.
    pub fn step(
        &mut self,
        tau_h_raw: &[f64],
        tau_walls: &[f64],
        mass: &[f64],
        dt_s: f64,
        speed_limit: Option<SpeedLimit<'_>>,
    ) -> Result<(), String> {
        self.propose(tau_h_raw, tau_walls, mass, dt_s)?;
        let scale = match speed_limit {
            Some(f) => f(&self.q_r, &self.dq_new),
            None => 1.0,
        };
        self.commit(scale, dt_s);
        Ok(())
    }
}

/// A float as Python's `str` writes it where it matters for the messages (nan, inf).
fn py_float(x: f64) -> String {
    if x.is_nan() {
        "nan".to_string()
    } else if x.is_infinite() {
        if x > 0.0 { "inf" } else { "-inf" }.to_string()
    } else {
        format!("{x:?}")
    }
}

/// The residual `b` of (A1) without the share of the load stiction carries.
///
/// At rest a joint's friction carries any share of the load up to its static level, so the
/// residual at rest is the model's error *plus* that share; once the joint slides the share
/// is gone, and a `b` that kept it reads as a hand pushing along the motion: the arm runs
/// away (1 m in 5 s on the virtual cell with stiction). The probe moves every joint out to
/// one side, back, out to the other side and back, a trapezoid of velocity per quarter
/// (`speed_rad_s` per joint for most of it, ramps of :data:`PROBE_RAMP_S`, `duration_s`
/// in all, back where it started): the residual on the samples that slid at cruise speed (the
/// command that drove them had no acceleration, and the joint moved the commanded way faster
/// than `slide_rad_s`) is the model's error minus the friction at that speed one way and
/// plus it the other way, so the mean of the two sides' medians is the model's error alone
/// (friction taken as symmetric). Each way is sampled as much on either side of the start, so
/// a hand holding the tool on a spring (the painter's grip) pulls as much one way as the
/// other and cancels too; the first probe, out and back on one side only, took the grip's
/// pull into b (-5 N·m on J2 and J3 on the teach bench). A joint with
/// fewer than :data:`PROBE_MIN_SAMPLES` on a side keeps the residual at rest beyond its
/// friction level.
#[derive(Clone, Debug)]
pub struct EngageProbe {
    n: usize,
    slide_rad_s: f64,
    /// Per probe sample: +1 / −1 at cruise that way (no acceleration), 0 elsewhere.
    cruise: Vec<f64>,
    /// Per probe sample, row-major by joint: the velocity command [rad/s].
    velocity: Vec<f64>,
    /// Per probe sample, row-major by joint: the offset from the start [rad] (the sum of the
    /// velocities before it times the period: back to 0 at the end).
    offset: Vec<f64>,
    /// Per joint, the residuals [N·m] sliding + (index 2 j) and − (2 j + 1), capacity for
    /// every cruise sample that way (observing a sample twice grows them, as in Python).
    sides: Vec<Vec<f64>>,
}

impl EngageProbe {
    /// `speed_rad_s` the cruise speed per joint, `duration_s` the whole probe, `period_s`
    /// the cycle, `slide_rad_s` the speed beyond which a joint slides. Err where the length
    /// `max(2, round(duration / 4 period))` per quarter is not a number or too long.
    pub fn new(
        speed_rad_s: &[f64],
        duration_s: f64,
        period_s: f64,
        slide_rad_s: f64,
    ) -> Result<EngageProbe, String> {
        let n = speed_rad_s.len();
        if n > MAX_JOINTS {
            return Err(format!(
                "engage probe speed_rad_s has {n} joints, at most {MAX_JOINTS}"
            ));
        }
        let ratio = (0.25 * duration_s / period_s).round_ties_even();
        if !ratio.is_finite() {
            return Err(format!(
                "engage probe duration_s {} over period_s {}: not a number of samples",
                py_float(duration_s),
                py_float(period_s)
            ));
        }
        if ratio > ((PROBE_MAX_SAMPLES - 1) / 4) as f64 {
            return Err(format!(
                "engage probe duration_s {} over period_s {}: more than {PROBE_MAX_SAMPLES} \
                 samples",
                py_float(duration_s),
                py_float(period_s)
            ));
        }
        let quarter = (ratio.max(2.0)) as usize;
        let ramp = if period_s > PROBE_RAMP_S {
            period_s
        } else {
            PROBE_RAMP_S
        };
        let len = 4 * quarter + 1;
        let span = quarter as f64 * period_s;
        let up: Vec<f64> = (0..quarter)
            .map(|i| {
                let t = i as f64 * period_s;
                np_clip(np_min(t / ramp, (span - t) / ramp), 0.0, 1.0)
            })
            .collect();
        let mut shape = Vec::with_capacity(len);
        shape.extend(up.iter().copied());
        shape.extend(up.iter().map(|u| -u));
        shape.extend(up.iter().map(|u| -u));
        shape.extend(up.iter().copied());
        shape.push(0.0);
        let mut cruise = vec![0.0; len];
        for k in 1..len {
            let same = if shape[k] == shape[k - 1] { 1.0 } else { 0.0 };
            cruise[k] = same * np_sign(shape[k]);
        }
        let mut velocity = vec![0.0; len * n];
        for (k, s) in shape.iter().enumerate() {
            for (j, v) in speed_rad_s.iter().enumerate() {
                velocity[k * n + j] = s * v;
            }
        }
        let mut offset = vec![0.0; len * n];
        for j in 0..n {
            let mut sum = 0.0;
            for k in 1..len {
                sum += velocity[(k - 1) * n + j];
                offset[k * n + j] = sum * period_s;
            }
        }
        let positive = cruise.iter().filter(|&&w| w > 0.0).count();
        let negative = cruise.iter().filter(|&&w| w != 0.0).count() - positive;
        let sides = (0..2 * n)
            .map(|i| Vec::with_capacity(if i % 2 == 0 { positive } else { negative }))
            .collect();
        Ok(EngageProbe {
            n,
            slide_rad_s,
            cruise,
            velocity,
            offset,
            sides,
        })
    }

    pub fn n(&self) -> usize {
        self.n
    }
    /// The number of probe samples (commands).
    pub fn len(&self) -> usize {
        self.cruise.len()
    }
    pub fn is_empty(&self) -> bool {
        self.cruise.is_empty()
    }
    pub fn slide_rad_s(&self) -> f64 {
        self.slide_rad_s
    }
    pub fn cruise(&self) -> &[f64] {
        &self.cruise
    }
    /// Sample `k`'s velocity command per joint [rad/s].
    pub fn velocity(&self, k: usize) -> &[f64] {
        &self.velocity[k * self.n..(k + 1) * self.n]
    }
    /// Sample `k`'s offset from the start per joint [rad].
    pub fn offset(&self, k: usize) -> &[f64] {
        &self.offset[k * self.n..(k + 1) * self.n]
    }

    /// The state measured over the cycle the probe's sample `k` drove: its velocity and the
    /// residual `model(q, 0, q̈) − K i` (no friction in the model's part). A sample out of
    /// range or not at cruise is ignored.
    pub fn observe(&mut self, k: usize, dq_rad_s: &[f64], residual_nm: &[f64]) {
        if k >= self.cruise.len() || self.cruise[k] == 0.0 {
            return;
        }
        let way = self.cruise[k];
        let side = if way > 0.0 { 0 } else { 1 };
        for j in 0..self.n {
            if way * dq_rad_s[j] > self.slide_rad_s {
                self.sides[2 * j + side].push(residual_nm[j]);
            }
        }
    }

    /// Joint `j`'s (samples sliding +, samples sliding −).
    pub fn samples(&self, j: usize) -> (usize, usize) {
        (self.sides[2 * j].len(), self.sides[2 * j + 1].len())
    }

    /// `b` per joint into `b_nm`, and per joint whether it did not slide both ways (too few
    /// samples) into `kept`: theirs is the residual at rest `at_rest_nm` less what friction
    /// may have carried there, `stick_nm` (towards 0). Sorts the samples in place (their
    /// order means nothing).
    pub fn bias(
        &mut self,
        at_rest_nm: &[f64],
        stick_nm: &[f64],
        b_nm: &mut [f64],
        kept: &mut [bool],
    ) {
        for j in 0..self.n {
            let at_rest = at_rest_nm[j];
            b_nm[j] = np_sign(at_rest) * np_max(at_rest.abs() - stick_nm[j], 0.0);
            let (pos, neg) = self.sides.split_at_mut(2 * j + 1);
            let (pos, neg) = (&mut pos[2 * j], &mut neg[0]);
            kept[j] = pos.len().min(neg.len()) < PROBE_MIN_SAMPLES;
            if !kept[j] {
                b_nm[j] = 0.5 * (median(pos) + median(neg));
            }
        }
    }
}

/// numpy's `median`: NaN with a NaN in it, the mean of the middle two for an even count.
/// Sorts `x` in place.
fn median(x: &mut [f64]) -> f64 {
    if x.iter().any(|v| v.is_nan()) {
        return f64::NAN;
    }
    x.sort_unstable_by(f64::total_cmp);
    let m = x.len() / 2;
    if x.len() % 2 == 1 {
        x[m]
    } else {
        (x[m - 1] + x[m]) / 2.0
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const N: usize = 6;
    const DT: f64 = 0.004;

    fn law(rest_factor: f64) -> Admittance {
        Admittance::new(0.5, &[20.0; N], &[2.0; N], 5.0, &[1.0; N], rest_factor).unwrap()
    }

    fn diag(d: &[f64]) -> Vec<f64> {
        let n = d.len();
        let mut m = vec![0.0; n * n];
        for (i, v) in d.iter().enumerate() {
            m[i * n + i] = *v;
        }
        m
    }

    /// Uniform in [lo, hi) from a 64-bit xorshift (the tests need no statistics, only spread).
    struct Rng(u64);
    impl Rng {
        fn uniform(&mut self, lo: f64, hi: f64) -> f64 {
            self.0 ^= self.0 << 13;
            self.0 ^= self.0 >> 7;
            self.0 ^= self.0 << 17;
            lo + (hi - lo) * (self.0 >> 11) as f64 / (1u64 << 53) as f64
        }
    }

    #[test]
    fn a_hand_torque_inside_the_dead_zone_leaves_the_arm_where_it_is() {
        let mut a = law(1.0);
        let q0: Vec<f64> = (0..N).map(|i| -0.3 + 0.12 * i as f64).collect();
        a.reset(&q0, None);
        let mass = diag(&[50.0, 200.0, 80.0, 1.0, 1.0, 0.3]);
        let mut rng = Rng(0x9e37_79b9_7f4a_7c15);
        for _ in 0..2000 {
            let raw: Vec<f64> = (0..N).map(|_| rng.uniform(-1.9, 1.9)).collect();
            a.step(&raw, &[0.0; N], &mass, DT, None).unwrap();
        }
        assert_eq!(a.q_r(), &q0[..]);
        assert_eq!(a.dq_r(), &[0.0; N]);
        assert!(!a.moving());
    }

    #[test]
    fn a_steady_push_reaches_the_speed_the_damping_allows_beyond_the_band() {
        let mut a = law(1.0);
        a.reset(&[0.0; N], None);
        let mass = diag(&[50.0, 40.0, 80.0, 1.0, 1.0, 0.3]);
        let push = [0.0, 12.0, 0.0, -4.0, 0.0, 0.0];
        for _ in 0..2000 {
            a.step(&push, &[0.0; N], &mass, DT, None).unwrap();
        }
        let want = [0.0, 0.5, 0.0, -0.1, 0.0, 0.0];
        for (v, w) in a.dq_r().iter().zip(want) {
            assert!((v - w).abs() < 0.005, "{:?}", a.dq_r());
        }
        assert!(a.q_r()[1] > 0.0 && a.q_r()[3] < 0.0 && a.q_r()[0] == 0.0);
    }

    #[test]
    fn the_implicit_damping_is_stable_at_any_step_and_the_speed_is_capped() {
        let mut a = Admittance::new(0.01, &[20.0; N], &[2.0; N], 5.0, &[0.5; N], 1.0).unwrap();
        a.reset(&[0.0; N], None);
        let mass = diag(&[1.0; N]);
        for dt in [0.004, 0.1, 1.0] {
            for _ in 0..50 {
                a.step(&[7.0; N], &[0.0; N], &mass, dt, None).unwrap();
                assert!(a.dq_r().iter().all(|v| v.abs() <= 0.5));
            }
        }
        a.reset(&[0.0; N], None);
        for _ in 0..500 {
            a.step(&[1e4; N], &[0.0; N], &mass, DT, None).unwrap();
        }
        assert_eq!(a.dq_r(), &[0.5; N]);
    }

    #[test]
    fn the_speed_limit_scales_the_proposed_speed_and_sees_the_old_reference() {
        let mut a = law(1.0);
        a.reset(&[0.1; N], None);
        let mass = diag(&[1.0; N]);
        let mut seen = (0.0, 0.0);
        let mut half = |q: &[f64], dq: &[f64]| {
            seen = (q[0], dq[0]);
            0.5
        };
        a.step(&[1e3; N], &[0.0; N], &mass, DT, Some(&mut half))
            .unwrap();
        assert_eq!(seen.0, 0.1);
        assert!(seen.1 > 0.0);
        assert_eq!(a.dq_r()[0], 0.5 * seen.1);
        assert_eq!(a.q_r()[0], 0.1 + DT * 0.5 * a.dq_r()[0]);
    }

    #[test]
    fn a_singular_system_is_refused_after_the_filter_took_the_sample_in() {
        let mut a = Admittance::new(0.5, &[0.0; 2], &[2.0; 2], 5.0, &[1.0; 2], 1.0).unwrap();
        a.reset(&[0.0; 2], None);
        let err = a.step(&[5.0, 0.0], &[0.0; 2], &[0.0; 4], DT, None);
        assert_eq!(err, Err("Singular matrix".to_string()));
        assert!(a.tau_h()[0] > 0.0);
    }

    #[test]
    fn the_solve_pivots_as_lapack_does() {
        // a zero on the first diagonal needs a row swap
        let mut m = vec![0.0, 2.0, 1.0, 3.0, 1.0, 0.0, 1.0, 1.0, 4.0];
        let x = [1.0, -2.0, 0.5];
        let mut b: Vec<f64> = (0..3)
            .map(|i| (0..3).map(|j| m[i * 3 + j] * x[j]).sum())
            .collect();
        solve_in_place(&mut m, &mut b, 3).unwrap();
        for (v, w) in b.iter().zip(x) {
            assert!((v - w).abs() < 1e-14, "{b:?}");
        }
    }

    #[test]
    fn bad_settings_are_refused() {
        let ok = [1.0; N];
        assert!(Admittance::new(0.0, &ok, &ok, 5.0, &ok, 1.0).is_err());
        assert!(Admittance::new(0.5, &ok, &ok, f64::NAN, &ok, 1.0).is_err());
        assert!(Admittance::new(0.5, &ok, &ok[..5], 5.0, &ok, 1.0).is_err());
        assert!(Admittance::new(0.5, &[-1.0; N], &ok, 5.0, &ok, 1.0).is_err());
        assert!(Admittance::new(0.5, &ok, &ok, 5.0, &[0.0; N], 1.0).is_err());
        assert!(Admittance::new(0.5, &ok, &ok, 5.0, &ok, 0.5).is_err());
        assert!(Admittance::new(0.5, &[1.0; 17], &[1.0; 17], 5.0, &[1.0; 17], 1.0).is_err());
        let err = Admittance::new(3.0, &ok, &ok, 5.0, &ok, 1.0).unwrap_err();
        assert_eq!(err, "admittance mass fraction 3.0 not in (0, 2]");
    }

    #[test]
    fn a_guided_arm_that_only_creeps_settles_and_then_needs_the_static_zone_again() {
        let mut a = law(10.0);
        a.reset(&[0.0; N], Some(&[5.0 / 3.5; N]));
        assert!(a.band().iter().all(|b| (b - 5.0).abs() < 1e-12));
        let mass = diag(&[20.0; N]);
        let mut push = [0.0; N];
        push[1] = 6.0;
        for _ in 0..250 {
            a.step(&push, &[0.0; N], &mass, DT, None).unwrap();
        }
        assert!(a.moving() && a.dq_r()[1] > 0.05);
        push[1] = 2.2;
        let mut steps = 0;
        while a.moving() && steps < 2000 {
            a.step(&push, &[0.0; N], &mass, DT, None).unwrap();
            steps += 1;
        }
        assert!(!a.moving(), "the creep kept the arm guided");
        assert!(steps as f64 * DT < 2.0 + SETTLE_S);
        for _ in 0..500 {
            a.step(&push, &[0.0; N], &mass, DT, None).unwrap();
        }
        assert!(a.dq_r()[1].abs() < 1e-9);
    }

    #[test]
    fn numpy_lets_nan_through_where_rust_would_not() {
        assert!(np_max(f64::NAN, 1.0).is_nan() && np_max(1.0, f64::NAN).is_nan());
        assert!(np_min(f64::NAN, 1.0).is_nan() && np_clip(f64::NAN, -1.0, 1.0).is_nan());
        assert!(np_sign(f64::NAN).is_nan());
        assert_eq!(np_sign(-0.0).to_bits(), 0.0f64.to_bits());
        assert!(median(&mut [1.0, f64::NAN, 2.0]).is_nan());
        assert_eq!(median(&mut [3.0, 1.0, 2.0, 10.0]), 2.5);
    }

    #[test]
    fn the_probe_goes_out_both_ways_and_back_to_where_it_started() {
        let p = EngageProbe::new(&[0.01, 0.02], 0.5, DT, 2e-3).unwrap();
        assert_eq!(p.len(), 4 * 31 + 1);
        let last = p.offset(p.len() - 1);
        assert!(last.iter().all(|v| v.abs() < 1e-15), "{last:?}");
        let out: Vec<f64> = (0..p.len()).map(|k| p.offset(k)[0]).collect();
        let (hi, lo) = out
            .iter()
            .fold((0.0f64, 0.0f64), |(h, l), &v| (h.max(v), l.min(v)));
        assert!((hi + lo).abs() < 1e-15 && hi < 0.01 * 0.125 + 1e-12);
        assert_eq!(p.velocity(15), &[0.01, 0.02]);
        // cruise: + in the first and last quarters, − in the middle two, none on the ramps
        assert_eq!(
            (p.cruise()[0], p.cruise()[15], p.cruise()[46]),
            (0.0, 1.0, -1.0)
        );
        assert_eq!(p.cruise()[1], 0.0);
        // Python's round: half to even (0.25 × 0.1 / 0.01 = 2.5 → 2)
        assert_eq!(EngageProbe::new(&[0.01], 0.1, 0.01, 0.0).unwrap().len(), 9);
        assert!(EngageProbe::new(&[0.01], 0.5, 0.0, 0.0).is_err());
        assert!(EngageProbe::new(&[0.01], f64::NAN, DT, 0.0).is_err());
        assert!(EngageProbe::new(&[0.01], 1e12, DT, 0.0).is_err());
    }

    #[test]
    fn the_probe_bias_is_the_mean_of_the_two_medians_or_the_rest_beyond_friction() {
        let mut p = EngageProbe::new(&[0.01, 0.01], 0.5, DT, 2e-3).unwrap();
        for k in 0..p.len() {
            let way = p.cruise()[k];
            let r = if way > 0.0 {
                -26.0 + k as f64 * 1e-3
            } else {
                34.0
            };
            p.observe(k, &[way * 0.01, 0.0], &[r, 7.0]);
        }
        p.observe(usize::MAX, &[0.01, 0.0], &[0.0, 0.0]);
        let (pos, neg) = p.samples(0);
        assert!(pos.min(neg) >= PROBE_MIN_SAMPLES);
        assert_eq!(p.samples(1), (0, 0));
        let (mut b, mut kept) = ([0.0; 2], [false; 2]);
        p.bias(&[29.0, 7.0], &[30.0, 5.0], &mut b, &mut kept);
        let plus: Vec<f64> = (0..p.len())
            .filter(|&k| p.cruise()[k] > 0.0)
            .map(|k| -26.0 + k as f64 * 1e-3)
            .collect();
        let mut sorted = plus.clone();
        let want = 0.5 * (median(&mut sorted) + 34.0);
        assert_eq!(b[0], want);
        assert_eq!(kept, [false, true]);
        assert_eq!(b[1], 2.0);
    }
}
