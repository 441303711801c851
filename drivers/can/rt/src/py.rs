//! The Python extension `drivers.can._rt`: what the driver process (drivers/can/driver.py) and
//! the tests see of the compiled cycle.
//!
//! * `HostCore(...)`: the host core built from the cell config's `[can]` section and the
//!   adapter's tables (derived in Python from the DBC/EDS). Its methods take and return CAN
//!   frames as SocketCAN `struct can_frame` / `canfd_frame` bytes, so a test can drive it
//!   cycle by cycle with an injected clock.
//! * `CanLoop.start(core, ...)`: moves the core onto the loop thread with its CAN socket and
//!   zenoh session; from then on Python only reads health and notes, and closes it.
//!
//! Errors in arguments raise ValueError naming what was wrong; a link that cannot be opened
//! raises OSError.

use std::sync::{Mutex, MutexGuard};

use pyo3::exceptions::{PyOSError, PyRuntimeError, PyValueError};
use pyo3::prelude::*;
use pyo3::types::PyBytes;

use crate::adapter::Adapter;
use crate::can_socket::Transport;
use crate::core::{Answer, CoreConfig, HostCore};
use crate::driver_loop::{monotonic_s, stages_json, DriverLoop, Keys};
use crate::frame::{Frame, CANFD_MTU};
use crate::speed_monitor::KinematicChain;

fn json_arg(text: &str, what: &str) -> PyResult<serde_json::Value> {
    serde_json::from_str(text).map_err(|e| PyValueError::new_err(format!("{what}: not JSON ({e})")))
}

fn build_adapter(name: &str, tables: &serde_json::Value) -> Result<Box<dyn Adapter>, String> {
    Ok(match name {
        "ltc_dbc" => Box::new(crate::ltc_adapter::LtcAdapter::from_tables(tables)?),
        "ltc_fd" => Box::new(crate::ltc_fd_adapter::LtcFdAdapter::from_tables(tables)?),
        "cia402" => Box::new(crate::cia402::Cia402Adapter::from_tables(tables)?),
        other => {
            return Err(format!(
                "[can].adapter = {other:?}: the compiled cycle has 'ltc_dbc', 'ltc_fd' and 'cia402'"
            ))
        }
    })
}

fn wire(py: Python<'_>, frames: &[Frame]) -> PyResult<Vec<Py<PyBytes>>> {
    let mut buf = [0u8; CANFD_MTU];
    frames
        .iter()
        .map(|f| {
            let n = f.to_wire(&mut buf).map_err(PyValueError::new_err)?;
            Ok(PyBytes::new(py, &buf[..n]).unbind())
        })
        .collect()
}

fn answer_name(a: Answer) -> &'static str {
    match a {
        Answer::None => "",
        Answer::Command => "command",
        Answer::Coast => "coast",
        Answer::Hold => "hold",
        Answer::Ramp => "ramp",
    }
}

/// The host core, cycle by cycle (the rules of core.rs).
#[pyclass(frozen, name = "HostCore", module = "drivers.can._rt")]
pub struct PyHostCore {
    core: Mutex<Option<HostCore>>,
}

impl PyHostCore {
    fn lock(&self) -> PyResult<MutexGuard<'_, Option<HostCore>>> {
        self.core
            .lock()
            .map_err(|_| PyRuntimeError::new_err("the host core's lock is poisoned"))
    }
}

macro_rules! with_core {
    ($self:ident, $core:ident, $body:block) => {{
        let mut guard = $self.lock()?;
        let $core = guard
            .as_mut()
            .ok_or_else(|| PyRuntimeError::new_err("this HostCore was moved onto a CanLoop"))?;
        $body
    }};
}

#[pymethods]
impl PyHostCore {
    /// `config_json`: `dataclasses.asdict(CanDriverConfig)`; `adapter`: its registry name;
    /// `tables_json`: the adapter's tables (drivers/can/rt_tables.py, rt_cia402_tables.py);
    /// `lower`/`upper`: the description's joint limits [rad]; `chain_json`: the kinematic
    /// chain of the speed monitor (drivers/can/rt_kinematics.py), None without a monitor;
    /// `stored_zero`: the commissioning's current zero (offset [A], samples, noise [A]).
    #[new]
    #[pyo3(signature = (config_json, adapter, tables_json, lower, upper, chain_json=None, stored_zero=None, health_period_s=0.1))]
    #[allow(clippy::too_many_arguments)]
    fn new(
        config_json: &str,
        adapter: &str,
        tables_json: &str,
        lower: Vec<f64>,
        upper: Vec<f64>,
        chain_json: Option<&str>,
        stored_zero: Option<(Vec<f64>, i64, Vec<f64>)>,
        health_period_s: f64,
    ) -> PyResult<Self> {
        let config = CoreConfig::from_json(&json_arg(config_json, "the [can] config")?)
            .map_err(PyValueError::new_err)?;
        let tables = json_arg(tables_json, "the adapter's tables")?;
        let adapter = build_adapter(adapter, &tables).map_err(PyValueError::new_err)?;
        let chain = match chain_json {
            None => None,
            Some(text) => Some(
                KinematicChain::from_json(&json_arg(text, "the kinematic chain")?)
                    .map_err(PyValueError::new_err)?,
            ),
        };
        let core = HostCore::new(
            config,
            adapter,
            health_period_s,
            stored_zero,
            chain,
            (lower, upper),
        )
        .map_err(PyValueError::new_err)?;
        Ok(PyHostCore {
            core: Mutex::new(Some(core)),
        })
    }

