//! `control._rt.AdmittanceCycle` (law/admittance/cycle.rs): the admittance law's cycle, built by
//! control/admittance_law.py's `AdmittanceController` over the zero-moment law's compiled cycle
//! (whose pieces it shares: the hold, ω̂, the motor torque, the speed limit, the guide) and the
//! `Admittance` of (A1)/(A2), both borrowed each call; the compiled loop
//! (py_cycle_loop.rs) answers teaching's states with it without the GIL. Also the stick anchor,
//! the start-up dither and the soft walls on their own (`StickAnchor`, `StartupDither`,
//! `wall_torque_nm`), as the tests drive them.
//!
//! Where the model cannot be evaluated a call raises ArithmeticError (a torque not finite) or
//! ValueError (a bad argument, a singular matrix, an undefined estimate).

use std::sync::{Mutex, MutexGuard};

use pyo3::exceptions::{PyRuntimeError, PyValueError};
use pyo3::prelude::*;

use crate::chain::MAX_JOINTS;
use crate::law::admittance::cycle::{self as cyc, AdmittanceCycle, Settings};
use crate::law::admittance::soft_walls;
use crate::law::admittance::startup_dither::{self as sd, StartupDither};
use crate::law::admittance::stick_anchor::{self as sa, StickAnchor};
use crate::law::zero_moment::State;
use crate::py_admittance::PyAdmittance;
use crate::py_args::check_len;
use crate::py_zero_moment::{law_error, PyZeroMomentCycle};

fn flat(rows: &[Vec<f64>], n: usize, what: &str) -> PyResult<Vec<f64>> {
    if rows.len() != n || rows.iter().any(|r| r.len() != n) {
        return Err(PyValueError::new_err(format!(
            "{what} needs {n} rows of {n}"
        )));
    }
    Ok(rows.concat())
}

fn settings(v: &serde_json::Value) -> Result<Settings, String> {
    let num = |k: &str| {
        v.get(k)
            .and_then(serde_json::Value::as_f64)
            .ok_or_else(|| format!("admittance settings: {k} missing or not a number"))
    };
    let max_offset_rad = v
        .get("max_offset_rad")
        .and_then(serde_json::Value::as_array)
        .ok_or("admittance settings: max_offset_rad missing or not a list")?
        .iter()
        .map(|x| {
            x.as_f64()
                .ok_or("admittance settings: max_offset_rad not numbers")
        })
        .collect::<Result<Vec<f64>, _>>()?;
    let anchor = match v.get("stick").and_then(serde_json::Value::as_str) {
        Some("anchor") => true,
        Some("zone") => false,
        other => {
            return Err(format!(
                "admittance settings: stick {other:?} is neither \"anchor\" nor \"zone\""
            ))
        }
    };
    let identified_mass = v
        .get("identified_mass")
        .and_then(serde_json::Value::as_bool)
        .ok_or("admittance settings: identified_mass missing or not a bool")?;
    Ok(Settings {
        max_offset_rad,
        stick_zone: num("stick_zone")?,
        anchor,
        probe_speed_rad_s: num("probe_speed_rad_s")?,
        probe_s: num("probe_s")?,
        dither: num("dither")?,
        dither_hz: num("dither_hz")?,
        identified_mass,
        inertia_step_rad: num("inertia_step_rad")?,
    })
}

/// The admittance law's cycle (law/admittance/cycle.rs).
#[pyclass(frozen, name = "AdmittanceCycle", module = "control._rt")]
pub struct PyAdmittanceCycle {
    cycle: Mutex<AdmittanceCycle>,
    zero_moment: Py<PyZeroMomentCycle>,
    admittance: Py<PyAdmittance>,
    n: usize,
}

