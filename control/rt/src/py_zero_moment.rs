//! `control._rt.ZeroMomentCycle` (law/zero_moment.rs): the zero-moment law's cycle, built by
//! control/zero_moment_law.py's `ZeroMomentController` over the pieces it owns (the outer loop, the
//! delay predictor, the rest hold, the guided switch, the hold average, the inner-loop
//! estimate, the model, the nominal chain), which the cycle borrows each call. A joint state
//! is passed as its fields; arrays in as any float sequence, out as lists.
//!
//! Where the model cannot be evaluated the call raises ArithmeticError (a torque not finite)
//! or ValueError (a bad argument or a singular mass matrix), as the Python law did.

use std::sync::{Mutex, MutexGuard};

use pyo3::exceptions::{PyArithmeticError, PyRuntimeError, PyValueError};
use pyo3::prelude::*;

use crate::chain::MAX_JOINTS;
use crate::law::guide::GuideMode;
use crate::law::zero_moment::{Parts, Settings, State, ZeroMoment};
use crate::py::{PyChain, PyPointModel};
use crate::py_args::check_len;
use crate::py_delay::PyDelayPredictor;
use crate::py_guided_friction::PyGuidedFriction;
use crate::py_inner_estimate::PyInnerLoopEstimator;
use crate::py_outer_loop::{PyHoldAverage, PyOuterLoop};
use crate::py_rest_hold::PyRestHold;

/// A model error (not finite) as ArithmeticError, anything else as ValueError.
pub(crate) fn law_error(e: String) -> PyErr {
    if e.contains("not finite") {
        PyArithmeticError::new_err(e)
    } else {
        PyValueError::new_err(e)
    }
}

fn rows(flat: &[f64], n: usize) -> Vec<Vec<f64>> {
    flat.chunks(n).map(<[f64]>::to_vec).collect()
}

/// The zero-moment law's cycle (law/zero_moment.rs).
#[pyclass(frozen, name = "ZeroMomentCycle", module = "control._rt")]
pub struct PyZeroMomentCycle {
    law: Mutex<ZeroMoment>,
    outer: Py<PyOuterLoop>,
    predictor: Py<PyDelayPredictor>,
    rest_hold: Py<PyRestHold>,
    guided: Py<PyGuidedFriction>,
    hold: Py<PyHoldAverage>,
    inner: Option<Py<PyInnerLoopEstimator>>,
    model: Mutex<Py<PyPointModel>>,
    chain: Option<Py<PyChain>>,
    n: usize,
}

