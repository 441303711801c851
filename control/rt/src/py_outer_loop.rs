//! `control._rt`'s outer loop (law/outer_loop.rs): the classes the control process
//! and the tests use, arrays taken as any float sequence and returned as lists of floats.
//!
//! * `OmegaAdaptation(rate_per_s, min_torque_nm)`, `PaperAdaptation(rate_per_s,
//!   min_torque_nm, upsilon_ratio=2.0, dead_zone_nm=(), bound_factor=50.0)`: frozen settings,
//!   `check(n)` raising ValueError.
//! * `HoldAverage(size=64)`: `add`, `clear`, `len()`, `mean()`, `torque_std()`.
//! * `OuterLoopCommand`: what `OuterLoop.step` returns (lists; `saturated` of bools).
//! * `OuterLoop(omega, upsilon_i, max_offset_rad, max_velocity_rad_s, adaptation=None)`.
//!
//! A wrong length or a bad setting raises ValueError naming it.

use std::sync::{Mutex, MutexGuard};

use pyo3::exceptions::{PyRuntimeError, PyTypeError, PyValueError};
use pyo3::prelude::*;
use pyo3::types::{PyDict, PyTuple};

use crate::law::outer_loop::{
    Adaptation, HoldAverage, OmegaAdaptation, OuterLoop, PaperAdaptation,
};
use crate::py_args::check_len;

fn tuple<'py>(py: Python<'py>, v: &[f64]) -> PyResult<Bound<'py, PyTuple>> {
    PyTuple::new(py, v)
}

/// Settings of eq. (28) (law/outer_loop.rs, module docs).
#[pyclass(frozen, name = "OmegaAdaptation", module = "control._rt")]
pub struct PyOmegaAdaptation {
    inner: OmegaAdaptation,
}

#[pymethods]
impl PyOmegaAdaptation {
    #[new]
    fn new(rate_per_s: f64, min_torque_nm: Vec<f64>) -> Self {
        PyOmegaAdaptation {
            inner: OmegaAdaptation {
                rate_per_s,
                min_torque_nm,
            },
        }
    }

    /// γ: how fast ω̂ converges [1/s]
    #[getter]
    fn rate_per_s(&self) -> f64 {
        self.inner.rate_per_s
    }

    /// per joint: no adaptation while |τ̂| is below this [N·m]
    #[getter]
    fn min_torque_nm<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyTuple>> {
        tuple(py, &self.inner.min_torque_nm)
    }

    /// ValueError unless the settings suit `n` joints.
    fn check(&self, n: usize) -> PyResult<()> {
        self.inner.check(n).map_err(PyValueError::new_err)
    }

    fn __repr__(&self) -> String {
        let a = &self.inner;
        format!(
            "OmegaAdaptation(rate_per_s={:?}, min_torque_nm={:?})",
            a.rate_per_s, a.min_torque_nm
        )
    }
}

/// Settings of eqs. (28) and (30) together (law/outer_loop.rs, "The paper's laws").
#[pyclass(frozen, name = "PaperAdaptation", module = "control._rt")]
pub struct PyPaperAdaptation {
    inner: PaperAdaptation,
}