impl PyAdmittanceCycle {
    fn lock(&self) -> PyResult<MutexGuard<'_, AdmittanceCycle>> {
        self.cycle
            .lock()
            .map_err(|_| PyRuntimeError::new_err("the admittance cycle's lock is poisoned"))
    }

    /// The answer to one state, for the compiled loop (no GIL): `(q_cmd, dq_cmd)` into the
    /// outputs; Err as [`AdmittanceCycle::answer`]'s.
    pub(crate) fn answer_state(
        &self,
        st: &State,
        p_bar: &[f64],
        q_cmd: &mut [f64],
        dq_cmd: &mut [f64],
    ) -> Result<(), String> {
        self.zero_moment.get().locked(|law, parts| {
            let mut adm = self.admittance.get().state_lock()?;
            let mut cycle = self
                .cycle
                .lock()
                .map_err(|_| "the admittance cycle's lock is poisoned".to_string())?;
            cycle.answer(law, parts, &mut adm, st, p_bar, q_cmd, dq_cmd)
        })
    }

    /// The zero-moment law's cycle this one shares its pieces with.
    pub(crate) fn zero_moment(&self) -> &PyZeroMomentCycle {
        self.zero_moment.get()
    }

    /// Stop following (the loop's error path, or a plan plays).
    pub(crate) fn disengage_now(&self) {
        if let Ok(mut cycle) = self.cycle.lock() {
            cycle.disengage();
        }
        self.zero_moment.get().disengage_now();
    }

    pub(crate) fn joints(&self) -> usize {
        self.n
    }
}

#[pymethods]
impl PyAdmittanceCycle {
    /// `settings_json`: `max_offset_rad` (list), `stick` ("anchor" or "zone"), `stick_zone`,
    /// `probe_speed_rad_s`, `probe_s`, `dither`, `dither_hz`, `identified_mass` (bool),
    /// `inertia_step_rad`; the command delay, the rest speed and the joints are the
    /// zero-moment law's, the estimate's low-pass the admittance's.
    #[new]
    fn new(
        settings_json: &str,
        zero_moment: Py<PyZeroMomentCycle>,
        admittance: Py<PyAdmittance>,
    ) -> PyResult<Self> {
        let v: serde_json::Value = serde_json::from_str(settings_json)
            .map_err(|e| PyValueError::new_err(format!("admittance settings: not JSON ({e})")))?;
        let s = settings(&v).map_err(PyValueError::new_err)?;
        let (n, delay, rest) = zero_moment
            .get()
            .locked(|law, _| Ok((law.s.n, law.s.command_delay_cycles, law.s.rest_rad_s)))
            .map_err(PyRuntimeError::new_err)?;
        let (adm_n, filter_hz) = {
            let adm = admittance.get().lock()?;
            (adm.n(), adm.filter_hz())
        };
        if adm_n != n {
            return Err(PyValueError::new_err(format!(
                "the admittance has {adm_n} joints, the zero-moment law {n}"
            )));
        }
        let cycle =
            AdmittanceCycle::new(s, n, delay, rest, filter_hz).map_err(PyValueError::new_err)?;
        Ok(PyAdmittanceCycle {
            cycle: Mutex::new(cycle),
            zero_moment,
            admittance,
            n,
        })
    }

