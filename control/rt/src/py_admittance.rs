//! The admittance's classes compiled (law/admittance.rs), as the control process and the tests use
//! them: the same class names, constructor arguments, methods and attributes; any float sequence
//! (list, tuple, numpy array) in, lists of floats out where Python gave numpy arrays.
//!
//! * `Admittance(mass_fraction, damping, band_nm, filter_hz, max_velocity, rest_factor=1.0)`:
//!   `filtered_noise`, `reset`, `dead_zone`, `step` (`mass` n rows of n); the attributes the
//!   controller reads (`q_r`, writable, `dq_r`, `ddq_r`, `tau_h`, `band`, `base_band`,
//!   `moving`, ...) and `speed_limit`, a `(q_r, dq) -> scale` callable or None, called with
//!   lists.
//! * `EngageProbe(speed_rad_s, duration_s, period_s, slide_rad_s)`: `len`, `observe`,
//!   `samples`, `bias`; `cruise` a list, `velocity` and `offset` lists of rows.
//! * The module constants `ADMITTANCE_NOISE_SIGMAS`, `ADMITTANCE_SETTLE_RAD_S`,
//!   `ADMITTANCE_SETTLE_S` (prefixed: generic names), `PROBE_RAMP_S`, `PROBE_MIN_SAMPLES`.
//!
//! Wrong lengths and bad settings raise ValueError naming the argument; a singular α M̂ + dt D
//! raises numpy's `LinAlgError("Singular matrix")` as `numpy.linalg.solve` did.

use std::sync::{Mutex, MutexGuard};

use pyo3::exceptions::{PyOverflowError, PyRuntimeError, PyValueError, PyZeroDivisionError};
use pyo3::gc::PyVisit;
use pyo3::prelude::*;
use pyo3::types::PyType;
use pyo3::PyTraverseError;

use crate::chain::MAX_JOINTS;
use crate::law::admittance::{self as law, Admittance, EngageProbe};
use crate::py_args::check_len;

/// numpy's `LinAlgError` (a ValueError) with `msg`; ValueError if numpy cannot be imported.
fn linalg_error(py: Python<'_>, msg: String) -> PyErr {
    let class = py
        .import("numpy.linalg")
        .and_then(|m| m.getattr("LinAlgError"))
        .ok()
        .and_then(|c| c.cast_into::<PyType>().ok());
    match class {
        Some(c) => PyErr::from_type(c, msg),
        None => PyValueError::new_err(msg),
    }
}

/// (A1) after the model, and (A2): the reference the vendor loop follows
/// (law/admittance.rs).
#[pyclass(frozen, name = "Admittance", module = "control._rt")]
pub struct PyAdmittance {
    law: Mutex<Admittance>,
    /// Apart from the law: the callable runs with the law's lock released (it may read the
    /// reference), and the garbage collector visits it.
    speed_limit: Mutex<Option<Py<PyAny>>>,
    n: usize,
}

impl PyAdmittance {
    /// The law, for the compiled admittance cycle (no GIL).
    pub(crate) fn state_lock(&self) -> Result<MutexGuard<'_, Admittance>, String> {
        self.law
            .lock()
            .map_err(|_| "the admittance's lock is poisoned".to_string())
    }

    pub(crate) fn lock(&self) -> PyResult<MutexGuard<'_, Admittance>> {
        self.law
            .lock()
            .map_err(|_| PyRuntimeError::new_err("the admittance's lock is poisoned"))
    }

    fn limit(&self, py: Python<'_>) -> PyResult<Option<Py<PyAny>>> {
        let guard = self
            .speed_limit
            .lock()
            .map_err(|_| PyRuntimeError::new_err("the admittance's lock is poisoned"))?;
        Ok(guard.as_ref().map(|f| f.clone_ref(py)))
    }
}

#[pymethods]
impl PyAdmittance {
    #[new]
    #[pyo3(signature = (mass_fraction, damping, band_nm, filter_hz, max_velocity, rest_factor=1.0))]
    fn new(
        mass_fraction: f64,
        damping: Vec<f64>,
        band_nm: Vec<f64>,
        filter_hz: f64,
        max_velocity: Vec<f64>,
        rest_factor: f64,
    ) -> PyResult<Self> {
        let law = Admittance::new(
            mass_fraction,
            &damping,
            &band_nm,
            filter_hz,
            &max_velocity,
            rest_factor,
        )
        .map_err(PyValueError::new_err)?;
        let n = law.n();
        Ok(PyAdmittance {
            law: Mutex::new(law),
            speed_limit: Mutex::new(None),
            n,
        })
    }