#[pymethods]
impl PyPaperAdaptation {
    #[new]
    #[pyo3(signature = (
        rate_per_s,
        min_torque_nm,
        upsilon_ratio=PaperAdaptation::UPSILON_RATIO,
        dead_zone_nm=Vec::new(),
        bound_factor=PaperAdaptation::BOUND_FACTOR,
    ))]
    fn new(
        rate_per_s: f64,
        min_torque_nm: Vec<f64>,
        upsilon_ratio: f64,
        dead_zone_nm: Vec<f64>,
        bound_factor: f64,
    ) -> Self {
        PyPaperAdaptation {
            inner: PaperAdaptation {
                rate_per_s,
                min_torque_nm,
                upsilon_ratio,
                dead_zone_nm,
                bound_factor,
            },
        }
    }

    /// γ: how fast the estimates converge [1/s] (the paper's Λ, normalised)
    #[getter]
    fn rate_per_s(&self) -> f64 {
        self.inner.rate_per_s
    }

    /// per joint: no adaptation while |φ| is below this [N·m]
    #[getter]
    fn min_torque_nm<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyTuple>> {
        tuple(py, &self.inner.min_torque_nm)
    }

    /// Λ_I / Λ (the paper: 0.02 / 0.01)
    #[getter]
    fn upsilon_ratio(&self) -> f64 {
        self.inner.upsilon_ratio
    }

    /// per joint: the dead zone's floor on |τ_m - τ̂| [N·m] (empty: none)
    #[getter]
    fn dead_zone_nm<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyTuple>> {
        tuple(py, &self.inner.dead_zone_nm)
    }

    /// ω̂ and Υ̂_I stay within this factor of where they started
    #[getter]
    fn bound_factor(&self) -> f64 {
        self.inner.bound_factor
    }

    /// ValueError unless the settings suit `n` joints.
    fn check(&self, n: usize) -> PyResult<()> {
        self.inner.check(n).map_err(PyValueError::new_err)
    }

    fn __repr__(&self) -> String {
        let a = &self.inner;
        format!(
            "PaperAdaptation(rate_per_s={:?}, min_torque_nm={:?}, upsilon_ratio={:?}, \
             dead_zone_nm={:?}, bound_factor={:?})",
            a.rate_per_s, a.min_torque_nm, a.upsilon_ratio, a.dead_zone_nm, a.bound_factor
        )
    }
}

/// Mean held offset and motor torque over the last `size` states of a drive holding the arm
/// at rest, for `OuterLoop.calibrate_from_hold`.
#[pyclass(frozen, name = "HoldAverage", module = "control._rt")]
pub struct PyHoldAverage {
    hold: Mutex<HoldAverage>,
}

impl PyHoldAverage {
    /// The lock without the GIL's error type (the compiled loop's thread).
    pub(crate) fn state_lock(
        &self,
    ) -> Result<MutexGuard<'_, HoldAverage>, std::sync::PoisonError<MutexGuard<'_, HoldAverage>>>
    {
        self.hold.lock()
    }

    pub(crate) fn lock(&self) -> PyResult<MutexGuard<'_, HoldAverage>> {
        self.hold
            .lock()
            .map_err(|_| PyRuntimeError::new_err("the hold average's lock is poisoned"))
    }
}

#[pymethods]
impl PyHoldAverage {
    #[new]
    #[pyo3(signature = (size=HoldAverage::SIZE as i64))]
    fn new(size: i64) -> PyResult<Self> {
        let size = usize::try_from(size)
            .map_err(|_| PyValueError::new_err(format!("size {size} must be >= 0")))?;
        Ok(PyHoldAverage {
            hold: Mutex::new(HoldAverage::new(size)),
        })
    }

    /// One held state: offset q_c - q [rad] and motor torque [N·m] per joint.
    fn add(&self, offset_rad: Vec<f64>, tau_m_nm: Vec<f64>) -> PyResult<()> {
        self.lock()?
            .add(&offset_rad, &tau_m_nm)
            .map_err(PyValueError::new_err)
    }

    fn clear(&self) -> PyResult<()> {
        self.lock()?.clear();
        Ok(())
    }

    fn __len__(&self) -> PyResult<usize> {
        Ok(self.lock()?.len())
    }

    /// The held motor torque's standard deviation per joint [N·m] (its noise at rest);
    /// ValueError with fewer than two states.
    fn torque_std(&self) -> PyResult<Vec<f64>> {
        let hold = self.lock()?;
        let mut std = vec![0.0; hold.n()];
        hold.torque_std(&mut std).map_err(PyValueError::new_err)?;
        Ok(std)
    }

    /// (offset, torque) averaged per joint; ValueError when empty.
    fn mean(&self) -> PyResult<(Vec<f64>, Vec<f64>)> {
        let hold = self.lock()?;
        let (mut offs, mut taus) = (vec![0.0; hold.n()], vec![0.0; hold.n()]);
        hold.mean(&mut offs, &mut taus)
            .map_err(PyValueError::new_err)?;
        Ok((offs, taus))
    }
}

