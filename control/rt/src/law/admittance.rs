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
//! at the edge of the band creeps `rest_factor` times slower. (A2) couples the joints through
//! M̂, so one joint's deceleration moves the others' references with no push on them, and a
//! joint stuck under a reference creeping at a few mrad/s sticks and slips: with hold speeds
//! per joint ([`Admittance::set_hold`]), once no joint's estimate exceeds its static band a
//! joint whose reference is slower than its own hold speed is held, its row of (A2) asking for
//! speed 0, until a push exceeds a static band again. The command sent is the reference
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
//! allocated in `new`; the per-cycle methods allocate nothing. Its cycle (the engagement, the
//! probe, the stick zone or anchor, the walls, the guide, the speed limit, the command) is
//! [`cycle::AdmittanceCycle`], which the control process's compiled loop runs.

use crate::chain::MAX_JOINTS;

mod constraint;
pub mod cycle;
mod engage_probe;
mod numpy_semantics;
pub mod soft_walls;
pub mod startup_dither;
pub mod stick_anchor;

pub use self::constraint::MAX_ROWS;
use self::constraint::{project, ProjectWork};

pub use self::engage_probe::{EngageProbe, PROBE_MAX_SAMPLES, PROBE_MIN_SAMPLES, PROBE_RAMP_S};
use self::numpy_semantics::{np_clip, np_max, np_min, np_sign, py_float, solve_in_place};

/// The dead zone is at least this many standard deviations of the filtered estimate's noise
/// at rest: a Gaussian sample passes 3.5 σ once in ~2,000 (about every 10 s at 250 Hz).
pub const NOISE_SIGMAS: f64 = 3.5;
/// A guided arm whose reference has been slower than this on every joint [rad/s] for
/// [`SETTLE_S`] is at rest again (it needs the static dead zone to break away).
pub const SETTLE_RAD_S: f64 = 2e-3;
/// See [`SETTLE_RAD_S`] [s].
pub const SETTLE_S: f64 = 0.3;