impl PyZeroMomentCycle {
    fn lock(&self) -> PyResult<MutexGuard<'_, ZeroMoment>> {
        self.law
            .lock()
            .map_err(|_| PyRuntimeError::new_err("the law's lock is poisoned"))
    }

    fn check(&self, v: &[f64], what: &str) -> PyResult<()> {
        check_len(v, self.n, what)
    }

    fn no_chain() -> PyErr {
        PyValueError::new_err("the law has no nominal chain (no delay, speed limit, friction ramp or inertia compensation)")
    }

    /// Run `f` with the law and every piece locked; needs no GIL (the pieces are frozen
    /// classes behind their own locks), so the compiled loop calls it from zenoh's thread.
    pub(crate) fn locked<R>(
        &self,
        f: impl FnOnce(&mut ZeroMoment, &mut Parts) -> Result<R, String>,
    ) -> Result<R, String> {
        let poisoned = |what: &str| format!("the {what}'s lock is poisoned");
        let mut law = self.law.lock().map_err(|_| poisoned("law"))?;
        let mut outer = self
            .outer
            .get()
            .state_lock()
            .map_err(|_| poisoned("outer loop"))?;
        let mut predictor = self
            .predictor
            .get()
            .state_lock()
            .map_err(|_| poisoned("predictor"))?;
        let mut rest_hold = self
            .rest_hold
            .get()
            .state_lock()
            .map_err(|_| poisoned("rest hold"))?;
        let mut guided = self
            .guided
            .get()
            .state_lock()
            .map_err(|_| poisoned("guided switch"))?;
        let mut hold = self
            .hold
            .get()
            .state_lock()
            .map_err(|_| poisoned("hold average"))?;
        let mut inner = match &self.inner {
            Some(e) => Some(e.get().state_lock().map_err(|_| poisoned("estimate"))?),
            None => None,
        };
        let model_slot = self.model.lock().map_err(|_| poisoned("model slot"))?;
        let mut model = model_slot
            .get()
            .state_lock()
            .map_err(|_| poisoned("model"))?;
        let mut chain = match &self.chain {
            Some(c) => Some(c.get().state_lock().map_err(|_| poisoned("chain"))?),
            None => None,
        };
        let chain_parts = chain.as_deref_mut().map(|c| (&c.chain, &mut c.work));
        let mut parts = Parts {
            outer: &mut outer,
            predictor: &mut predictor,
            rest_hold: &mut rest_hold,
            guided: &mut guided,
            hold: &mut hold,
            inner: inner.as_deref_mut(),
            model: &mut model,
            chain: chain_parts,
        };
        f(&mut law, &mut parts)
    }

    /// [`Self::locked`] for the Python methods: a model error as ArithmeticError, any other
    /// as ValueError.
    fn with_parts<R>(
        &self,
        _py: Python<'_>,
        f: impl FnOnce(&mut ZeroMoment, &mut Parts) -> Result<R, String>,
    ) -> PyResult<R> {
        self.locked(f).map_err(law_error)
    }

    /// The answer to one state, for the compiled loop (no GIL): `(q_cmd, dq_cmd)` into the
    /// outputs; Err as [`ZeroMoment::answer`]'s.
    pub(crate) fn answer_state(
        &self,
        st: &State,
        p_bar: &[f64],
        q_cmd: &mut [f64],
        dq_cmd: &mut [f64],
    ) -> Result<(), String> {
        self.locked(|law, parts| law.answer(parts, st, p_bar, q_cmd, dq_cmd))
    }

    /// The command offset at (q, dq) with pressures `p_bar`, for the compiled loop (no GIL):
    /// as [`PyZeroMomentCycle::hold_offset`].
    pub(crate) fn offset_at(
        &self,
        q: &[f64],
        dq: &[f64],
        p_bar: &[f64],
        out: &mut [f64],
    ) -> Result<(), String> {
        self.locked(|law, parts| law.hold_offset(parts.model, parts.outer, q, dq, p_bar, out))
    }

    /// The motor torque `current_a` reports [N·m], for the compiled loop (no GIL).
    pub(crate) fn motor_torque_at(&self, current_a: &[f64], out: &mut [f64]) -> Result<(), String> {
        let law = self
            .law
            .lock()
            .map_err(|_| "the law's lock is poisoned".to_string())?;
        law.motor_torque(current_a, out);
        Ok(())
    }

    /// Stop following (the loop's error path).
    pub(crate) fn disengage_now(&self) {
        if let Ok(mut law) = self.law.lock() {
            law.disengage();
        }
    }

    pub(crate) fn joints(&self) -> usize {
        self.n
    }

    #[allow(clippy::too_many_arguments)]
    pub(crate) fn state<'a>(
        &self,
        cycle: i64,
        flags: u32,
        period_s: f64,
        q: &'a [f64],
        dq: &'a [f64],
        q_cmd: &'a [f64],
        dq_cmd: &'a [f64],
        current_a: &'a [f64],
    ) -> PyResult<State<'a>> {
        self.check(q, "q")?;
        self.check(dq, "dq")?;
        self.check(q_cmd, "q_cmd")?;
        self.check(dq_cmd, "dq_cmd")?;
        self.check(current_a, "current_a")?;
        Ok(State {
            cycle,
            flags,
            period_s,
            q,
            dq,
            q_cmd,
            dq_cmd,
            current_a,
        })
    }
}

#[pymethods]
impl PyZeroMomentCycle {
    #[new]
    #[pyo3(signature = (settings_json, outer_loop, predictor, rest_hold, guided, hold, inner_estimate, model, chain))]
    #[allow(clippy::too_many_arguments)]
    fn new(
        settings_json: &str,
        outer_loop: Py<PyOuterLoop>,
        predictor: Py<PyDelayPredictor>,
        rest_hold: Py<PyRestHold>,
        guided: Py<PyGuidedFriction>,
        hold: Py<PyHoldAverage>,
        inner_estimate: Option<Py<PyInnerLoopEstimator>>,
        model: Py<PyPointModel>,
        chain: Option<Py<PyChain>>,
    ) -> PyResult<Self> {
        let v: serde_json::Value = serde_json::from_str(settings_json)
            .map_err(|e| PyValueError::new_err(format!("law settings: not JSON ({e})")))?;
        let s = Settings::from_json(&v)
            .map_err(|e| PyValueError::new_err(format!("law settings: {e}")))?;
        let n = s.n;
        if outer_loop.get().lock()?.n() != n {
            return Err(PyValueError::new_err(format!(
                "the outer loop is not of {n} joints"
            )));
        }
        if model.get().lock()?.n() != n {
            return Err(PyValueError::new_err(format!(
                "the model is not of {n} joints"
            )));
        }
        if let Some(c) = &chain {
            if c.get().lock()?.chain.n() != n {
                return Err(PyValueError::new_err(format!(
                    "the chain is not of {n} joints"
                )));
            }
        } else if s.needs_chain() {
            return Err(Self::no_chain());
        }
        Ok(PyZeroMomentCycle {
            law: Mutex::new(ZeroMoment::new(s)),
            outer: outer_loop,
            predictor,
            rest_hold,
            guided,
            hold,
            inner: inner_estimate,
            model: Mutex::new(model),
            chain,
            n,
        })
    }

