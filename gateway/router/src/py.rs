//! The Python extension `gateway._router`: the locked bus's router the gateway hosts
//! (gateway/bus.py `open_router`), with its refusals counted by [`crate::refusals`].
//!
//! * `Router(zenoh_config)`: open zenoh's router with these (key, JSON5 value) settings, the
//!   ones gateway/bus.py builds for it (mode, endpoints, credentials, access-control list).
//!   ValueError names a setting zenoh refuses; OSError a router that cannot open.
//! * `refusals()`: every (identity, action, key, count) the access-control list refused in
//!   this process so far.
//! * `close()`: idempotent.

use std::sync::{Arc, Mutex, OnceLock};

use pyo3::exceptions::{PyOSError, PyRuntimeError, PyValueError};
use pyo3::prelude::*;
use zenoh::Wait;

use crate::refusals::{AclSubscriber, RefusalCounter};

/// The process's counter: zenoh's `tracing` events have one global dispatcher per process.
static COUNTER: OnceLock<Result<Arc<RefusalCounter>, String>> = OnceLock::new();

fn counter() -> PyResult<Arc<RefusalCounter>> {
    COUNTER
        .get_or_init(|| {
            let counter = Arc::new(RefusalCounter::default());
            let dispatch = tracing_core::Dispatch::new(AclSubscriber {
                counter: counter.clone(),
            });
            tracing_core::dispatcher::set_global_default(dispatch)
                .map(|()| counter)
                .map_err(|e| format!("the router's refusal counter could not be installed: {e}"))
        })
        .clone()
        .map_err(PyRuntimeError::new_err)
}

#[pyclass(frozen, name = "Router", module = "gateway._router")]
pub struct PyRouter {
    session: Mutex<Option<zenoh::Session>>,
    counter: Arc<RefusalCounter>,
}

#[pymethods]
impl PyRouter {
    #[new]
    fn new(py: Python<'_>, zenoh_config: Vec<(String, String)>) -> PyResult<PyRouter> {
        let counter = counter()?;
        let mut cfg = zenoh::Config::default();
        for (k, v) in &zenoh_config {
            cfg.insert_json5(k, v)
                .map_err(|e| PyValueError::new_err(format!("zenoh config {k} = {v}: {e}")))?;
        }
        let session = py
            .detach(|| zenoh::open(cfg).wait())
            .map_err(|e| PyOSError::new_err(format!("zenoh router: {e}")))?;
        Ok(PyRouter {
            session: Mutex::new(Some(session)),
            counter,
        })
    }

    /// Every (identity, action, key) refused so far in this process, with its count.
    fn refusals(&self, py: Python<'_>) -> Vec<(String, String, String, u64)> {
        py.detach(|| self.counter.snapshot())
    }

    /// Close the router (every link to it drops). Idempotent.
    fn close(&self, py: Python<'_>) -> PyResult<()> {
        let taken = self
            .session
            .lock()
            .unwrap_or_else(|p| p.into_inner())
            .take();
        match taken {
            Some(session) => py
                .detach(|| session.close().wait())
                .map_err(|e| PyOSError::new_err(format!("zenoh router close: {e}"))),
            None => Ok(()),
        }
    }
}

#[pymodule]
fn _router(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<PyRouter>()?;
    Ok(())
}