/// The low-pass's coefficient for one step of `dt_s`: exact first order at `filter_hz`.
fn filter_coefficient(filter_hz: f64, dt_s: f64) -> f64 {
    1.0 - (-2.0 * std::f64::consts::PI * filter_hz * dt_s).exp()
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
    /// Per joint, the hold speed (0: never held) [rad/s]: [`Admittance::update_held`].
    hold_rad_s: Vec<f64>,
    /// The joints held ([`Admittance::held`]).
    held: Vec<bool>,
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
    /// Constrained guiding ([`Admittance::set_constraint`]): the guide's rows on the
    /// reference's speed (row-major, `guide_m` × n, then one per held joint while a step
    /// projects), their rates, the step's matrix without the held rows, the projection's work.
    c_rows: Vec<f64>,
    c_rates: Vec<f64>,
    guide_m: usize,
    metric: Vec<f64>,
    project_work: ProjectWork,
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
            hold_rad_s: vec![0.0; n],
            held: vec![false; n],
            q_r: vec![0.0; n],
            dq_r: vec![0.0; n],
            ddq_r: vec![0.0; n],
            tau_h: vec![0.0; n],
            pushed: vec![0.0; n],
            dq_new: vec![0.0; n],
            lhs: vec![0.0; n * n],
            c_rows: vec![0.0; MAX_ROWS * n],
            c_rates: vec![0.0; MAX_ROWS],
            guide_m: 0,
            metric: vec![0.0; n * n],
            project_work: ProjectWork::default(),
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
    /// Per joint, the speed below which it is held once no push exceeds a static band
    /// [rad/s]; 0: that joint is never held ([`Admittance::update_held`]).
    pub fn hold_rad_s(&self) -> &[f64] {
        &self.hold_rad_s
    }
    /// Sets [`Admittance::hold_rad_s`]; Err unless one value per joint, each finite and >= 0.
    pub fn set_hold(&mut self, hold_rad_s: &[f64]) -> Result<(), String> {
        if hold_rad_s.len() != self.n {
            return Err(format!(
                "admittance hold speeds: {} values for {} joints",
                hold_rad_s.len(),
                self.n
            ));
        }
        if let Some(&bad) = hold_rad_s.iter().find(|v| !(v.is_finite() && **v >= 0.0)) {
            return Err(format!(
                "admittance hold speed {} must be >= 0",
                py_float(bad)
            ));
        }
        self.hold_rad_s.copy_from_slice(hold_rad_s);
        Ok(())
    }
    /// Constrained guiding: from the next step on, the reference's new speed meets `rows q̇ =
    /// rates` (`rows` row-major, one row of n per rate; at most 6 rows): the speed (A2) gives,
    /// projected in the step's own metric (admittance/constraint.rs), and a speed limit per
    /// joint scales every joint alike instead of clipping one. Err (the constraint unchanged)
    /// unless the sizes agree and every value is finite.
    pub fn set_constraint(&mut self, rows: &[f64], rates: &[f64]) -> Result<(), String> {
        let m = rates.len();
        if m > 6 || rows.len() != m * self.n {
            return Err(format!(
                "admittance constraint: {} values for {m} rows of {} joints (at most 6 rows)",
                rows.len(),
                self.n
            ));
        }
        if !rows.iter().chain(rates).all(|v| v.is_finite()) {
            return Err("admittance constraint: a row or rate is not finite".to_string());
        }
        self.c_rows[..rows.len()].copy_from_slice(rows);
        self.c_rates[..m].copy_from_slice(rates);
        self.guide_m = m;
        Ok(())
    }

    /// No constraint from the next step on (free guiding).
    pub fn clear_constraint(&mut self) {
        self.guide_m = 0;
    }

    /// Per joint: held, its reference still (none with [`Admittance::hold_rad_s`] 0).
    pub fn held(&self) -> &[bool] {
        &self.held
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
        for (held, &hold) in self.held.iter_mut().zip(&self.hold_rad_s) {
            *held = hold > 0.0;
        }
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
        self.update_held(tau_walls);
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
                self.metric[i * n + j] = self.lhs[i * n + j];
            }
            self.dq_new[i] = rhs + dt_s * drive;
        }
        // a held joint's reference stays still: the row asks for speed 0, and the other rows
        // then take it as 0 (the reduced system of the guided joints, the held ones'
        // constraint torques absorbing the coupling through M̂)
        for i in 0..n {
            if self.held[i] {
                for j in 0..n {
                    self.lhs[i * n + j] = if i == j { 1.0 } else { 0.0 };
                }
                self.dq_new[i] = 0.0;
            }
        }
        solve_in_place(&mut self.lhs, &mut self.dq_new, n)?;
        if self.guide_m > 0 {
            self.constrain()?;
            return Ok(());
        }
        for (v, &vmax) in self.dq_new.iter_mut().zip(&self.max_velocity) {
            *v = np_clip(*v, -vmax, vmax);
        }
        Ok(())
    }

    /// The guide's rows and a held joint's (its speed 0) on the new speed: the speed (A2)
    /// gave, projected in the step's metric α M̂ + dt D (admittance/constraint.rs), then
    /// scaled as a whole so that no joint exceeds its maximum (a clip per joint would turn
    /// the tool). Err (the speed unconstrained) where the metric is not positive definite.
    fn constrain(&mut self) -> Result<(), String> {
        let n = self.n;
        let mut m = self.guide_m;
        for i in 0..n {
            if self.held[i] {
                let row = &mut self.c_rows[m * n..(m + 1) * n];
                row.fill(0.0);
                row[i] = 1.0;
                self.c_rates[m] = 0.0;
                m += 1;
            }
        }
        project(
            &self.metric,
            &self.c_rows[..m * n],
            &self.c_rates[..m],
            n,
            m,
            &mut self.dq_new,
            &mut self.project_work,
        )?;
        let mut scale = 1.0f64;
        for (v, &vmax) in self.dq_new.iter().zip(&self.max_velocity) {
            if v.abs() > vmax {
                scale = scale.min(vmax / v.abs());
            }
        }
        for v in self.dq_new.iter_mut() {
            *v *= scale;
        }
        Ok(())
    }

    /// Per joint, with a hold speed: while some joint's estimate exceeds its static `band`
    /// (a hand pushes), every joint is guided, as without one (the reference's coupling
    /// through M̂ helps a stuck joint break away); once none does (the hand eases or lets
    /// go), a joint whose reference is slower than the hold speed is held, its reference
    /// still, so that no joint creeps on the others' deceleration. A joint a wall or a guide's
    /// fixture pushes beyond its kinetic band (`tau_walls`) is not held: they act as a hand.
    fn update_held(&mut self, tau_walls: &[f64]) {
        let active = self.moving && self.tau_h.iter().zip(&self.band).any(|(t, b)| t.abs() > *b);
        let joints = self
            .held
            .iter_mut()
            .zip(tau_walls)
            .zip(&self.base_band)
            .zip(&self.dq_r)
            .zip(&self.hold_rad_s);
        for ((((held, &wall), &band), &speed), &hold) in joints {
            let walled = wall.abs() > band;
            *held = if hold <= 0.0 || active || walled {
                false
            } else {
                *held || speed.abs() < hold
            };
        }
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

#[cfg(test)]
#[path = "admittance_tests.rs"]
mod tests;
