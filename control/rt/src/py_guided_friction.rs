//! `control._rt.GuidedFriction` (law/guided_friction.rs).

use std::sync::{Mutex, MutexGuard};

use pyo3::exceptions::{PyRuntimeError, PyValueError};
use pyo3::prelude::*;

use crate::law::guided_friction::{self, GuidedFriction};

/// Whether the zero-moment arm is being guided, for its friction compensation.
#[pyclass(frozen, name = "GuidedFriction", module = "control._rt")]
pub struct PyGuidedFriction {
    state: Mutex<GuidedFriction>,
    hold_s: f64,
}

impl PyGuidedFriction {
    /// The lock without the GIL's error type (the compiled loop's thread).
    pub(crate) fn state_lock(
        &self,
    ) -> Result<
        MutexGuard<'_, GuidedFriction>,
        std::sync::PoisonError<MutexGuard<'_, GuidedFriction>>,
    > {
        self.state.lock()
    }

    pub(crate) fn lock(&self) -> PyResult<MutexGuard<'_, GuidedFriction>> {
        self.state
            .lock()
            .map_err(|_| PyRuntimeError::new_err("the guided friction's lock is poisoned"))
    }
}

#[pymethods]
impl PyGuidedFriction {
    #[classattr]
    const POSITIONING_JOINTS: usize = guided_friction::POSITIONING_JOINTS;

    #[new]
    fn new(hold_s: f64) -> Self {
        PyGuidedFriction {
            state: Mutex::new(GuidedFriction::new(hold_s)),
            hold_s,
        }
    }

    /// Release time after the positioning joints slowed [s].
    #[getter]
    fn hold_s(&self) -> f64 {
        self.hold_s
    }

    #[getter]
    fn guided(&self) -> PyResult<bool> {
        Ok(self.lock()?.guided())
    }

    /// Take in a cycle's measured velocities [rad/s] and the joints' ramp speeds [rad/s];
    /// True while the arm is guided.
    fn update(&self, dq_rad_s: Vec<f64>, ramps: Vec<f64>, dt_s: f64) -> PyResult<bool> {
        self.lock()?
            .update(&dq_rad_s, &ramps, dt_s)
            .map_err(PyValueError::new_err)
    }

    fn reset(&self) -> PyResult<()> {
        self.lock()?.reset();
        Ok(())
    }
}

pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<PyGuidedFriction>()
}