/// The command `OuterLoop.step` returns.
#[pyclass(frozen, get_all, name = "OuterLoopCommand", module = "control._rt")]
pub struct PyOuterLoopCommand {
    q_cmd_rad: Vec<f64>,
    dq_cmd_rad_s: Vec<f64>,
    /// e = q_cmd - q, the offset the command carries [rad]
    offset_rad: Vec<f64>,
    /// per joint: the offset or velocity limit was hit
    saturated: Vec<bool>,
}

#[pymethods]
impl PyOuterLoopCommand {
    #[new]
    fn new(
        q_cmd_rad: Vec<f64>,
        dq_cmd_rad_s: Vec<f64>,
        offset_rad: Vec<f64>,
        saturated: Vec<bool>,
    ) -> Self {
        PyOuterLoopCommand {
            q_cmd_rad,
            dq_cmd_rad_s,
            offset_rad,
            saturated,
        }
    }

    fn __repr__(&self) -> String {
        format!(
            "OuterLoopCommand(q_cmd_rad={:?}, dq_cmd_rad_s={:?}, offset_rad={:?}, saturated={:?})",
            self.q_cmd_rad, self.dq_cmd_rad_s, self.offset_rad, self.saturated
        )
    }
}

/// Discrete eq. (21) with per-joint limits on the offset and the velocity command, ω̂ (and
/// Υ̂_I) adapted by eq. (28) (and 30) when an adaptation is given.
#[pyclass(frozen, name = "OuterLoop", module = "control._rt")]
pub struct PyOuterLoop {
    state: Mutex<OuterLoop>,
    /// the settings object given, returned as is by `adaptation`
    adaptation: Option<Py<PyAny>>,
    n: usize,
}

impl PyOuterLoop {
    /// The lock without the GIL's error type (the compiled loop's thread).
    pub(crate) fn state_lock(
        &self,
    ) -> Result<MutexGuard<'_, OuterLoop>, std::sync::PoisonError<MutexGuard<'_, OuterLoop>>> {
        self.state.lock()
    }

    pub(crate) fn lock(&self) -> PyResult<MutexGuard<'_, OuterLoop>> {
        self.state
            .lock()
            .map_err(|_| PyRuntimeError::new_err("the outer loop's lock is poisoned"))
    }

    fn check(&self, v: &[f64], what: &str) -> PyResult<()> {
        check_len(v, self.n, what)
    }

    fn copied(&self, py: Python<'_>) -> PyResult<PyOuterLoop> {
        Ok(PyOuterLoop {
            state: Mutex::new(self.lock()?.clone()),
            adaptation: self.adaptation.as_ref().map(|a| a.clone_ref(py)),
            n: self.n,
        })
    }

    /// The cycle of `step` and `step_floats`: (q_cmd, dq_cmd, offset carried, saturated).
    #[allow(clippy::type_complexity)]
    fn cycle(
        &self,
        q_rad: &[f64],
        dq_rad_s: &[f64],
        tau_d_nm: &[f64],
        dt_s: f64,
    ) -> PyResult<(Vec<f64>, Vec<f64>, Vec<f64>, Vec<bool>)> {
        self.check(q_rad, "q_rad")?;
        self.check(dq_rad_s, "dq_rad_s")?;
        self.check(tau_d_nm, "tau_d_nm")?;
        let n = self.n;
        let (mut q_cmd, mut dq_cmd, mut sat) = (vec![0.0; n], vec![0.0; n], vec![false; n]);
        let mut lp = self.lock()?;
        let offset = lp.offset_rad().to_vec();
        lp.step(
            q_rad,
            dq_rad_s,
            tau_d_nm,
            dt_s,
            &mut q_cmd,
            &mut dq_cmd,
            &mut sat,
        );
        Ok((q_cmd, dq_cmd, offset, sat))
    }
}

