//! `control._rt`'s online inner-loop estimate (law/inner_estimate.rs), as the control
//! process and the tests use it: `cycle_means(...)`, `InnerLoopEstimator` and the constant
//! `REJECT_SIGMA`. Per-joint results are lists of floats where Python returned numpy arrays
//! (`rel_std` a list of `[K_p, K_I]` pairs, `rejected` a list of ints). A wrong length or a bad
//! setting raises ValueError naming it.

use std::sync::{Mutex, MutexGuard};

use pyo3::exceptions::{PyRuntimeError, PyValueError};
use pyo3::prelude::*;

use crate::law::inner_estimate::{self as core, Cycle, InnerLoopEstimator, REJECT_SIGMA};

#[allow(clippy::too_many_arguments)]
fn cycle<'a>(
    q_cmd: &'a [f64],
    dq_cmd: &'a [f64],
    q_start: &'a [f64],
    q_end: &'a [f64],
    period_s: f64,
    dq_start: &'a Option<Vec<f64>>,
    dq_end: &'a Option<Vec<f64>>,
    ticks: i64,
) -> Cycle<'a> {
    Cycle {
        q_cmd_rad: q_cmd,
        dq_cmd_rad_s: dq_cmd,
        q_start_rad: q_start,
        q_end_rad: q_end,
        period_s,
        dq_start_end_rad_s: dq_start.as_deref().zip(dq_end.as_deref()),
        ticks,
    }
}

/// `(u₁, u₂)` = (mean(dq_c - dq) [rad/s], mean(q_c - q) [rad]) per joint over the cycle the
/// command (q_cmd, dq_cmd) drove, from the measured positions at its start and end; with the
/// drive's servo `ticks` per cycle and the measured velocities, the means its PI saw.
/// Non-finite inputs give non-finite means.
#[pyfunction]
#[pyo3(signature = (q_cmd, dq_cmd, q_start, q_end, period_s, dq_start=None, dq_end=None, ticks=0))]
#[allow(clippy::too_many_arguments)]
fn cycle_means(
    q_cmd: Vec<f64>,
    dq_cmd: Vec<f64>,
    q_start: Vec<f64>,
    q_end: Vec<f64>,
    period_s: f64,
    dq_start: Option<Vec<f64>>,
    dq_end: Option<Vec<f64>>,
    ticks: i64,
) -> PyResult<(Vec<f64>, Vec<f64>)> {
    let c = cycle(
        &q_cmd, &dq_cmd, &q_start, &q_end, period_s, &dq_start, &dq_end, ticks,
    );
    let (mut u1, mut u2) = (vec![0.0; c.n()], vec![0.0; c.n()]);
    core::cycle_means(&c, &mut u1, &mut u2).map_err(PyValueError::new_err)?;
    Ok((u1, u2))
}

/// Per-joint RLS on eq. (19) (law/inner_estimate.rs). Feed it one cycle at a time.
#[pyclass(frozen, name = "InnerLoopEstimator", module = "control._rt")]
pub struct PyInnerLoopEstimator {
    est: Mutex<InnerLoopEstimator>,
    n: usize,
}

impl PyInnerLoopEstimator {
    /// The lock without the GIL's error type (the compiled loop's thread).
    pub(crate) fn state_lock(
        &self,
    ) -> Result<
        MutexGuard<'_, InnerLoopEstimator>,
        std::sync::PoisonError<MutexGuard<'_, InnerLoopEstimator>>,
    > {
        self.est.lock()
    }

    pub(crate) fn lock(&self) -> PyResult<MutexGuard<'_, InnerLoopEstimator>> {
        self.est
            .lock()
            .map_err(|_| PyRuntimeError::new_err("the inner-loop estimate's lock is poisoned"))
    }

    fn per_joint(&self, f: impl Fn(&InnerLoopEstimator, &mut [f64])) -> PyResult<Vec<f64>> {
        let mut out = vec![0.0; self.n];
        f(&*self.lock()?, &mut out);
        Ok(out)
    }
}

#[pymethods]
impl PyInnerLoopEstimator {
    #[new]
    #[pyo3(signature = (kp0_a_s_per_rad, ki0_a_per_rad, drive_gain_nm_per_a, memory_s=30.0, prior_rel=1.0))]
    fn new(
        kp0_a_s_per_rad: Vec<f64>,
        ki0_a_per_rad: Vec<f64>,
        drive_gain_nm_per_a: Vec<f64>,
        memory_s: f64,
        prior_rel: f64,
    ) -> PyResult<Self> {
        let est = InnerLoopEstimator::new(
            &kp0_a_s_per_rad,
            &ki0_a_per_rad,
            &drive_gain_nm_per_a,
            memory_s,
            prior_rel,
        )
        .map_err(PyValueError::new_err)?;
        let n = est.n();
        Ok(PyInnerLoopEstimator {
            est: Mutex::new(est),
            n,
        })
    }

