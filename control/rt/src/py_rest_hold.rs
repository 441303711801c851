//! `control._rt.RestHold` and `control._rt.hold_band_nm` (law/rest_hold.rs).

use std::sync::{Mutex, MutexGuard};

use pyo3::exceptions::{PyRuntimeError, PyValueError};
use pyo3::prelude::*;

use crate::law::rest_hold::{self, RestHold};

/// The elasto-plastic hold (law/rest_hold.rs), one `torque_nm` per cycle.
#[pyclass(frozen, name = "RestHold", module = "control._rt")]
pub struct PyRestHold {
    hold: Mutex<RestHold>,
    band_nm: Vec<f64>,
    deflection_rad: f64,
    active: bool,
}

impl PyRestHold {
    /// The lock without the GIL's error type (the compiled loop's thread).
    pub(crate) fn state_lock(
        &self,
    ) -> Result<MutexGuard<'_, RestHold>, std::sync::PoisonError<MutexGuard<'_, RestHold>>> {
        self.hold.lock()
    }

    pub(crate) fn lock(&self) -> PyResult<MutexGuard<'_, RestHold>> {
        self.hold
            .lock()
            .map_err(|_| PyRuntimeError::new_err("the rest hold's lock is poisoned"))
    }
}

#[pymethods]
impl PyRestHold {
    #[new]
    fn new(band_nm: Vec<f64>, deflection_rad: f64) -> PyResult<Self> {
        let hold = RestHold::new(&band_nm, deflection_rad).map_err(PyValueError::new_err)?;
        let active = hold.active();
        Ok(PyRestHold {
            hold: Mutex::new(hold),
            band_nm,
            deflection_rad,
            active,
        })
    }

    /// The band per joint [N·m].
    #[getter]
    fn band_nm(&self) -> Vec<f64> {
        self.band_nm.clone()
    }

    /// The deflection at which the band is reached [rad].
    #[getter]
    fn deflection_rad(&self) -> f64 {
        self.deflection_rad
    }

    /// Some joint holds (a band above 0).
    #[getter]
    fn active(&self) -> bool {
        self.active
    }

    /// Start afresh: the next step anchors every joint where it is (τ_h = 0).
    fn reset(&self) -> PyResult<()> {
        self.lock()?.reset();
        Ok(())
    }

    /// τ_h per joint [N·m] at the joint positions `q` [rad].
    fn torque_nm(&self, q: Vec<f64>) -> PyResult<Vec<f64>> {
        let mut out = vec![0.0; q.len()];
        self.lock()?
            .torque_nm(&q, &mut out)
            .map_err(PyValueError::new_err)?;
        Ok(out)
    }
}

/// Per joint: `rms_factor` × the model's held-out RMS, at least `floor_nm` [N·m].
#[pyfunction]
#[pyo3(signature = (floor_nm, rms_factor, heldout_rms_nm))]
fn hold_band_nm(
    floor_nm: Vec<f64>,
    rms_factor: f64,
    heldout_rms_nm: Option<Vec<f64>>,
) -> PyResult<Vec<f64>> {
    rest_hold::hold_band_nm(&floor_nm, rms_factor, heldout_rms_nm.as_deref())
        .map_err(PyValueError::new_err)
}

pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<PyRestHold>()?;
    m.add_function(wrap_pyfunction!(hold_band_nm, m)?)?;
    Ok(())
}