fn adaptation_arg(a: Option<&Bound<'_, PyAny>>) -> PyResult<Adaptation> {
    let Some(a) = a.filter(|a| !a.is_none()) else {
        return Ok(Adaptation::None);
    };
    if let Ok(o) = a.cast::<PyOmegaAdaptation>() {
        return Ok(Adaptation::Omega(o.get().inner.clone()));
    }
    if let Ok(p) = a.cast::<PyPaperAdaptation>() {
        return Ok(Adaptation::Paper(p.get().inner.clone()));
    }
    Err(PyTypeError::new_err(format!(
        "adaptation must be OmegaAdaptation, PaperAdaptation or None, got {}",
        a.get_type().name()?
    )))
}

#[pymethods]
impl PyOuterLoop {
    #[new]
    #[pyo3(signature = (omega, upsilon_i, max_offset_rad, max_velocity_rad_s, adaptation=None))]
    fn new(
        omega: Vec<f64>,
        upsilon_i: Vec<f64>,
        max_offset_rad: Vec<f64>,
        max_velocity_rad_s: Vec<f64>,
        adaptation: Option<Bound<'_, PyAny>>,
    ) -> PyResult<Self> {
        let law = adaptation_arg(adaptation.as_ref())?;
        let lp = OuterLoop::new(
            &omega,
            &upsilon_i,
            &max_offset_rad,
            &max_velocity_rad_s,
            law,
        )
        .map_err(PyValueError::new_err)?;
        let n = lp.n();
        Ok(PyOuterLoop {
            state: Mutex::new(lp),
            adaptation: adaptation.filter(|a| !a.is_none()).map(Bound::unbind),
            n,
        })
    }

    /// ω̂ per joint now [rad/s per N·m] (a copy).
    #[getter]
    fn omega(&self) -> PyResult<Vec<f64>> {
        Ok(self.lock()?.omega().to_vec())
    }

    /// Υ̂_I per joint now [1/s] (a copy).
    #[getter]
    fn upsilon_i(&self) -> PyResult<Vec<f64>> {
        Ok(self.lock()?.upsilon_i().to_vec())
    }

    /// ω̂₀ as constructed [rad/s per N·m].
    #[getter]
    fn omega0(&self) -> PyResult<Vec<f64>> {
        Ok(self.lock()?.omega0().to_vec())
    }

    /// Υ̂_I₀ as constructed [1/s].
    #[getter]
    fn upsilon_i0(&self) -> PyResult<Vec<f64>> {
        Ok(self.lock()?.upsilon_i0().to_vec())
    }

    #[getter]
    fn max_offset_rad(&self) -> PyResult<Vec<f64>> {
        Ok(self.lock()?.max_offset_rad().to_vec())
    }

    #[getter]
    fn max_velocity_rad_s(&self) -> PyResult<Vec<f64>> {
        Ok(self.lock()?.max_velocity_rad_s().to_vec())
    }

    /// The OmegaAdaptation or PaperAdaptation given, or None.
    #[getter]
    fn adaptation(&self, py: Python<'_>) -> Option<Py<PyAny>> {
        self.adaptation.as_ref().map(|a| a.clone_ref(py))
    }

    /// PaperAdaptation's dead zone per joint [N·m] (zeros for the other laws).
    #[getter]
    fn dead_zone_nm(&self) -> PyResult<Vec<f64>> {
        Ok(self.lock()?.dead_zone_nm().to_vec())
    }

    /// e = q_cmd - q that the next command carries [rad] (a copy).
    #[getter]
    fn offset_rad(&self) -> PyResult<Vec<f64>> {
        Ok(self.lock()?.offset_rad().to_vec())
    }

    #[setter]
    fn set_offset_rad(&self, value: Vec<f64>) -> PyResult<()> {
        self.check(&value, "offset_rad")?;
        self.lock()?.set_offset_rad(&value);
        Ok(())
    }

    /// PaperAdaptation's dead zone from the motor torque's noise measured at rest [N·m]:
    /// 3 standard deviations per joint, at least the configured floor.
    fn set_dead_zone(&self, noise_std_nm: Vec<f64>) -> PyResult<()> {
        let mut lp = self.lock()?;
        if matches!(lp.adaptation(), Adaptation::Paper(_)) {
            self.check(&noise_std_nm, "noise_std_nm")?;
            lp.set_dead_zone(&noise_std_nm);
        }
        Ok(())
    }