    /// The standard deviation of τ̂_h after the low-pass [N·m], for white noise of
    /// `raw_std_nm` per sample at steps of `dt_s`.
    fn filtered_noise(&self, raw_std_nm: Vec<f64>, dt_s: f64) -> PyResult<Vec<f64>> {
        let mut out = vec![0.0; raw_std_nm.len()];
        self.lock()?.filtered_noise(&raw_std_nm, dt_s, &mut out);
        Ok(out)
    }

    /// Start at rest at `q_rad`; with `noise_std_nm` the static dead zone is at least
    /// ADMITTANCE_NOISE_SIGMAS of it.
    #[pyo3(signature = (q_rad, noise_std_nm=None))]
    fn reset(&self, q_rad: Vec<f64>, noise_std_nm: Option<Vec<f64>>) -> PyResult<()> {
        check_len(&q_rad, self.n, "q_rad")?;
        if let Some(noise) = &noise_std_nm {
            check_len(noise, self.n, "noise_std_nm")?;
        }
        self.lock()?.reset(&q_rad, noise_std_nm.as_deref());
        Ok(())
    }

    /// The push beyond the dead zone per joint [N·m]; updates `moving`.
    fn dead_zone(&self, tau: Vec<f64>) -> PyResult<Vec<f64>> {
        check_len(&tau, self.n, "tau")?;
        let mut out = vec![0.0; self.n];
        self.lock()?.dead_zone(&tau, &mut out);
        Ok(out)
    }

    /// One cycle's raw hand torque estimate (A1) and the walls' torque [N·m], M̂ at the
    /// reference (n rows of n); returns the new reference `(q_r, dq_r)`. With `constraint`
    /// `(rows, rates)`, the constrained guide's rows on the reference's speed
    /// (ZeroMomentCycle.guide_constraint_at), the new speed meets them; without, it is free.
    #[pyo3(signature = (tau_h_raw, tau_walls, mass, dt_s, constraint=None))]
    #[allow(clippy::type_complexity)]
    fn step(
        &self,
        py: Python<'_>,
        tau_h_raw: Vec<f64>,
        tau_walls: Vec<f64>,
        mass: Vec<Vec<f64>>,
        dt_s: f64,
        constraint: Option<(Vec<Vec<f64>>, Vec<f64>)>,
    ) -> PyResult<(Vec<f64>, Vec<f64>)> {
        let n = self.n;
        check_len(&tau_h_raw, n, "tau_h_raw")?;
        check_len(&tau_walls, n, "tau_walls")?;
        if mass.len() != n || mass.iter().any(|row| row.len() != n) {
            return Err(PyValueError::new_err(format!("mass needs {n} rows of {n}")));
        }
        match constraint {
            Some((rows, rates)) => {
                if rows.len() != rates.len() || rows.iter().any(|row| row.len() != n) {
                    return Err(PyValueError::new_err(format!(
                        "constraint needs one row of {n} per rate"
                    )));
                }
                let flat: Vec<f64> = rows.concat();
                self.lock()?
                    .set_constraint(&flat, &rates)
                    .map_err(PyValueError::new_err)?;
            }
            None => self.lock()?.clear_constraint(),
        }
        let mut flat = [0.0; MAX_JOINTS * MAX_JOINTS];
        for (i, row) in mass.iter().enumerate() {
            flat[i * n..(i + 1) * n].copy_from_slice(row);
        }
        let limit = self.limit(py)?;
        let (q_r, proposed) = {
            let mut law = self.lock()?;
            law.propose(&tau_h_raw, &tau_walls, &flat[..n * n], dt_s)
                .map_err(|e| linalg_error(py, e))?;
            if limit.is_none() {
                law.commit(1.0, dt_s);
                return Ok((law.q_r().to_vec(), law.dq_r().to_vec()));
            }
            (law.q_r().to_vec(), law.proposed().to_vec())
        };
        let scale: f64 = match limit {
            Some(f) => f.call1(py, (q_r, proposed))?.extract(py)?,
            None => 1.0,
        };
        let mut law = self.lock()?;
        law.commit(scale, dt_s);
        Ok((law.q_r().to_vec(), law.dq_r().to_vec()))
    }

    #[getter]
    fn rest_factor(&self) -> PyResult<f64> {
        Ok(self.lock()?.rest_factor())
    }

    /// The mass fraction α.
    #[getter]
    fn alpha(&self) -> PyResult<f64> {
        Ok(self.lock()?.alpha())
    }