    /// `(q_cmd, dq_cmd)` answering the state given by its fields, with the cylinders'
    /// pressures `p_bar` [bar].
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
        let zm = self.zero_moment.get();
        let st = zm.state(cycle, flags, period_s, &q, &dq, &q_cmd, &dq_cmd, &current_a)?;
        let mut out_q = vec![0.0; self.n];
        let mut out_dq = vec![0.0; self.n];
        py.detach(|| self.answer_state(&st, &p_bar, &mut out_q, &mut out_dq))
            .map_err(law_error)?;
        Ok((out_q, out_dq))
    }

    /// Let go: the probe ends, the zero-moment law's part disengages.
    fn disengage(&self) {
        self.disengage_now();
    }

    /// M̂ of the identified model at `q_at` (n rows of n), computed off the cycle.
    fn set_mass(&self, q_at: Vec<f64>, mass: Vec<Vec<f64>>) -> PyResult<()> {
        check_len(&q_at, self.n, "q_at")?;
        let m = flat(&mass, self.n, "mass")?;
        self.lock()?
            .set_mass(&q_at, &m)
            .map_err(PyValueError::new_err)
    }

    /// Whether M̂ should be computed again at `q` (the reference): no M̂ of the identified
    /// model handed in within the inertia step of it (always False without one).
    fn mass_wanted(&self, q: Vec<f64>) -> PyResult<bool> {
        check_len(&q, self.n, "q")?;
        Ok(self.lock()?.mass_wanted(&q).is_some())
    }

    /// M̂ the cycle would use with its reference at `q` (n rows of n): the identified model's
    /// as last handed in, else the nominal rigid body's with rotor inertias.
    fn mass_in_use(&self, q: Vec<f64>) -> PyResult<Vec<Vec<f64>>> {
        check_len(&q, self.n, "q")?;
        let n = self.n;
        let mut m = vec![0.0; n * n];
        self.zero_moment
            .get()
            .locked(|law, parts| {
                let cycle = self
                    .cycle
                    .lock()
                    .map_err(|_| "the admittance cycle's lock is poisoned".to_string())?;
                cycle.mass_at(law, parts, &q, &mut m)
            })
            .map_err(law_error)?;
        Ok(m.chunks(n).map(<[f64]>::to_vec).collect())
    }

    /// What the drives must give for the arm to move so without a hand [N·m], with M̂ `mass`.
    fn model_torque(
        &self,
        q: Vec<f64>,
        dq: Vec<f64>,
        ddq: Vec<f64>,
        p_bar: Vec<f64>,
        mass: Vec<Vec<f64>>,
    ) -> PyResult<Vec<f64>> {
        let n = self.n;
        check_len(&q, n, "q")?;
        check_len(&dq, n, "dq")?;
        check_len(&ddq, n, "ddq")?;
        let m = flat(&mass, n, "mass")?;
        let mut out = vec![0.0; n];
        self.zero_moment
            .get()
            .locked(|law, parts| {
                AdmittanceCycle::model_torque(law, parts.model, &q, &dq, &ddq, &p_bar, &m, &mut out)
            })
            .map_err(law_error)?;
        Ok(out)
    }

    /// The engagement probe's cruise speed per joint at the model's friction level [rad/s].
    fn probe_speeds(&self, friction_level_nm: Vec<f64>) -> PyResult<Vec<f64>> {
        check_len(&friction_level_nm, self.n, "friction_level_nm")?;
        let (omega, upsilon) = self
            .zero_moment
            .get()
            .locked(|_, parts| {
                Ok((
                    parts.outer.omega().to_vec(),
                    parts.outer.upsilon_i().to_vec(),
                ))
            })
            .map_err(PyRuntimeError::new_err)?;
        let mut out = vec![0.0; self.n];
        self.lock()?
            .probe_speeds(&omega, &upsilon, &friction_level_nm, &mut out);
        Ok(out)
    }

    /// The residual b of (A1) [N·m].
    #[getter]
    fn bias(&self) -> PyResult<Vec<f64>> {
        Ok(self.lock()?.bias().to_vec())
    }

    /// The desired torque of the last cycle [N·m] (the dither included).
    #[getter]
    fn tau_d_nm(&self) -> PyResult<Vec<f64>> {
        Ok(self.lock()?.tau_d().to_vec())
    }

    /// The model's friction level at the engagement's pose [N·m].
    #[getter]
    fn friction_level(&self) -> PyResult<Vec<f64>> {
        Ok(self.lock()?.friction_level().to_vec())
    }

    /// While the engagement probe runs: `(first cycle, states, period [s])`, else None.
    #[getter]
    fn probe_span(&self) -> PyResult<Option<(i64, usize, f64)>> {
        Ok(self.lock()?.probe_span())
    }

    /// What the operator's log should say since the last call: `(warning, text)` each.
    fn take_events(&self) -> PyResult<Vec<(bool, String)>> {
        Ok(self
            .lock()?
            .take_events()
            .into_iter()
            .map(|e| (e.warning, e.text))
            .collect())
    }
}

/// The stick anchor (law/admittance/stick_anchor.rs).
#[pyclass(frozen, name = "StickAnchor", module = "control._rt")]
pub struct PyStickAnchor {
    inner: Mutex<StickAnchor>,
}

#[pymethods]
impl PyStickAnchor {
    #[new]
    fn new(n: usize, filter_hz: f64) -> PyResult<Self> {
        let inner = StickAnchor::new(n, filter_hz).map_err(PyValueError::new_err)?;
        Ok(PyStickAnchor {
            inner: Mutex::new(inner),
        })
    }

    fn reset(&self) {
        self.inner.lock().unwrap_or_else(|p| p.into_inner()).reset();
    }

    #[getter]
    fn anchor(&self) -> Vec<f64> {
        self.inner
            .lock()
            .unwrap_or_else(|p| p.into_inner())
            .anchor()
            .to_vec()
    }