    /// The model the law compensates from the next cycle on (a model adapted in replay).
    fn set_model(&self, model: Py<PyPointModel>) -> PyResult<()> {
        if model.get().lock()?.n() != self.n {
            return Err(PyValueError::new_err(format!(
                "the model is not of {} joints",
                self.n
            )));
        }
        *self
            .model
            .lock()
            .map_err(|_| PyRuntimeError::new_err("the law's model lock is poisoned"))? = model;
        Ok(())
    }

    /// `(q_cmd, dq_cmd)` answering the joint state with the cylinders' pressures `p_bar`.
    #[allow(clippy::too_many_arguments)]
    fn answer(
        &self,
        py: Python<'_>,
        cycle: i64,
        flags: u32,
        period_s: f64,
        q: Vec<f64>,
        dq: Vec<f64>,
        q_cmd: Vec<f64>,
        dq_cmd: Vec<f64>,
        current_a: Vec<f64>,
        p_bar: Vec<f64>,
    ) -> PyResult<(Vec<f64>, Vec<f64>)> {
        let st = self.state(cycle, flags, period_s, &q, &dq, &q_cmd, &dq_cmd, &current_a)?;
        let n = self.n;
        let mut out_q = [0.0; MAX_JOINTS];
        let mut out_dq = [0.0; MAX_JOINTS];
        self.with_parts(py, |law, parts| {
            law.answer(parts, &st, &p_bar, &mut out_q[..n], &mut out_dq[..n])
        })?;
        Ok((out_q[..n].to_vec(), out_dq[..n].to_vec()))
    }

    /// A state while the arm is held: at rest, into the hold's average; moving, it restarts.
    #[allow(clippy::too_many_arguments)]
    fn observe_hold(
        &self,
        py: Python<'_>,
        flags: u32,
        q: Vec<f64>,
        dq: Vec<f64>,
        q_cmd: Vec<f64>,
        current_a: Vec<f64>,
    ) -> PyResult<()> {
        let st = self.state(0, flags, 0.0, &q, &dq, &q_cmd, &dq, &current_a)?;
        self.with_parts(py, |law, parts| law.observe_hold(&st, parts.hold))
    }

    /// Before engaging: take the state into the hold's average; True while the arm has not
    /// rested long enough (and at most `engage_max_wait_states`).
    fn still_waiting(
        &self,
        py: Python<'_>,
        flags: u32,
        q: Vec<f64>,
        dq: Vec<f64>,
        q_cmd: Vec<f64>,
        current_a: Vec<f64>,
    ) -> PyResult<bool> {
        let st = self.state(0, flags, 0.0, &q, &dq, &q_cmd, &dq, &current_a)?;
        self.with_parts(py, |law, parts| law.still_waiting(&st, parts.hold))
    }

    fn disengage(&self) -> PyResult<()> {
        self.lock()?.disengage();
        Ok(())
    }

    #[getter]
    fn engaged(&self) -> PyResult<bool> {
        Ok(self.lock()?.engaged)
    }

    #[setter]
    fn set_engaged(&self, value: bool) -> PyResult<()> {
        self.lock()?.engaged = value;
        Ok(())
    }

    #[getter]
    fn last_cycle(&self) -> PyResult<Option<i64>> {
        Ok(self.lock()?.last_cycle)
    }

    #[setter]
    fn set_last_cycle(&self, value: Option<i64>) -> PyResult<()> {
        self.lock()?.last_cycle = value;
        Ok(())
    }

    /// States answered with a hold while waiting to engage.
    #[getter]
    fn waited(&self) -> PyResult<usize> {
        Ok(self.lock()?.waited)
    }

