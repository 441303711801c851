//! The compiled model's classes of `control._rt` (registered by py_module.rs), as the control
//! process and the tests see them (control/rt_tables.py writes the tables).
//!
//! * `Chain(table_json)`: the rigid-body chain (chain.rs): inverse dynamics, its regressor,
//!   the mass matrix, the tool's pose and Jacobian, as nested lists of floats.
//! * `PointModel(table_json)`: the model the law compensates (point_model.rs):
//!   `torque_nm`, `cycle_torques_nm`, `cylinder_torques_nm`.
//!
//! A bad table or argument raises ValueError naming what was wrong; a model torque that is not
//! finite raises ArithmeticError (the caller refuses the sample, as it did with `math`'s).

use std::sync::{Mutex, MutexGuard};

use pyo3::exceptions::{PyArithmeticError, PyRuntimeError, PyValueError};
use pyo3::prelude::*;

use crate::chain::{Chain, Work, MAX_JOINTS};
use crate::point_model::PointModel;
use crate::py_args::check_len;

fn json_arg(text: &str, what: &str) -> PyResult<serde_json::Value> {
    serde_json::from_str(text).map_err(|e| PyValueError::new_err(format!("{what}: not JSON ({e})")))
}

fn rows(flat: &[f64], width: usize) -> Vec<Vec<f64>> {
    flat.chunks(width).map(<[f64]>::to_vec).collect()
}

pub(crate) struct ChainState {
    pub(crate) chain: Chain,
    pub(crate) work: Work,
}

/// The rigid-body chain (chain.rs).
#[pyclass(frozen, name = "Chain", module = "control._rt")]
pub struct PyChain {
    state: Mutex<ChainState>,
    n: usize,
}

impl PyChain {
    /// The lock without the GIL's error type (the compiled loop's thread).
    pub(crate) fn state_lock(
        &self,
    ) -> Result<MutexGuard<'_, ChainState>, std::sync::PoisonError<MutexGuard<'_, ChainState>>>
    {
        self.state.lock()
    }

    pub(crate) fn lock(&self) -> PyResult<MutexGuard<'_, ChainState>> {
        self.state
            .lock()
            .map_err(|_| PyRuntimeError::new_err("the chain's lock is poisoned"))
    }

    fn check(&self, v: &[f64], what: &str) -> PyResult<()> {
        check_len(v, self.n, what)
    }
}

#[pymethods]
impl PyChain {
    #[new]
    fn new(table_json: &str) -> PyResult<Self> {
        let chain = Chain::from_json(&json_arg(table_json, "chain table")?)
            .map_err(PyValueError::new_err)?;
        let n = chain.n();
        Ok(PyChain {
            state: Mutex::new(ChainState {
                chain,
                work: Work::default(),
            }),
            n,
        })
    }

    #[getter]
    fn n(&self) -> usize {
        self.n
    }

    /// Inverse dynamics [N·m] at (q, dq, ddq).
    #[pyo3(signature = (q, dq, ddq, gravity=true, armature=false))]
    fn rnea(
        &self,
        q: Vec<f64>,
        dq: Vec<f64>,
        ddq: Vec<f64>,
        gravity: bool,
        armature: bool,
    ) -> PyResult<Vec<f64>> {
        self.check(&q, "q")?;
        self.check(&dq, "dq")?;
        self.check(&ddq, "ddq")?;
        let mut s = self.lock()?;
        let ChainState { chain, work } = &mut *s;
        let mut tau = vec![0.0; self.n];
        chain.rnea(&q, &dq, &ddq, gravity, armature, work, &mut tau);
        Ok(tau)
    }

    /// The joint-torque regressor (n rows of 10 n).
    fn regressor(&self, q: Vec<f64>, dq: Vec<f64>, ddq: Vec<f64>) -> PyResult<Vec<Vec<f64>>> {
        self.check(&q, "q")?;
        self.check(&dq, "dq")?;
        self.check(&ddq, "ddq")?;
        let mut s = self.lock()?;
        let ChainState { chain, work } = &mut *s;
        let mut y = vec![0.0; 10 * self.n * self.n];
        chain.regressor(&q, &dq, &ddq, work, &mut y);
        Ok(rows(&y, 10 * self.n))
    }

    /// M(q) (n rows), with the rotors' armature when `armature`.
    #[pyo3(signature = (q, armature=false))]
    fn mass_matrix(&self, q: Vec<f64>, armature: bool) -> PyResult<Vec<Vec<f64>>> {
        self.check(&q, "q")?;
        let mut s = self.lock()?;
        let ChainState { chain, work } = &mut *s;
        let mut m = vec![0.0; self.n * self.n];
        chain.mass_matrix(&q, armature, work, &mut m);
        Ok(rows(&m, self.n))
    }