    /// `(τ̂ − anchor, settled)` per joint.
    fn hand(
        &self,
        tau_h: Vec<f64>,
        resting: Vec<bool>,
        band: Vec<f64>,
        dt_s: f64,
    ) -> PyResult<(Vec<f64>, Vec<bool>)> {
        let mut a = self.inner.lock().unwrap_or_else(|p| p.into_inner());
        let n = a.n();
        check_len(&tau_h, n, "tau_h")?;
        check_len(&band, n, "band")?;
        if resting.len() != n {
            return Err(PyValueError::new_err(format!("resting needs {n} values")));
        }
        let mut rel = vec![0.0; n];
        let mut settled = vec![false; n];
        a.hand(&tau_h, &resting, &band, dt_s, &mut rel, &mut settled);
        Ok((rel, settled))
    }
}

/// The start-up dither (law/admittance/startup_dither.rs).
#[pyclass(frozen, name = "StartupDither", module = "control._rt")]
pub struct PyStartupDither {
    inner: Mutex<StartupDither>,
}

#[pymethods]
impl PyStartupDither {
    #[new]
    fn new(share: f64, hz: f64, rest_rad_s: f64, delay_cycles: usize) -> PyResult<Self> {
        let inner = StartupDither::new(share, hz, rest_rad_s, delay_cycles)
            .map_err(PyValueError::new_err)?;
        Ok(PyStartupDither {
            inner: Mutex::new(inner),
        })
    }

    fn reset(&self, friction_level_nm: Vec<f64>) -> PyResult<()> {
        if friction_level_nm.len() > MAX_JOINTS {
            return Err(PyValueError::new_err(format!(
                "at most {MAX_JOINTS} joints"
            )));
        }
        self.inner
            .lock()
            .unwrap_or_else(|p| p.into_inner())
            .reset(&friction_level_nm);
        Ok(())
    }

    fn step(&self, dq_r: Vec<f64>, dt_s: f64) -> PyResult<Vec<f64>> {
        let mut d = self.inner.lock().unwrap_or_else(|p| p.into_inner());
        let n = d.n();
        check_len(&dq_r, n, "dq_r")?;
        let mut out = vec![0.0; n];
        d.step(&dq_r, dt_s, &mut out);
        Ok(out)
    }

    fn drove(&self) -> Vec<f64> {
        let d = self.inner.lock().unwrap_or_else(|p| p.into_inner());
        let mut out = vec![0.0; d.n()];
        d.drove(&mut out);
        out
    }

    #[getter]
    fn share(&self) -> f64 {
        self.inner.lock().unwrap_or_else(|p| p.into_inner()).share()
    }
}

/// The soft walls' torque on the reference per joint [N·m] (law/admittance/soft_walls.rs).
#[pyfunction]
#[pyo3(name = "wall_torque_nm")]
#[allow(clippy::too_many_arguments)]
fn py_wall_torque_nm(
    q: Vec<f64>,
    dq_r: Vec<f64>,
    lower: Vec<f64>,
    upper: Vec<f64>,
    stiffness_nm_per_rad: f64,
    rendered_inertia: Vec<f64>,
    dt_s: f64,
) -> PyResult<Vec<f64>> {
    let n = q.len();
    check_len(&dq_r, n, "dq_r")?;
    check_len(&lower, n, "lower")?;
    check_len(&upper, n, "upper")?;
    check_len(&rendered_inertia, n, "rendered_inertia")?;
    let mut out = vec![0.0; n];
    soft_walls::wall_torque(
        &q,
        &dq_r,
        &lower,
        &upper,
        stiffness_nm_per_rad,
        &rendered_inertia,
        dt_s,
        &mut out,
    )
    .map_err(PyValueError::new_err)?;
    Ok(out)
}

pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<PyAdmittanceCycle>()?;
    m.add_class::<PyStickAnchor>()?;
    m.add_class::<PyStartupDither>()?;
    m.add_function(wrap_pyfunction!(py_wall_torque_nm, m)?)?;
    m.add("ADMITTANCE_MIN_NOISE_STATES", cyc::MIN_NOISE_STATES)?;
    m.add("ADMITTANCE_DRIVE_SETTLE_CYCLES", cyc::DRIVE_SETTLE_CYCLES)?;
    m.add("PROBE_BREAKAWAY_SHARE", cyc::PROBE_BREAKAWAY_SHARE)?;
    m.add("PROBE_MAX_RAD_S", cyc::PROBE_MAX_RAD_S)?;
    m.add("STICK_ANCHOR_FOLLOW_S", sa::FOLLOW_S)?;
    m.add("STICK_ANCHOR_SETTLE_S", sa::SETTLE_S)?;
    m.add("STARTUP_DITHER_FADE_S", sd::FADE_S)?;
    Ok(())
}
