//! The motor-current sensors' zero, measured while the drives are unpowered (reading and
//! writing `current_zero.json` stays in Python, gateway/current_zero_file.py, which hands the
//! stored zero to the constructor).
//!
//! A drive's current sensor reads a small constant offset (typically within 0.5 % of its
//! range) in every current it reports, the servo on or off. With the servo power off no
//! current flows (brakes engaged, or released for the servo-off baseline), so what the drive
//! reports then is its offset plus noise. [`CurrentZero`] averages the newest `window` such
//! cycles, after skipping `settle` cycles once the power went off (a drive's current filter
//! still holds the last powered ticks), and freezes while the power is on. The driver
//! subtracts it from every current it publishes, so identification, the control law and
//! recordings see the motor's current, and reports it in its health. It first requests the
//! servo power once the window is full ([`CurrentZero::ready`]): a zero from a handful of
//! cycles would be off by the current noise over their root, a constant torque error that the
//! zero-moment loop turns into a creeping wrist (at 0.02 A noise, 20 cycles leave 0.0045 A,
//! 0.05 N·m on J5 of the GR630ST; 250 cycles 0.0013 A).
//!
//! The zero of the commissioning (`stored`), when given, is used from the start instead: the
//! dynamic model was identified with it. The running mean then only watches it; a drift
//! beyond what the noise of the two means explains ([`DRIFT_SIGMAS`]) means the sensors
//! changed since the commissioning.

/// A fresh zero this many standard errors (of the two means' difference) from the stored
/// one is a drift, not noise.
pub const DRIFT_SIGMAS: f64 = 5.0;

/// Running mean of the currents reported while the servo power is off (module docs). All of
/// its state is allocated at construction; [`CurrentZero::update`] and
/// [`CurrentZero::correct`] never allocate.
#[derive(Clone, Debug)]
pub struct CurrentZero {
    /// cycles in the mean when full; 0 disables the measurement
    pub window: usize,
    /// unpowered cycles skipped before the mean takes one
    pub settle: usize,
    /// cycles in the mean (<= window)
    pub samples: usize,
    /// the running mean of the newest unpowered cycles [A], one per joint
    pub measured_a: Vec<f64>,
    /// the commissioning's zero: (zero [A], samples, per-cycle noise [A])
    pub stored: Option<(Vec<f64>, i64, Vec<f64>)>,
    /// the current sensors' zero [A], one per joint: what [`CurrentZero::correct`] subtracts
    pub offset_a: Vec<f64>,
    /// the zero can be used: the window was full once, or the commissioning's is loaded
    pub ready: bool,
    joints: usize,
    /// the newest `window` unpowered cycles, row-major (max(window, 1) × joints) [A]
    ring: Vec<f64>,
    /// their sum per joint [A]
    sum: Vec<f64>,
    next: usize,
    off_cycles: u64,
}

impl CurrentZero {
    /// The zero of `joints` sensors over `window` cycles after `settle` [cycles]; `stored`
    /// the commissioning's (zero [A], samples, per-cycle noise [A]), as Python's
    /// `read_stored_zero` returns it. Err (Python's ValueError) for a negative size, or a
    /// stored zero whose vectors are not one per joint or whose samples are < 1.
    pub fn new(
        joints: usize,
        window: i64,
        settle: i64,
        stored: Option<(Vec<f64>, i64, Vec<f64>)>,
    ) -> Result<CurrentZero, String> {
        if window < 0 || settle < 0 {
            return Err(format!("window {window} and settle {settle} must be >= 0"));
        }
        if let Some((zero, samples, noise)) = &stored {
            if zero.len() != joints || noise.len() != joints || *samples < 1 {
                return Err(format!(
                    "the stored zero has {} values, {} noise values and {samples} samples; \
                     want {joints}, {joints} and >= 1",
                    zero.len(),
                    noise.len()
                ));
            }
        }
        let window = window as usize;
        let offset_a = match &stored {
            Some((zero, _, _)) => zero.clone(),
            None => vec![0.0; joints],
        };
        Ok(CurrentZero {
            window,
            settle: settle as usize,
            samples: 0,
            measured_a: vec![0.0; joints],
            ready: window == 0 || stored.is_some(),
            stored,
            offset_a,
            joints,
            ring: vec![0.0; window.max(1) * joints],
            sum: vec![0.0; joints],
            next: 0,
            off_cycles: 0,
        })
    }