    /// Take over from the command the robot currently follows (bumpless transfer), the
    /// offset clipped to its limits. ω̂ keeps what it learnt.
    fn reset(&self, offset_rad: Vec<f64>) -> PyResult<()> {
        self.check(&offset_rad, "offset_rad")?;
        self.lock()?.reset(&offset_rad);
        Ok(())
    }

    /// Eq. (28) (OmegaAdaptation) or eqs. (28) and (30) (PaperAdaptation) for a cycle the
    /// drive followed as sent: its means u₁ = mean(dq_c - dq) [rad/s] and u₂ = mean(q_c - q)
    /// [rad], and the motor torque measured over it [N·m].
    fn adapt(
        &self,
        u1_rad_s: Vec<f64>,
        u2_rad: Vec<f64>,
        tau_m_nm: Vec<f64>,
        dt_s: f64,
    ) -> PyResult<()> {
        let mut lp = self.lock()?;
        if *lp.adaptation() == Adaptation::None {
            return Ok(());
        }
        self.check(&u1_rad_s, "u1_rad_s")?;
        self.check(&u2_rad, "u2_rad")?;
        self.check(&tau_m_nm, "tau_m_nm")?;
        lp.adapt(&u1_rad_s, &u2_rad, &tau_m_nm, dt_s);
        Ok(())
    }

    /// ω̂ from the drive holding the arm at rest: the held offset q_c - q [rad] and the
    /// motor torque [N·m] measure K K_I (law/outer_loop.rs).
    fn calibrate_from_hold(&self, offset_rad: Vec<f64>, tau_m_nm: Vec<f64>) -> PyResult<()> {
        let mut lp = self.lock()?;
        if *lp.adaptation() == Adaptation::None {
            return Ok(());
        }
        self.check(&offset_rad, "offset_rad")?;
        self.check(&tau_m_nm, "tau_m_nm")?;
        lp.calibrate_from_hold(&offset_rad, &tau_m_nm);
        Ok(())
    }

    /// One controller cycle of eq. (21); returns the command to send now.
    fn step(
        &self,
        q_rad: Vec<f64>,
        dq_rad_s: Vec<f64>,
        tau_d_nm: Vec<f64>,
        dt_s: f64,
    ) -> PyResult<PyOuterLoopCommand> {
        let (q_cmd_rad, dq_cmd_rad_s, offset_rad, saturated) =
            self.cycle(&q_rad, &dq_rad_s, &tau_d_nm, dt_s)?;
        Ok(PyOuterLoopCommand {
            q_cmd_rad,
            dq_cmd_rad_s,
            offset_rad,
            saturated,
        })
    }

    /// `step`, the per-cycle form: `(q_cmd, dq_cmd)` only (the same arithmetic).
    fn step_floats(
        &self,
        q_rad: Vec<f64>,
        dq_rad_s: Vec<f64>,
        tau_d_nm: Vec<f64>,
        dt_s: f64,
    ) -> PyResult<(Vec<f64>, Vec<f64>)> {
        let (q_cmd, dq_cmd, _, _) = self.cycle(&q_rad, &dq_rad_s, &tau_d_nm, dt_s)?;
        Ok((q_cmd, dq_cmd))
    }

    fn __copy__(&self, py: Python<'_>) -> PyResult<PyOuterLoop> {
        self.copied(py)
    }

    /// A copy with its own state (the adaptation's settings are frozen: shared).
    fn __deepcopy__(&self, py: Python<'_>, _memo: &Bound<'_, PyDict>) -> PyResult<PyOuterLoop> {
        self.copied(py)
    }
}

pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<PyOmegaAdaptation>()?;
    m.add_class::<PyPaperAdaptation>()?;
    m.add_class::<PyHoldAverage>()?;
    m.add_class::<PyOuterLoopCommand>()?;
    m.add_class::<PyOuterLoop>()?;
    Ok(())
}
