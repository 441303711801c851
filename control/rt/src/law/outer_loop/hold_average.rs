//! The drive's hold before the arm is released, averaged (outer_loop.rs): the mean held offset
//! and motor torque that calibrate ω̂, and the torque's noise at rest, summed as numpy sums.

use crate::chain::MAX_JOINTS;

/// numpy's `pairwise_sum` over `get(0..n)` (a float array's sum along a contiguous axis):
/// eight running sums below 128 values, halves above, plainly below 8.
pub(super) fn pairwise_sum(first: usize, n: usize, get: &impl Fn(usize) -> f64) -> f64 {
    if n < 8 {
        (first..first + n).fold(0.0, |acc, i| acc + get(i))
    } else if n <= 128 {
        let mut r = [0.0; 8];
        for (j, rj) in r.iter_mut().enumerate() {
            *rj = get(first + j);
        }
        let mut i = 8;
        while i < n - n % 8 {
            for (j, rj) in r.iter_mut().enumerate() {
                *rj += get(first + i + j);
            }
            i += 8;
        }
        let mut res = ((r[0] + r[1]) + (r[2] + r[3])) + ((r[4] + r[5]) + (r[6] + r[7]));
        for k in i..n {
            res += get(first + k);
        }
        res
    } else {
        let half = n / 2;
        let half = half - half % 8;
        pairwise_sum(first, half, get) + pairwise_sum(first + half, n - half, get)
    }
}

/// Mean held offset q_c - q and measured motor torque over the last `size` states of a drive
/// holding the arm at rest, for
/// [`OuterLoop::calibrate_from_hold`](super::OuterLoop::calibrate_from_hold) (one state's
/// current noise would set ω̂ of a lightly loaded wrist joint tens of per cent off). A ring of
/// rows, grown to `size` once and reused after [`HoldAverage::clear`].
#[derive(Clone, Debug)]
pub struct HoldAverage {
    size: usize,
    /// the joint count of the rows held (set by the first row after a clear)
    n: usize,
    /// rows held, at most `size`
    len: usize,
    /// the oldest row's index once the ring is full
    start: usize,
    /// per row: n offsets [rad] then n torques [N·m]
    rows: Vec<f64>,
}

impl HoldAverage {
    /// The default: the last 64 states.
    pub const SIZE: usize = 64;

    pub fn new(size: usize) -> HoldAverage {
        HoldAverage {
            size,
            n: 0,
            len: 0,
            start: 0,
            rows: Vec::new(),
        }
    }

    /// Add one held state: its offset q_c - q [rad] and motor torque [N·m] per joint, as many
    /// of each as the rows already held (any count up to [`MAX_JOINTS`] after a clear). The
    /// oldest row goes once `size` are held.
    pub fn add(&mut self, offset_rad: &[f64], tau_m_nm: &[f64]) -> Result<(), String> {
        let n = offset_rad.len();
        if tau_m_nm.len() != n {
            return Err(format!(
                "tau_m_nm needs {n} values (one per offset_rad), got {}",
                tau_m_nm.len()
            ));
        }
        if n > MAX_JOINTS {
            return Err(format!("offset_rad: at most {MAX_JOINTS} joints, got {n}"));
        }
        if self.len > 0 && n != self.n {
            return Err(format!(
                "offset_rad needs {} values (the held states'), got {n}",
                self.n
            ));
        }
        if self.size == 0 {
            return Ok(());
        }
        self.n = n;
        if self.len < self.size {
            self.rows.extend_from_slice(offset_rad);
            self.rows.extend_from_slice(tau_m_nm);
            self.len += 1;
        } else {
            let row = &mut self.rows[2 * n * self.start..2 * n * (self.start + 1)];
            row[..n].copy_from_slice(offset_rad);
            row[n..].copy_from_slice(tau_m_nm);
            self.start = (self.start + 1) % self.size;
        }
        Ok(())
    }

    pub fn clear(&mut self) {
        self.rows.clear();
        (self.len, self.start) = (0, 0);
    }

    /// The number of states held.
    pub fn len(&self) -> usize {
        self.len
    }

    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// The joint count of the states held (0 when empty).
    pub fn n(&self) -> usize {
        if self.len == 0 {
            0
        } else {
            self.n
        }
    }

    /// The held rows, oldest first: (offsets, torques).
    fn rows(&self) -> impl Iterator<Item = (&[f64], &[f64])> {
        let n = self.n;
        (0..self.len).map(move |i| {
            let k = (self.start + i) % self.len;
            self.rows[2 * n * k..2 * n * (k + 1)].split_at(n)
        })
    }

    /// Per joint, the sum over the held rows of `f(offset, torque)`, oldest first, as numpy
    /// sums a list of rows along axis 0: row after row, but pairwise for one joint (the
    /// column is then a contiguous array).
    fn sum_into(&self, out: &mut [f64], f: impl Fn(usize, &[f64], &[f64]) -> f64) {
        if self.n == 1 {
            let start = self.start;
            let get = |i: usize| {
                let k = (start + i) % self.len;
                f(
                    0,
                    &self.rows[2 * k..2 * k + 1],
                    &self.rows[2 * k + 1..2 * k + 2],
                )
            };
            out[0] = pairwise_sum(0, self.len, &get);
            return;
        }
        for (i, (offs, taus)) in self.rows().enumerate() {
            for (j, o) in out.iter_mut().enumerate() {
                let v = f(j, offs, taus);
                *o = if i == 0 { v } else { *o + v };
            }
        }
    }

    /// (offset [rad], torque [N·m]) averaged per joint (`np.mean(rows, axis=0)`), into
    /// [`HoldAverage::n`] values each; an error when empty.
    pub fn mean(&self, offset_rad: &mut [f64], tau_m_nm: &mut [f64]) -> Result<(), String> {
        if self.len == 0 {
            return Err("no hold observed".into());
        }
        let count = self.len as f64;
        self.sum_into(&mut offset_rad[..self.n], |j, offs, _| offs[j]);
        self.sum_into(&mut tau_m_nm[..self.n], |j, _, taus| taus[j]);
        for v in offset_rad[..self.n]
            .iter_mut()
            .chain(&mut tau_m_nm[..self.n])
        {
            *v /= count;
        }
        Ok(())
    }

    /// The held motor torque's standard deviation per joint [N·m] (its noise at rest;
    /// `np.std(rows, axis=0, ddof=1)`), into [`HoldAverage::n`] values; an error with fewer
    /// than two states.
    pub fn torque_std(&self, std_nm: &mut [f64]) -> Result<(), String> {
        if self.len < 2 {
            return Err("fewer than two held states".into());
        }
        let (n, count) = (self.n, self.len as f64);
        let mut mean = [0.0; MAX_JOINTS];
        self.sum_into(&mut mean[..n], |j, _, taus| taus[j]);
        for m in &mut mean[..n] {
            *m /= count;
        }
        self.sum_into(&mut std_nm[..n], |j, _, taus| {
            let d = taus[j] - mean[j];
            d * d
        });
        for s in &mut std_nm[..n] {
            *s = (*s / (count - 1.0)).sqrt();
        }
        Ok(())
    }
}