    /// One cycle the drive followed as sent: its command, the measured positions at the
    /// cycle's start and end [rad], the reported mean current [A], the cycle [s].
    #[pyo3(signature = (q_cmd, dq_cmd, q_start, q_end, current_a, period_s, noise_a=0.02, dq_start=None, dq_end=None, ticks=0))]
    #[allow(clippy::too_many_arguments)]
    fn update(
        &self,
        q_cmd: Vec<f64>,
        dq_cmd: Vec<f64>,
        q_start: Vec<f64>,
        q_end: Vec<f64>,
        current_a: Vec<f64>,
        period_s: f64,
        noise_a: f64,
        dq_start: Option<Vec<f64>>,
        dq_end: Option<Vec<f64>>,
        ticks: i64,
    ) -> PyResult<()> {
        let c = cycle(
            &q_cmd, &dq_cmd, &q_start, &q_end, period_s, &dq_start, &dq_end, ticks,
        );
        self.lock()?
            .update(&c, &current_a, noise_a)
            .map_err(PyValueError::new_err)?;
        Ok(())
    }

    #[getter]
    fn kp_hat_a_s_per_rad(&self) -> PyResult<Vec<f64>> {
        self.per_joint(InnerLoopEstimator::kp_hat_a_s_per_rad)
    }

    #[getter]
    fn ki_hat_a_per_rad(&self) -> PyResult<Vec<f64>> {
        self.per_joint(InnerLoopEstimator::ki_hat_a_per_rad)
    }

    /// ω̂ = 1/(K K̂_p) per joint (NaN where K̂_p is not positive).
    #[getter]
    fn omega_rad_s_per_nm(&self) -> PyResult<Vec<f64>> {
        self.per_joint(InnerLoopEstimator::omega_rad_s_per_nm)
    }

    /// Υ̂_I = K̂_I / K̂_p per joint (NaN where K̂_p is not positive).
    #[getter]
    fn upsilon_i_per_s(&self) -> PyResult<Vec<f64>> {
        self.per_joint(InnerLoopEstimator::upsilon_i_per_s)
    }

    /// Relative standard deviation of (K̂_p, K̂_I) per joint, n pairs, from the RLS covariance.
    #[getter]
    fn rel_std(&self) -> PyResult<Vec<Vec<f64>>> {
        let mut out = vec![[0.0; 2]; self.n];
        self.lock()?.rel_std(&mut out);
        Ok(out.iter().map(|r| r.to_vec()).collect())
    }

    /// Per joint, cycles whose residual was rejected as an outlier.
    #[getter]
    fn rejected(&self) -> PyResult<Vec<u64>> {
        Ok(self.lock()?.rejected().to_vec())
    }

    /// Time covered by the cycles taken [s].
    #[getter]
    fn seconds(&self) -> PyResult<f64> {
        Ok(self.lock()?.seconds())
    }

    /// Cycles taken (skipped ones excluded).
    #[getter]
    fn updates(&self) -> PyResult<u64> {
        Ok(self.lock()?.updates())
    }

    #[getter]
    fn memory_s(&self) -> PyResult<f64> {
        Ok(self.lock()?.memory_s())
    }

    /// The commissioned K_p0 [A·s/rad].
    #[getter]
    fn kp0(&self) -> PyResult<Vec<f64>> {
        Ok(self.lock()?.kp0_a_s_per_rad().to_vec())
    }

    /// The commissioned K_I0 [A/rad].
    #[getter]
    fn ki0(&self) -> PyResult<Vec<f64>> {
        Ok(self.lock()?.ki0_a_per_rad().to_vec())
    }

    /// The datasheet's torque constants K [N·m/A].
    #[getter]
    fn k(&self) -> PyResult<Vec<f64>> {
        Ok(self.lock()?.drive_gain_nm_per_a().to_vec())
    }

    /// `(K_p/K_p0, K_I/K_I0, b [A])` per joint.
    #[getter]
    fn theta(&self) -> PyResult<Vec<Vec<f64>>> {
        Ok(self.lock()?.theta().iter().map(|r| r.to_vec()).collect())
    }

    /// The RLS covariance per joint, n 3×3 matrices.
    #[getter]
    fn p(&self) -> PyResult<Vec<Vec<Vec<f64>>>> {
        let est = self.lock()?;
        Ok(est
            .p()
            .iter()
            .map(|m| m.iter().map(|r| r.to_vec()).collect())
            .collect())
    }
}

pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<PyInnerLoopEstimator>()?;
    m.add_function(wrap_pyfunction!(cycle_means, m)?)?;
    m.add("REJECT_SIGMA", REJECT_SIGMA)?;
    Ok(())
}