    /// Take one received frame (struct can_frame/canfd_frame bytes): (the JointState to
    /// publish or None, frames to send now, the StateWindow to publish or None).
    #[allow(clippy::type_complexity)]
    fn on_frame(
        &self,
        py: Python<'_>,
        frame: &[u8],
        now: f64,
    ) -> PyResult<(Option<Py<PyBytes>>, Vec<Py<PyBytes>>, Option<Py<PyBytes>>)> {
        let frame = Frame::from_wire(frame, true).map_err(PyValueError::new_err)?;
        with_core!(self, core, {
            let (mut out, mut state, mut window) = (Vec::new(), Vec::new(), Vec::new());
            let r = core.on_frame(&frame, now, &mut out, &mut state, &mut window);
            let state = r.state.then(|| PyBytes::new(py, &state).unbind());
            let window = r.window.then(|| PyBytes::new(py, &window).unbind());
            Ok((state, wire(py, &out)?, window))
        })
    }

    /// Decide on one JointCommand payload: (frames to send, "command"/"hold"/... or "").
    fn on_command(
        &self,
        py: Python<'_>,
        payload: &[u8],
        now: f64,
    ) -> PyResult<(Vec<Py<PyBytes>>, &'static str)> {
        with_core!(self, core, {
            let mut out = Vec::new();
            let r = core.on_command(payload, now, &mut out);
            Ok((wire(py, &out)?, answer_name(r.answer)))
        })
    }

    /// Deadline answers, servo requests and heartbeats due at `now`.
    fn on_tick(&self, py: Python<'_>, now: f64) -> PyResult<Vec<Py<PyBytes>>> {
        with_core!(self, core, {
            let mut out = Vec::new();
            core.on_tick(now, &mut out);
            wire(py, &out)
        })
    }

    fn on_lifecycle(&self, payload: &[u8], now: f64) -> PyResult<()> {
        with_core!(self, core, {
            core.on_lifecycle(payload, now);
            Ok(())
        })
    }

    fn on_io(&self, payload: &[u8], now: f64) -> PyResult<()> {
        with_core!(self, core, {
            core.on_io(payload, now);
            Ok(())
        })
    }

    fn next_tick_s(&self) -> PyResult<f64> {
        with_core!(self, core, { Ok(core.next_tick_s()) })
    }

    fn closing_frames(&self, py: Python<'_>) -> PyResult<Vec<Py<PyBytes>>> {
        with_core!(self, core, {
            let mut out = Vec::new();
            core.closing_frames(&mut out);
            wire(py, &out)
        })
    }

    fn link_ok(&self, now: f64) -> PyResult<bool> {
        with_core!(self, core, { Ok(core.link_ok(now)) })
    }

    /// The servo request the core wants now: "BRAKE", "SERVO_ON" or "RESET_FAULT".
    fn desired_request(&self, now: f64) -> PyResult<&'static str> {
        with_core!(self, core, { Ok(core.desired_request(now).name()) })
    }

    /// Why forwarding is blocked now (a reject reason), None if it is not.
    fn blocked(&self, now: f64) -> PyResult<Option<&'static str>> {
        with_core!(self, core, { Ok(core.blocked(now)) })
    }

    /// (cycle, answer) of the newest cycle, None before the first.
    fn pending(&self) -> PyResult<Option<(i64, &'static str)>> {
        with_core!(self, core, {
            Ok(core
                .pending_cycle()
                .map(|c| (c, answer_name(core.pending_answer()))))
        })
    }

    /// The health's core entries, as a JSON object's text.
    fn health(&self, now: f64) -> PyResult<String> {
        with_core!(self, core, {
            Ok(serde_json::Value::Object(core.health(now)).to_string())
        })
    }

    /// Notes since the last call: [(level, key, message)], levels as Python's logging.
    fn take_notes(&self) -> PyResult<Vec<(u8, String, String)>> {
        with_core!(self, core, { Ok(core.take_notes()) })
    }
}

