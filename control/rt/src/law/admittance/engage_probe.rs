//! The admittance's engagement probe (admittance.rs): the residual `b` of (A1), measured
//! by moving every joint out and back both ways, without the share of the load stiction
//! carries at rest.

use super::numpy_semantics::{median, np_clip, np_max, np_min, np_sign, py_float};
use crate::chain::MAX_JOINTS;

/// The engagement probe's ramps to and from its cruise speed [s].
pub const PROBE_RAMP_S: f64 = 0.05;
/// A probe side needs this many sliding cruise samples for its median.
pub const PROBE_MIN_SAMPLES: usize = 3;
/// The most samples a probe may have (4 quarters and the final stop); numpy would try to
/// allocate any length, this refuses a length no cell could mean.
pub const PROBE_MAX_SAMPLES: usize = 100_000_000;

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
