//! The extension module `sim_bridge._rt`: the virtual I/O module as the simulator drives it
//! (`sim_bridge/modbus_server.py` wraps it with the module's manual).

use std::sync::{Arc, Mutex};

use pyo3::exceptions::{PyOSError, PyRuntimeError};
use pyo3::prelude::*;

use crate::io_module::{Inputs, Module, Server};

/// The module's registers and its Modbus TCP server: `start()` listens and answers on native
/// threads (no GIL); `set_inputs` and `setpoints` are the simulator's side, from any thread.
#[pyclass(module = "sim_bridge._rt", frozen)]
struct VirtualIoModule {
    module: Arc<Module>,
    server: Mutex<Option<Server>>,
    host: String,
    port: u16,
    device_id: u8,
}

#[pymethods]
impl VirtualIoModule {
    #[new]
    #[pyo3(signature = (host, port, device_id, p2_set_bar, p3_set_bar))]
    fn new(host: String, port: u16, device_id: u8, p2_set_bar: f64, p3_set_bar: f64) -> Self {
        VirtualIoModule {
            module: Arc::new(Module::new(p2_set_bar, p3_set_bar)),
            server: Mutex::new(None),
            host,
            port,
            device_id,
        }
    }

    /// Listen and serve; returns the port (the one bound if 0 was asked). OSError naming the
    /// address if it cannot listen; RuntimeError if already started.
    fn start(&self, py: Python<'_>) -> PyResult<u16> {
        let mut slot = self.server.lock().unwrap_or_else(|p| p.into_inner());
        if slot.is_some() {
            return Err(PyRuntimeError::new_err(
                "the virtual I/O module is already started",
            ));
        }
        let (host, port, id, module) = (&self.host, self.port, self.device_id, &self.module);
        let server = py
            .detach(|| Server::start(host, port, id, module.clone()))
            .map_err(|e| {
                PyOSError::new_err(format!(
                    "virtual I/O module cannot listen on {host}:{port}: {e}"
                ))
            })?;
        let bound = server.port();
        *slot = Some(server);
        Ok(bound)
    }

    /// Close the listener and every connection and join the server's threads (idempotent).
    fn stop(&self, py: Python<'_>) {
        let server = self.server.lock().unwrap_or_else(|p| p.into_inner()).take();
        if let Some(mut server) = server {
            py.detach(|| server.stop());
        }
    }

    #[pyo3(signature = (p2_bar, p3_bar, enabling, estop_ok, mark=false))]
    fn set_inputs(&self, p2_bar: f64, p3_bar: f64, enabling: bool, estop_ok: bool, mark: bool) {
        self.module.set_inputs(Inputs {
            p2_bar,
            p3_bar,
            enabling,
            estop_ok,
            mark,
        });
    }

    /// `(p2_set_bar, p3_set_bar)` as stored: written by a client, or the initial ones.
    fn setpoints(&self) -> (f64, f64) {
        self.module.setpoints_bar()
    }

    /// Write requests that reached the set-points.
    #[getter]
    fn setpoint_writes(&self) -> u64 {
        self.module.setpoint_writes()
    }

    /// Whether the server is listening.
    #[getter]
    fn running(&self) -> bool {
        self.server
            .lock()
            .unwrap_or_else(|p| p.into_inner())
            .is_some()
    }
}

#[pymodule]
fn _rt(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<VirtualIoModule>()
}
