//! The lead-through law whose teaching cycle `control._rt.CycleLoop` answers
//! (`py_cycle_loop.rs`): the zero-moment law's or the admittance's, one call for either.

use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;

use crate::law::zero_moment::State;
use crate::py_admittance_cycle::PyAdmittanceCycle;
use crate::py_zero_moment::PyZeroMomentCycle;

/// The lead-through law whose teaching cycle the loop answers: the zero-moment law's, or the
/// admittance's (which shares the zero-moment law's pieces: its offset on a replay, the motor
/// torque).
pub(crate) enum Law {
    ZeroMoment(Py<PyZeroMomentCycle>),
    Admittance(Py<PyAdmittanceCycle>),
}

impl Law {
    pub(crate) fn from_py(law: &Bound<'_, PyAny>) -> PyResult<Law> {
        if let Ok(z) = law.cast::<PyZeroMomentCycle>() {
            return Ok(Law::ZeroMoment(z.clone().unbind()));
        }
        if let Ok(a) = law.cast::<PyAdmittanceCycle>() {
            return Ok(Law::Admittance(a.clone().unbind()));
        }
        Err(PyValueError::new_err(
            "law must be a ZeroMomentCycle, an AdmittanceCycle or None",
        ))
    }

    pub(crate) fn zero_moment(&self) -> &PyZeroMomentCycle {
        match self {
            Law::ZeroMoment(z) => z.get(),
            Law::Admittance(a) => a.get().zero_moment(),
        }
    }

    pub(crate) fn joints(&self) -> usize {
        match self {
            Law::ZeroMoment(z) => z.get().joints(),
            Law::Admittance(a) => a.get().joints(),
        }
    }

    pub(crate) fn answer_state(
        &self,
        st: &State,
        p_bar: &[f64],
        q_cmd: &mut [f64],
        dq_cmd: &mut [f64],
    ) -> Result<(), String> {
        match self {
            Law::ZeroMoment(z) => z.get().answer_state(st, p_bar, q_cmd, dq_cmd),
            Law::Admittance(a) => a.get().answer_state(st, p_bar, q_cmd, dq_cmd),
        }
    }

    pub(crate) fn disengage_now(&self) {
        match self {
            Law::ZeroMoment(z) => z.get().disengage_now(),
            Law::Admittance(a) => a.get().disengage_now(),
        }
    }
}