    /// The desired torque of the last cycle [N·m].
    #[getter]
    fn tau_d_nm(&self) -> PyResult<Vec<f64>> {
        Ok(self.lock()?.tau_d().to_vec())
    }

    /// Per joint, the speed over which the friction compensation ramps in [rad/s].
    #[getter]
    fn ramps(&self) -> PyResult<Vec<f64>> {
        Ok(self.lock()?.ramps().to_vec())
    }

    #[setter]
    fn set_ramps(&self, value: Vec<f64>) -> PyResult<()> {
        self.check(&value, "ramps")?;
        self.lock()?.set_ramps(&value);
        Ok(())
    }

    /// The model's friction level at the engagement's pose [N·m].
    #[getter]
    fn friction_level(&self) -> PyResult<Vec<f64>> {
        Ok(self.lock()?.friction_level().to_vec())
    }

    /// The inertia compensation's torque of the last cycle [N·m].
    #[getter]
    fn tau_inertia_nm(&self) -> PyResult<Vec<f64>> {
        Ok(self.lock()?.tau_inertia().to_vec())
    }

    /// The stiction dither's torque of the last cycle [N·m].
    #[getter]
    fn stiction_torque_nm(&self) -> PyResult<Vec<f64>> {
        Ok(self.lock()?.stiction_torque().to_vec())
    }