    /// The tool frame in the world: (rotation rows, origin [m]).
    fn tool_pose(&self, q: Vec<f64>) -> PyResult<(Vec<Vec<f64>>, Vec<f64>)> {
        self.check(&q, "q")?;
        let mut s = self.lock()?;
        let ChainState { chain, work } = &mut *s;
        let x = chain.tool_pose(&q, work);
        Ok((x.r.iter().map(|r| r.to_vec()).collect(), x.p.to_vec()))
    }

    /// The tool's Jacobian, 6 rows (linear then angular velocity, world axes).
    fn tool_jacobian(&self, q: Vec<f64>) -> PyResult<Vec<Vec<f64>>> {
        self.check(&q, "q")?;
        let mut s = self.lock()?;
        let ChainState { chain, work } = &mut *s;
        let mut jac = [0.0; 6 * MAX_JOINTS];
        chain.tool_jacobian(&q, work, &mut jac);
        Ok(rows(&jac[..6 * self.n], self.n))
    }
}

/// The model the law compensates (point_model.rs).
#[pyclass(frozen, name = "PointModel", module = "control._rt")]
pub struct PyPointModel {
    model: Mutex<PointModel>,
    n: usize,
    n_cylinders: usize,
}

impl PyPointModel {
    /// The lock without the GIL's error type (the compiled loop's thread).
    pub(crate) fn state_lock(
        &self,
    ) -> Result<MutexGuard<'_, PointModel>, std::sync::PoisonError<MutexGuard<'_, PointModel>>>
    {
        self.model.lock()
    }

    pub(crate) fn lock(&self) -> PyResult<MutexGuard<'_, PointModel>> {
        self.model
            .lock()
            .map_err(|_| PyRuntimeError::new_err("the model's lock is poisoned"))
    }
}

#[pymethods]
impl PyPointModel {
    #[new]
    fn new(table_json: &str) -> PyResult<Self> {
        let model = PointModel::from_json(&json_arg(table_json, "point model table")?)
            .map_err(PyValueError::new_err)?;
        let (n, n_cylinders) = (model.n(), model.n_cylinders());
        Ok(PyPointModel {
            model: Mutex::new(model),
            n,
            n_cylinders,
        })
    }

    #[getter]
    fn n(&self) -> usize {
        self.n
    }

    /// Joint torque [N·m] at (q, dq) and ddq = 0 (dq None: at rest), cylinders excluded.
    #[pyo3(signature = (q, dq=None))]
    fn torque_nm(&self, q: Vec<f64>, dq: Option<Vec<f64>>) -> PyResult<Vec<f64>> {
        check_len(&q, self.n, "q")?;
        if let Some(d) = &dq {
            check_len(d, self.n, "dq")?;
        }
        let mut out = vec![0.0; self.n];
        self.lock()?.torque(&q, dq.as_deref(), &mut out);
        Ok(out)
    }

    /// The cylinders' joint torques [N·m] at q with one pressure per cylinder [bar].
    fn cylinder_torques_nm(&self, q: Vec<f64>, p_bar: Vec<f64>) -> PyResult<Vec<f64>> {
        check_len(&q, self.n, "q")?;
        check_len(&p_bar, self.n_cylinders, "p_bar")?;
        let mut out = vec![0.0; self.n];
        self.lock()?.cylinder_torques(&q, &p_bar, &mut out);
        Ok(out)
    }

    /// (torque at rest less the cylinders', what moving at dq adds) [N·m]; ArithmeticError
    /// where the model's torque is not finite.
    fn cycle_torques_nm(
        &self,
        q: Vec<f64>,
        dq: Vec<f64>,
        p_bar: Vec<f64>,
    ) -> PyResult<(Vec<f64>, Vec<f64>)> {
        check_len(&q, self.n, "q")?;
        check_len(&dq, self.n, "dq")?;
        check_len(&p_bar, self.n_cylinders, "p_bar")?;
        let (mut stat, mut fric) = (vec![0.0; self.n], vec![0.0; self.n]);
        self.lock()?
            .cycle_torques(&q, &dq, &p_bar, &mut stat, &mut fric)
            .map_err(PyArithmeticError::new_err)?;
        Ok((stat, fric))
    }
}

pub(crate) fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<PyChain>()?;
    m.add_class::<PyPointModel>()?;
    Ok(())
}