    #[getter]
    fn filter_hz(&self) -> PyResult<f64> {
        Ok(self.lock()?.filter_hz())
    }

    #[getter]
    fn damping(&self) -> PyResult<Vec<f64>> {
        Ok(self.lock()?.damping().to_vec())
    }

    #[getter]
    fn max_velocity(&self) -> PyResult<Vec<f64>> {
        Ok(self.lock()?.max_velocity().to_vec())
    }

    /// The configured dead zone [N·m].
    #[getter]
    fn base_band(&self) -> PyResult<Vec<f64>> {
        Ok(self.lock()?.base_band().to_vec())
    }

    /// The static dead zone [N·m] (`reset` widens it to the measured noise).
    #[getter]
    fn band(&self) -> PyResult<Vec<f64>> {
        Ok(self.lock()?.band().to_vec())
    }

    /// Per joint, held: its reference still (law/admittance.rs `held`).
    #[getter]
    fn held(&self) -> PyResult<Vec<bool>> {
        Ok(self.lock()?.held().to_vec())
    }

    /// Per joint, the speed below which it is held once no push exceeds a static band
    /// [rad/s]; 0: never (writable: one value per joint, or one for every joint).
    #[getter]
    fn hold_rad_s(&self) -> PyResult<Vec<f64>> {
        Ok(self.lock()?.hold_rad_s().to_vec())
    }

    #[setter]
    fn set_hold_rad_s(&self, hold_rad_s: &Bound<'_, PyAny>) -> PyResult<()> {
        let mut law = self.lock()?;
        let speeds = match hold_rad_s.extract::<f64>() {
            Ok(one) => vec![one; law.n()],
            Err(_) => hold_rad_s.extract::<Vec<f64>>()?,
        };
        law.set_hold(&speeds).map_err(PyValueError::new_err)
    }

    /// The arm is guided (a joint broke away and not every joint is back in `base_band`).
    #[getter]
    fn moving(&self) -> PyResult<bool> {
        Ok(self.lock()?.moving())
    }

    /// The reference [rad]; writable (the controller holds it near the arm).
    #[getter]
    fn q_r(&self) -> PyResult<Vec<f64>> {
        Ok(self.lock()?.q_r().to_vec())
    }

    #[setter]
    fn set_q_r(&self, q_r: Vec<f64>) -> PyResult<()> {
        check_len(&q_r, self.n, "q_r")?;
        self.lock()?.set_q_r(&q_r);
        Ok(())
    }

    #[getter]
    fn dq_r(&self) -> PyResult<Vec<f64>> {
        Ok(self.lock()?.dq_r().to_vec())
    }

    #[getter]
    fn ddq_r(&self) -> PyResult<Vec<f64>> {
        Ok(self.lock()?.ddq_r().to_vec())
    }

    /// The low-passed hand torque estimate [N·m].
    #[getter]
    fn tau_h(&self) -> PyResult<Vec<f64>> {
        Ok(self.lock()?.tau_h().to_vec())
    }

    /// `(q_r, dq) -> scale` in (0, 1] that keeps a Cartesian speed limit, called with lists
    /// (None: none).
    #[getter]
    fn speed_limit(&self, py: Python<'_>) -> PyResult<Option<Py<PyAny>>> {
        self.limit(py)
    }

    #[setter]
    fn set_speed_limit(&self, f: Option<Py<PyAny>>) -> PyResult<()> {
        *self
            .speed_limit
            .lock()
            .map_err(|_| PyRuntimeError::new_err("the admittance's lock is poisoned"))? = f;
        Ok(())
    }

    fn __traverse__(&self, visit: PyVisit<'_>) -> Result<(), PyTraverseError> {
        if let Ok(f) = self.speed_limit.try_lock() {
            visit.call(&*f)?;
        }
        Ok(())
    }

    fn __clear__(&self) {
        if let Ok(mut f) = self.speed_limit.try_lock() {
            *f = None;
        }
    }
}

/// The residual `b` of (A1) without the share of the load stiction carries
/// (law/admittance.rs).
#[pyclass(frozen, name = "EngageProbe", module = "control._rt")]
pub struct PyEngageProbe {
    probe: Mutex<EngageProbe>,
    n: usize,
}

impl PyEngageProbe {
    pub(crate) fn lock(&self) -> PyResult<MutexGuard<'_, EngageProbe>> {
        self.probe
            .lock()
            .map_err(|_| PyRuntimeError::new_err("the engage probe's lock is poisoned"))
    }

    fn rows(&self, row: impl Fn(&EngageProbe, usize) -> &[f64]) -> PyResult<Vec<Vec<f64>>> {
        let p = self.lock()?;
        Ok((0..p.len()).map(|k| row(&p, k).to_vec()).collect())
    }
}