    /// Where [`CurrentZero::offset_a`] comes from: "commissioning", "measured" or "off".
    pub fn source(&self) -> &'static str {
        if self.stored.is_some() {
            "commissioning"
        } else if self.window > 0 {
            "measured"
        } else {
            "off"
        }
    }

    /// Per-cycle standard deviation (ddof 1) of the unpowered currents in the window [A],
    /// one per joint (zeros below 2 samples). Allocates: for the health, not the cycle.
    pub fn noise_a(&self) -> Vec<f64> {
        let mut out = vec![0.0; self.joints];
        if self.samples < 2 {
            return out;
        }
        let rows = || self.ring[..self.samples * self.joints].chunks_exact(self.joints);
        for (j, o) in out.iter_mut().enumerate() {
            let mean = rows().map(|r| r[j]).sum::<f64>() / self.samples as f64;
            let ss: f64 = rows().map(|r| (r[j] - mean) * (r[j] - mean)).sum();
            *o = (ss / (self.samples - 1) as f64).sqrt();
        }
        out
    }

    /// Fresh zero less the stored one [A] once the window is full (None before, or with no
    /// stored zero). Allocates: for the health, not the cycle.
    pub fn drift_a(&self) -> Option<Vec<f64>> {
        let (zero, _, _) = self.stored.as_ref()?;
        if self.samples < self.window || self.window == 0 {
            return None;
        }
        Some(
            self.measured_a
                .iter()
                .zip(zero)
                .map(|(m, z)| m - z)
                .collect(),
        )
    }

    /// The fresh zero differs from the stored one by more than [`DRIFT_SIGMAS`] standard
    /// errors of the two means on some joint (`noise_a`: [`CurrentZero::noise_a`], when the
    /// caller has it already).
    pub fn drift_significant(&self, noise_a: Option<&[f64]>) -> bool {
        let (Some(drift), Some((_, n_stored, noise_stored))) = (self.drift_a(), &self.stored)
        else {
            return false;
        };
        let own;
        let noise = match noise_a {
            Some(n) => n,
            None => {
                own = self.noise_a();
                &own
            }
        };
        (0..self.joints).any(|j| {
            let se = (noise_stored[j].powi(2) / *n_stored as f64
                + noise[j].powi(2) / self.samples as f64)
                .sqrt();
            drift[j].abs() > DRIFT_SIGMAS * se.max(1e-12)
        })
    }

    /// Take one cycle's reported currents `current_a` [A] and whether the servo power was on.
    pub fn update(&mut self, current_a: &[f64], servo_power: bool) {
        if servo_power || self.window == 0 {
            self.off_cycles = 0;
            return;
        }
        self.off_cycles += 1;
        let n = self.joints;
        if self.off_cycles <= self.settle as u64
            || current_a.len() < n
            || !current_a[..n].iter().all(|v| v.is_finite())
        {
            return;
        }
        let row = &mut self.ring[self.next * n..(self.next + 1) * n];
        if self.samples == self.window {
            for (s, old) in self.sum.iter_mut().zip(row.iter()) {
                *s -= old;
            }
        } else {
            self.samples += 1;
        }
        row.copy_from_slice(&current_a[..n]);
        for (s, c) in self.sum.iter_mut().zip(&current_a[..n]) {
            *s += c;
        }
        self.next = (self.next + 1) % self.window;
        for (m, s) in self.measured_a.iter_mut().zip(&self.sum) {
            *m = s / self.samples as f64;
        }
        if self.stored.is_none() {
            self.offset_a.copy_from_slice(&self.measured_a);
        }
        self.ready = self.ready || self.samples == self.window;
    }

    /// The motor's current [A] into `out`: `current_a` less the sensors' zero (Python returns
    /// a new array; here the caller's).
    pub fn correct(&self, current_a: &[f64], out: &mut [f64]) {
        for ((o, c), z) in out.iter_mut().zip(current_a).zip(&self.offset_a) {
            *o = c - z;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn close(a: &[f64], b: &[f64], tol: f64) -> bool {
        a.len() == b.len() && a.iter().zip(b).all(|(x, y)| (x - y).abs() <= tol)
    }

    /// A reproducible normal sample (Box-Muller on a 64-bit LCG): the test's noise.
    struct Noise(u64);

    impl Noise {
        fn uniform(&mut self) -> f64 {
            self.0 = self
                .0
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            ((self.0 >> 11) as f64 + 0.5) / (1u64 << 53) as f64
        }

        fn normal(&mut self) -> f64 {
            let (u, v) = (self.uniform(), self.uniform());
            (-2.0 * u.ln()).sqrt() * (2.0 * std::f64::consts::PI * v).cos()
        }
    }

    #[test]
    fn the_zero_is_the_mean_of_the_newest_unpowered_cycles_after_settling() {
        let mut z = CurrentZero::new(2, 3, 1, None).unwrap();
        z.update(&[5.0, 5.0], false); // settling: the filter's powered ticks
        assert!(z.samples == 0 && z.offset_a.iter().all(|v| *v == 0.0));
        for v in [1.0, 2.0, 3.0, 4.0] {
            z.update(&[v, -v], false);
        }
        assert!(close(&z.offset_a, &[3.0, -3.0], 1e-12), "the newest three");
        z.update(&[100.0, 100.0], true);
        let mut out = [0.0; 2];
        z.correct(&[10.0, 0.0], &mut out);
        assert!(close(&out, &[7.0, 3.0], 1e-12));
        z.update(&[100.0, 100.0], false); // settling again after power-off
        assert!(close(&z.offset_a, &[3.0, -3.0], 1e-12));
        z.update(&[f64::NAN, 0.0], false); // a NaN never enters the mean
        assert!(close(&z.offset_a, &[3.0, -3.0], 1e-12));
    }

    #[test]
    fn a_zero_window_disables_it_and_negative_sizes_are_refused() {
        let mut z = CurrentZero::new(1, 0, 0, None).unwrap();
        z.update(&[0.5], false);
        let mut out = [0.0];
        z.correct(&[1.0], &mut out);
        assert_eq!((z.samples, out[0]), (0, 1.0));
        assert!(CurrentZero::new(1, -1, 0, None)
            .unwrap_err()
            .contains("window"));
        assert!(CurrentZero::new(2, 4, 0, Some((vec![0.1], 250, vec![0.0, 0.0]))).is_err());
    }

    #[test]
    fn the_commissioning_zero_is_used_at_once_and_a_fresh_one_only_watches_it() {
        let stored = (vec![0.1, -0.2], 250, vec![0.02, 0.02]);
        let mut z = CurrentZero::new(2, 4, 0, Some(stored)).unwrap();
        assert!(z.ready && z.source() == "commissioning");
        let mut out = [0.0; 2];
        z.correct(&[1.0, 1.0], &mut out);
        assert!(close(&out, &[0.9, 1.2], 1e-12));
        let mut rng = Noise(3);
        for _ in 0..4 {
            // the same offsets again, measured with noise
            z.update(
                &[0.1 + 0.02 * rng.normal(), -0.2 + 0.02 * rng.normal()],
                false,
            );
        }
        assert!(
            close(&z.offset_a, &[0.1, -0.2], 0.0),
            "still the commissioning's"
        );
        let drift = z.drift_a().unwrap();
        assert!(drift.iter().all(|d| d.abs() < 0.06), "{drift:?}");
        assert!(!z.drift_significant(None));
        for _ in 0..4 {
            // the sensors changed: 0.1 A more on joint 2
            z.update(
                &[0.1 + 0.002 * rng.normal(), -0.1 + 0.002 * rng.normal()],
                false,
            );
        }
        assert!(close(&z.measured_a, &[0.1, -0.1], 0.01));
        assert!(close(&z.offset_a, &[0.1, -0.2], 0.0));
        assert!(z.drift_significant(None));
        assert!(z.drift_significant(Some(&z.noise_a())));
    }

    #[test]
    fn a_measured_zero_has_no_drift_and_an_off_zero_says_so() {
        let mut z = CurrentZero::new(1, 2, 0, None).unwrap();
        assert!(z.source() == "measured" && !z.ready && z.drift_a().is_none());
        z.update(&[0.3], false);
        z.update(&[0.5], false);
        assert!(z.ready && z.drift_a().is_none() && !z.drift_significant(None));
        // np.std([0.3, 0.5], ddof=1)
        assert!(close(&z.noise_a(), &[0.1414213562373095], 1e-15));
        assert_eq!(CurrentZero::new(1, 0, 0, None).unwrap().source(), "off");
    }
}
