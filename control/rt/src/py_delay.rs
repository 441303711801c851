//! `control._rt.DelayPredictor` (law/delay.rs): the Smith predictor over the command delay,
//! as the control process and the tests use it, and its constants as `DELAY_SUBSTEP_S`,
//! `DELAY_STIFF_STEP`, `DELAY_MAX_SUBSTEPS`.

use std::sync::{Mutex, MutexGuard};

use pyo3::exceptions::{PyOverflowError, PyRuntimeError, PyValueError};
use pyo3::prelude::*;

use crate::law::delay::{
    Cycle, DelayError, DelayPredictor, Drive, MAX_SUBSTEPS, STIFF_STEP, SUBSTEP_S,
};

fn py_err(e: DelayError) -> PyErr {
    match e {
        DelayError::StepsInfinite => PyOverflowError::new_err(e.to_string()),
        _ => PyValueError::new_err(e.to_string()),
    }
}

/// M(q)⁻¹ as n rows of n, row-major flat.
fn square(rows: Vec<Vec<f64>>, n: usize, what: &str) -> PyResult<Vec<f64>> {
    if rows.len() != n || rows.iter().any(|r| r.len() != n) {
        return Err(PyValueError::new_err(format!(
            "{what} needs {n} rows of {n} values"
        )));
    }
    Ok(rows.concat())
}

/// The state `delay_cycles` cycles on (law/delay.rs). Call `predict` once per state, in
/// order; `reset` when the history breaks.
#[pyclass(frozen, name = "DelayPredictor", module = "control._rt")]
pub struct PyDelayPredictor {
    predictor: Mutex<DelayPredictor>,
    delay_cycles: usize,
}

impl PyDelayPredictor {
    /// The lock without the GIL's error type (the compiled loop's thread).
    pub(crate) fn state_lock(
        &self,
    ) -> Result<
        MutexGuard<'_, DelayPredictor>,
        std::sync::PoisonError<MutexGuard<'_, DelayPredictor>>,
    > {
        self.predictor.lock()
    }

    pub(crate) fn lock(&self) -> PyResult<MutexGuard<'_, DelayPredictor>> {
        self.predictor
            .lock()
            .map_err(|_| PyRuntimeError::new_err("the delay predictor's lock is poisoned"))
    }
}

#[pymethods]
impl PyDelayPredictor {
    #[new]
    fn new(delay_cycles: i64) -> PyResult<Self> {
        let predictor = DelayPredictor::new(delay_cycles).map_err(PyValueError::new_err)?;
        let delay_cycles = predictor.delay_cycles();
        Ok(PyDelayPredictor {
            predictor: Mutex::new(predictor),
            delay_cycles,
        })
    }

    #[getter]
    fn delay_cycles(&self) -> usize {
        self.delay_cycles
    }

    fn reset(&self) -> PyResult<()> {
        self.lock()?.reset();
        Ok(())
    }

    /// `(q, dq)` when the command answering this state takes effect, as lists; with a delay
    /// of 0 the arguments `q`, `dq` themselves. `echo_*` the command the driver sent last
    /// (this state's echo), `consecutive` this state follows the last by one cycle, `m_inv`
    /// M(q)⁻¹ (n rows of n), `k_star` = 1/ω̂ [N·m·s/rad], `upsilon` Υ̂_I [1/s].
    #[allow(clippy::too_many_arguments)]
    fn predict<'py>(
        &self,
        q: Bound<'py, PyAny>,
        dq: Bound<'py, PyAny>,
        echo_q: Vec<f64>,
        echo_dq: Vec<f64>,
        period_s: f64,
        consecutive: bool,
        m_inv: Vec<Vec<f64>>,
        k_star: Vec<f64>,
        upsilon: Vec<f64>,
    ) -> PyResult<(Bound<'py, PyAny>, Bound<'py, PyAny>)> {
        if self.delay_cycles == 0 {
            return Ok((q, dq));
        }
        let py = q.py();
        let (q, dq): (Vec<f64>, Vec<f64>) = (q.extract()?, dq.extract()?);
        let m_inv = square(m_inv, q.len(), "m_inv")?;
        let cycle = Cycle {
            q: &q,
            dq: &dq,
            echo_q: &echo_q,
            echo_dq: &echo_dq,
            period_s,
            consecutive,
        };
        let drive = Drive {
            m_inv: &m_inv,
            k_star: &k_star,
            upsilon: &upsilon,
        };
        let (mut q_out, mut dq_out) = (vec![0.0; q.len()], vec![0.0; q.len()]);
        self.lock()?
            .predict(&cycle, &drive, &mut q_out, &mut dq_out)
            .map_err(py_err)?;
        Ok((
            q_out.into_pyobject(py)?.into_any(),
            dq_out.into_pyobject(py)?.into_any(),
        ))
    }
}

pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<PyDelayPredictor>()?;
    m.add("DELAY_SUBSTEP_S", SUBSTEP_S)?;
    m.add("DELAY_STIFF_STEP", STIFF_STEP)?;
    m.add("DELAY_MAX_SUBSTEPS", MAX_SUBSTEPS)?;
    Ok(())
}