    /// Constrained guiding's mode (law/guide.rs): "free", "orientation-locked", "plane" or
    /// "axis". Setting another mode takes its reference at the next cycle; ValueError for a
    /// name not among them, or a mode other than "free" on a law without the nominal chain.
    #[getter]
    fn guide(&self) -> PyResult<&'static str> {
        Ok(self.lock()?.guide.mode().name())
    }

    #[setter]
    fn set_guide(&self, name: &str) -> PyResult<()> {
        let mode = GuideMode::parse(name).map_err(PyValueError::new_err)?;
        if mode != GuideMode::Free && self.chain.is_none() {
            return Err(Self::no_chain());
        }
        self.lock()?.guide.set_mode(mode);
        Ok(())
    }

    /// The constrained guiding's torque of the last cycle [N·m].
    #[getter]
    fn guide_torque_nm(&self) -> PyResult<Vec<f64>> {
        Ok(self.lock()?.guide_torque().to_vec())
    }

    /// The last cycle's distance of the tool point from its plane or line [m], and its
    /// rotation from the locked orientation [rad] (0 where the mode holds neither).
    #[getter]
    fn guide_deviation(&self) -> PyResult<(f64, f64)> {
        let law = self.lock()?;
        Ok((law.guide.deviation_m(), law.guide.rotation_rad()))
    }

    /// The tool speed the commands are held to [m/s].
    #[getter]
    fn speed_target_m_s(&self) -> PyResult<f64> {
        Ok(self.lock()?.speed_target_m_s())
    }

    #[setter]
    fn set_speed_target_m_s(&self, value: f64) -> PyResult<()> {
        self.lock()?.set_speed_target(value);
        Ok(())
    }

    /// The model's friction at `q` just above rest, per joint [N·m] (0 where undefined).
    fn friction_level_nm(&self, py: Python<'_>, q: Vec<f64>) -> PyResult<Vec<f64>> {
        self.check(&q, "q")?;
        let mut out = vec![0.0; self.n];
        self.with_parts(py, |law, parts| {
            law.friction_level_at(parts.model, &q, &mut out);
            Ok(())
        })?;
        Ok(out)
    }

    /// M(q)⁻¹ of the nominal rigid body with rotor inertias (cached, module docs).
    fn inverse_inertia(&self, py: Python<'_>, q: Vec<f64>) -> PyResult<Vec<Vec<f64>>> {
        self.check(&q, "q")?;
        self.with_parts(py, |law, parts| {
            let (chain, work) = parts
                .chain
                .as_mut()
                .ok_or_else(|| "no nominal chain".to_string())?;
            law.refresh_inertia(chain, work, &q)?;
            Ok(rows(law.m_inv(), law.s.n))
        })
    }

    /// M(q) of the nominal rigid body with rotor inertias (cached as `inverse_inertia`'s).
    fn inertia(&self, py: Python<'_>, q: Vec<f64>) -> PyResult<Vec<Vec<f64>>> {
        self.check(&q, "q")?;
        self.with_parts(py, |law, parts| {
            let (chain, work) = parts
                .chain
                .as_mut()
                .ok_or_else(|| "no nominal chain".to_string())?;
            law.refresh_inertia(chain, work, &q)?;
            Ok(rows(law.m(), law.s.n))
        })
    }

    /// The constrained guide as the admittance holds it at its reference `q` (law/guide.rs,
    /// `Guide::constraint`): its rows on the reference's speed and their rates, ([] , []) in
    /// "free"; the first call after :meth:`restart_guide` or a change of mode takes the
    /// reference there.
    #[allow(clippy::type_complexity)]
    fn guide_constraint_at(
        &self,
        py: Python<'_>,
        q: Vec<f64>,
    ) -> PyResult<(Vec<Vec<f64>>, Vec<f64>)> {
        self.check(&q, "q")?;
        let n = q.len();
        self.with_parts(py, |law, parts| {
            let mut rows = [0.0; 5 * MAX_JOINTS];
            let mut rates = [0.0; 5];
            let m = if let Some((chain, work)) = parts.chain.as_mut() {
                law.guide
                    .constraint(chain, work, &q, &mut rows[..5 * n], &mut rates)
            } else if law.guide.mode() != GuideMode::Free {
                return Err("constrained guiding needs the nominal chain".into());
            } else {
                0
            };
            Ok((
                (0..m).map(|i| rows[i * n..(i + 1) * n].to_vec()).collect(),
                rates[..m].to_vec(),
            ))
        })
    }

    /// The constrained guide takes its reference again at the next cycle (the admittance
    /// engages).
    fn restart_guide(&self) -> PyResult<()> {
        self.lock()?.guide.restart();
        Ok(())
    }

    /// The faster of the tool point and the flange at (q, dq) [m/s].
    fn point_speed(&self, py: Python<'_>, q: Vec<f64>, dq: Vec<f64>) -> PyResult<f64> {
        self.check(&q, "q")?;
        self.check(&dq, "dq")?;
        self.with_parts(py, |law, parts| {
            let (chain, work) = parts
                .chain
                .as_mut()
                .ok_or_else(|| "no nominal chain".to_string())?;
            Ok(law.point_speed(chain, work, &q, &dq))
        })
    }

    /// The speed the commands are to be held to at (q, dq) [m/s] (not stored: set
    /// `speed_target_m_s`).
    fn speed_target(&self, py: Python<'_>, q: Vec<f64>, dq: Vec<f64>) -> PyResult<f64> {
        self.check(&q, "q")?;
        self.check(&dq, "dq")?;
        self.with_parts(py, |law, parts| {
            let (chain, work) = parts
                .chain
                .as_mut()
                .ok_or_else(|| "no nominal chain".to_string())?;
            Ok(law.speed_target(chain, work, &q, &dq))
        })
    }

    /// The factor (≤ 1) on `dq` that keeps the tool point and the flange within the speed
    /// target.
    fn tool_speed_scale(&self, py: Python<'_>, q: Vec<f64>, dq: Vec<f64>) -> PyResult<f64> {
        self.check(&q, "q")?;
        self.check(&dq, "dq")?;
        self.with_parts(py, |law, parts| {
            let (chain, work) = parts
                .chain
                .as_mut()
                .ok_or_else(|| "no nominal chain".to_string())?;
            Ok(law.tool_speed_scale(chain, work, &q, &dq))
        })
    }

    /// The command offset `q_c - q` [rad] at which the vendor loop gives the model's torque
    /// at (q, dq): eq. (21)'s steady state `ω̂ τ / Υ̂_I`.
    fn hold_offset(
        &self,
        py: Python<'_>,
        q: Vec<f64>,
        dq: Vec<f64>,
        p_bar: Vec<f64>,
    ) -> PyResult<Vec<f64>> {
        self.check(&q, "q")?;
        self.check(&dq, "dq")?;
        let mut out = vec![0.0; self.n];
        self.with_parts(py, |law, parts| {
            law.hold_offset(parts.model, parts.outer, &q, &dq, &p_bar, &mut out)
        })?;
        Ok(out)
    }

    /// The motor torque a state reports: datasheet K × measured current [N·m].
    fn motor_torque_nm(&self, current_a: Vec<f64>) -> PyResult<Vec<f64>> {
        self.check(&current_a, "current_a")?;
        let mut out = vec![0.0; self.n];
        self.lock()?.motor_torque(&current_a, &mut out);
        Ok(out)
    }
}

pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<PyZeroMomentCycle>()?;
    Ok(())
}