/// The running cycle: the loop thread, the CAN socket and the zenoh session.
#[pyclass(frozen, name = "CanLoop", module = "drivers.can._rt")]
pub struct PyCanLoop {
    inner: Mutex<DriverLoop>,
}

impl PyCanLoop {
    fn lock(&self) -> MutexGuard<'_, DriverLoop> {
        self.inner.lock().unwrap_or_else(|p| p.into_inner())
    }
}

#[pymethods]
impl PyCanLoop {
    /// Move `core` onto a new loop thread: open the CAN link (`transport_json`: the
    /// `[can.transport]` table), the zenoh session (`zenoh_config`: (key, JSON5 value) pairs,
    /// those of gateway/bus.py's session for this process) and declare `keys` (joint_state,
    /// state_window, joint_command, lifecycle, io_state). `core` is unusable afterwards.
    /// `brake_signals`: stop signals on which the loop sends the BRAKE itself, with no Python
    /// on the way (only signals this process already handles: driver_loop.rs `start`).
    #[staticmethod]
    #[pyo3(signature = (core, transport_json, zenoh_config, keys, brake_signals=Vec::new()))]
    fn start(
        py: Python<'_>,
        core: &PyHostCore,
        transport_json: &str,
        zenoh_config: Vec<(String, String)>,
        keys: std::collections::HashMap<String, String>,
        brake_signals: Vec<i32>,
    ) -> PyResult<PyCanLoop> {
        let transport = Transport::from_json(&json_arg(transport_json, "[can.transport]")?)
            .map_err(PyValueError::new_err)?;
        let key = |k: &str| {
            keys.get(k)
                .cloned()
                .ok_or_else(|| PyValueError::new_err(format!("keys: {k} missing")))
        };
        let keys = Keys {
            joint_state: key("joint_state")?,
            state_window: key("state_window")?,
            joint_command: key("joint_command")?,
            lifecycle: key("lifecycle")?,
            io_state: key("io_state")?,
        };
        let host = core.lock()?.take().ok_or_else(|| {
            PyRuntimeError::new_err("this HostCore was already moved onto a CanLoop")
        })?;
        let started =
            py.detach(|| DriverLoop::start(host, &transport, &zenoh_config, &keys, &brake_signals));
        let inner = started.map_err(PyOSError::new_err)?;
        Ok(PyCanLoop {
            inner: Mutex::new(inner),
        })
    }

    /// The process's health entries of the cycle, as a JSON object's text: the core's, the
    /// stage timers and the socket's error counters.
    fn health(&self, py: Python<'_>) -> String {
        py.detach(|| {
            let l = self.lock();
            let now = monotonic_s();
            let mut guard = l.lock();
            let mut m = guard.core.health(now);
            m.insert("send_errors".into(), guard.send_errors.into());
            m.insert("recv_errors".into(), guard.recv_errors.into());
            m.insert("stages".into(), stages_json(&guard.stages));
            serde_json::Value::Object(m).to_string()
        })
    }

    fn take_notes(&self, py: Python<'_>) -> Vec<(u8, String, String)> {
        py.detach(|| self.lock().take_notes())
    }

    fn link_ok(&self, py: Python<'_>) -> bool {
        py.detach(|| {
            let l = self.lock();
            let ok = l.lock().core.link_ok(monotonic_s());
            ok
        })
    }

    /// When a stop signal reached the process (time.monotonic() [s]; the loop then sends the
    /// BRAKE by itself), or None.
    #[getter]
    fn signal_s(&self) -> Option<f64> {
        self.lock().signal_s()
    }

    /// Whether the loop sent the exit BRAKE itself on a stop signal (false before the BRAKE
    /// went, or when a close sent it first).
    #[getter]
    fn braked_on_signal(&self) -> bool {
        self.lock().braked_on_signal()
    }

    #[getter]
    fn running(&self) -> bool {
        self.lock().running()
    }

    /// Why the loop thread ended, if it ended on an error.
    #[getter]
    fn failed(&self) -> Option<String> {
        self.lock().failed()
    }

    /// Brake, stop the loop, release the links; the frames sent on the way out. Idempotent.
    fn close(&self, py: Python<'_>) -> PyResult<usize> {
        py.detach(|| self.lock().close())
            .map_err(PyOSError::new_err)
    }
}

/// CLOCK_MONOTONIC [s], as the loop reads it (Python's time.monotonic()).
#[pyfunction]
fn monotonic() -> f64 {
    monotonic_s()
}

#[pymodule]
fn _rt(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<PyHostCore>()?;
    m.add_class::<PyCanLoop>()?;
    m.add_function(wrap_pyfunction!(monotonic, m)?)?;
    Ok(())
}