#[pymethods]
impl PyEngageProbe {
    /// Python raised ZeroDivisionError for a zero period and OverflowError for an infinite
    /// number of samples (`round`); so does this.
    #[new]
    fn new(
        speed_rad_s: Vec<f64>,
        duration_s: f64,
        period_s: f64,
        slide_rad_s: f64,
    ) -> PyResult<Self> {
        if period_s == 0.0 {
            return Err(PyZeroDivisionError::new_err(
                "engage probe period_s must not be 0",
            ));
        }
        if (0.25 * duration_s / period_s).is_infinite() {
            return Err(PyOverflowError::new_err(format!(
                "engage probe duration_s {duration_s} over period_s {period_s}: infinitely many \
                 samples"
            )));
        }
        let probe = EngageProbe::new(&speed_rad_s, duration_s, period_s, slide_rad_s)
            .map_err(PyValueError::new_err)?;
        let n = probe.n();
        Ok(PyEngageProbe {
            probe: Mutex::new(probe),
            n,
        })
    }

    fn __len__(&self) -> PyResult<usize> {
        Ok(self.lock()?.len())
    }

    /// The state measured over the cycle the probe's sample `k` drove: its velocity [rad/s]
    /// and the residual `model(q, 0, q̈) − K i` [N·m]; a `k` out of range is ignored.
    fn observe(&self, k: i64, dq_rad_s: Vec<f64>, residual_nm: Vec<f64>) -> PyResult<()> {
        check_len(&dq_rad_s, self.n, "dq_rad_s")?;
        check_len(&residual_nm, self.n, "residual_nm")?;
        if let Ok(k) = usize::try_from(k) {
            self.lock()?.observe(k, &dq_rad_s, &residual_nm);
        }
        Ok(())
    }

    /// (samples sliding +, samples sliding −) per joint.
    fn samples(&self) -> PyResult<Vec<(usize, usize)>> {
        let p = self.lock()?;
        Ok((0..self.n).map(|j| p.samples(j)).collect())
    }

    /// `b` per joint [N·m], and the joints that did not slide both ways: theirs is
    /// `at_rest_nm` less `stick_nm` (towards 0).
    fn bias(&self, at_rest_nm: Vec<f64>, stick_nm: Vec<f64>) -> PyResult<(Vec<f64>, Vec<usize>)> {
        check_len(&at_rest_nm, self.n, "at_rest_nm")?;
        check_len(&stick_nm, self.n, "stick_nm")?;
        let (mut b, mut kept) = (vec![0.0; self.n], vec![false; self.n]);
        self.lock()?.bias(&at_rest_nm, &stick_nm, &mut b, &mut kept);
        Ok((b, (0..self.n).filter(|&j| kept[j]).collect()))
    }

    /// Per probe sample: +1 / −1 at cruise that way, 0 elsewhere.
    #[getter]
    fn cruise(&self) -> PyResult<Vec<f64>> {
        Ok(self.lock()?.cruise().to_vec())
    }

    /// Per probe sample, the velocity command per joint [rad/s].
    #[getter]
    fn velocity(&self) -> PyResult<Vec<Vec<f64>>> {
        self.rows(EngageProbe::velocity)
    }

    /// Per probe sample, the offset from the start per joint [rad].
    #[getter]
    fn offset(&self) -> PyResult<Vec<Vec<f64>>> {
        self.rows(EngageProbe::offset)
    }

    #[getter]
    fn slide_rad_s(&self) -> PyResult<f64> {
        Ok(self.lock()?.slide_rad_s())
    }

    #[getter]
    fn n(&self) -> usize {
        self.n
    }
}

/// Adds the classes and constants to `control._rt`.
pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<PyAdmittance>()?;
    m.add_class::<PyEngageProbe>()?;
    m.add("ADMITTANCE_NOISE_SIGMAS", law::NOISE_SIGMAS)?;
    m.add("ADMITTANCE_SETTLE_RAD_S", law::SETTLE_RAD_S)?;
    m.add("ADMITTANCE_SETTLE_S", law::SETTLE_S)?;
    m.add("PROBE_RAMP_S", law::PROBE_RAMP_S)?;
    m.add("PROBE_MIN_SAMPLES", law::PROBE_MIN_SAMPLES)?;
    Ok(())
}
