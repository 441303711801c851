//! `control._rt.PlanPlay` (law/plan_play.rs): the slot of the plan being played. The control
//! process's `PlanPlayer` (control/plan_player.py) builds a plan off the cycle and installs it
//! here; the compiled loop (py_cycle_loop.rs) plays it from zenoh's thread without the GIL, and
//! Python reads where it is for the operator and the export.

use std::sync::{Mutex, MutexGuard};

use pyo3::exceptions::{PyRuntimeError, PyValueError};
use pyo3::prelude::*;

use crate::law::plan_play::{Phase, PlanPlay};

/// The plan being played, or none (module docs).
#[pyclass(frozen, name = "PlanPlay", module = "control._rt")]
pub struct PyPlanPlay {
    slot: Mutex<Option<PlanPlay>>,
}

impl PyPlanPlay {
    /// The slot without the GIL's error type (the compiled loop's thread).
    pub(crate) fn slot(&self) -> Result<MutexGuard<'_, Option<PlanPlay>>, String> {
        self.slot
            .lock()
            .map_err(|_| "the plan's lock is poisoned".to_string())
    }

    fn lock(&self) -> PyResult<MutexGuard<'_, Option<PlanPlay>>> {
        self.slot().map_err(PyRuntimeError::new_err)
    }
}

#[pymethods]
impl PyPlanPlay {
    #[new]
    fn new() -> Self {
        PyPlanPlay {
            slot: Mutex::new(None),
        }
    }

    /// Play a new plan: rows of `n` joints (`q` [rad], `dq` [rad/s], flat), in segments of
    /// `lengths` samples, one sample every `period_s` [s]; held longer than `max_pause_s` [s]
    /// in a row it fails; after a hold it resumes no faster than `resume_accel_rad_s2`.
    #[allow(clippy::too_many_arguments)]
    fn install(
        &self,
        q: Vec<f64>,
        dq: Vec<f64>,
        n: usize,
        lengths: Vec<usize>,
        period_s: f64,
        max_pause_s: f64,
        resume_accel_rad_s2: f64,
    ) -> PyResult<()> {
        let plan = PlanPlay::new(
            q,
            dq,
            n,
            &lengths,
            period_s,
            max_pause_s,
            resume_accel_rad_s2,
        )
        .map_err(PyValueError::new_err)?;
        *self.lock()? = Some(plan);
        Ok(())
    }

    /// No plan: the loop answers no state with one.
    fn clear(&self) -> PyResult<()> {
        *self.lock()? = None;
        Ok(())
    }

    /// The command answering the state of `cycle` with `flags`: `(q, dq)`, or None when
    /// nothing is to be sent (no plan, or it failed).
    #[allow(clippy::type_complexity)]
    fn command(&self, cycle: i64, flags: u32) -> PyResult<Option<(Vec<f64>, Vec<f64>)>> {
        let mut slot = self.lock()?;
        let Some(plan) = slot.as_mut() else {
            return Ok(None);
        };
        let (mut q, mut dq) = (vec![0.0; plan.joints()], vec![0.0; plan.joints()]);
        Ok(plan
            .command(cycle, flags, &mut q, &mut dq)
            .then_some((q, dq)))
    }

    /// The plan fails with `why` (nothing more is sent for it).
    fn fail(&self, why: String) -> PyResult<()> {
        if let Some(plan) = self.lock()?.as_mut() {
            plan.fail(why);
        }
        Ok(())
    }

    /// Where the plan is: `(phase, reason, k, samples, repeats, segment cycles)` with phase
    /// "running", "done" or "failed" and each segment's (first, last) cycle (-1: not yet), or
    /// None without a plan.
    #[allow(clippy::type_complexity)]
    fn status(
        &self,
    ) -> PyResult<Option<(&'static str, String, usize, usize, u64, Vec<(i64, i64)>)>> {
        Ok(self.lock()?.as_ref().map(|p| {
            (
                p.phase.name(),
                p.reason.clone(),
                p.k,
                p.len(),
                p.repeats,
                p.segment_cycles.clone(),
            )
        }))
    }
}

/// The loop's side: the plan plays this state when there is one that has not failed.
pub(crate) fn playable(plan: &Option<PlanPlay>, n: usize) -> bool {
    plan.as_ref()
        .is_some_and(|p| p.phase != Phase::Failed && p.joints() == n)
}

pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<PyPlanPlay>()?;
    Ok(())
}
