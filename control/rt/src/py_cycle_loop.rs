//! `control._rt.CycleLoop`: the control process's joint-state subscription, compiled (issue 48:
//! no Python between the joint state in and the command out).
//!
//! The loop opens its own zenoh session (the zenoh crate at the Python wheel's version, with the
//! settings `gateway/bus.py peer_config_entries` gives the process's own session, as the CAN
//! driver's compiled loop does) and subscribes to the joint states on zenoh's receiving thread.
//! Each state is decided there, once:
//!
//! - teaching with the zero-moment law (the gateway's lifecycle fresh and TEACHING, the drives
//!   following, the cylinders' pressures fresh): the compiled law answers it
//!   ([`PyZeroMomentCycle`], its pieces borrowed without the GIL) and the command is encoded and
//!   published from that thread, stamped at receipt and at sending as the Python did;
//! - anything else (a hold to observe, a plan to play, stale pressures, a malformed payload, the
//!   admittance law): the payload and its receipt time go to the Python callback
//!   (`ControlProcess._on_state_bytes`), under the GIL, as the Python subscription did.
//!
//! Python tells the loop what it needs to decide ([`PyCycleLoop::set_lifecycle`],
//! [`PyCycleLoop::set_io`]) from its own lifecycle and I/O subscriptions, and reads its counters
//! and notes (errors the loop met: the law undefined at a state, a command that could not be
//! encoded; each disengages the law and sends nothing) from its slow loop.

use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex};

use bus_rt::messages::{JointCommand, JointState};
use pyo3::exceptions::{PyRuntimeError, PyValueError};
use pyo3::prelude::*;
use pyo3::types::{PyBytes, PyDict};
use zenoh::pubsub::{Publisher, Subscriber};
use zenoh::qos::{CongestionControl, Priority};
use zenoh::{Session, Wait};

use crate::chain::MAX_JOINTS;
use crate::law::zero_moment::State;
use crate::py_zero_moment::PyZeroMomentCycle;

/// Notes kept for Python at most (the oldest go first).
const MAX_NOTES: usize = 64;

/// CLOCK_MONOTONIC [s]: Python's `time.monotonic()`, one clock for every process.
fn monotonic_s() -> f64 {
    let mut ts = libc::timespec {
        tv_sec: 0,
        tv_nsec: 0,
    };
    // SAFETY: a valid timespec.
    unsafe { libc::clock_gettime(libc::CLOCK_MONOTONIC, &mut ts) };
    ts.tv_sec as f64 + ts.tv_nsec as f64 * 1e-9
}

/// What decides whether the law answers a state (set by Python).
struct Mode {
    /// The gateway's last lifecycle is TEACHING (and the law is the compiled one).
    teaching: bool,
    lifecycle_rx_s: f64,
    lifecycle_timeout_s: f64,
    /// The cylinders' pressures [bar] and when the Modbus driver read them.
    p_bar: [f64; 2],
    io_stamp_s: f64,
    io_timeout_s: f64,
}

struct Shared {
    law: Option<Py<PyZeroMomentCycle>>,
    forward: Py<PyAny>,
    mode: Mutex<Mode>,
    publisher: Publisher<'static>,
    buf: Mutex<Vec<u8>>,
    states: AtomicU64,
    commands: AtomicU64,
    forwarded: AtomicU64,
    errors: AtomicU64,
    notes: Mutex<Vec<String>>,
    /// The last state the law answered: (cycle, q, dq, n).
    last: Mutex<(i64, [f64; MAX_JOINTS], [f64; MAX_JOINTS], usize)>,
}

impl Shared {
    fn note(&self, text: String) {
        let mut notes = self.notes.lock().unwrap_or_else(|p| p.into_inner());
        if notes.len() >= MAX_NOTES {
            notes.remove(0);
        }
        notes.push(text);
    }

    /// The law answers this state (module docs).
    fn answers(&self, st: &JointState, law: &PyZeroMomentCycle, now: f64) -> Option<[f64; 2]> {
        let m = self.mode.lock().unwrap_or_else(|p| p.into_inner());
        let fresh = now - m.lifecycle_rx_s <= m.lifecycle_timeout_s;
        let io_fresh = now - m.io_stamp_s <= m.io_timeout_s;
        let ok = m.teaching
            && fresh
            && io_fresh
            && st.controller_state.servoing()
            && st.q_rad.len() == law.joints();
        ok.then_some(m.p_bar)
    }

    fn forward(&self, payload: &[u8], now: f64) {
        self.forwarded.fetch_add(1, Ordering::Relaxed);
        Python::attach(|py| {
            let data = PyBytes::new(py, payload);
            if let Err(e) = self.forward.call1(py, (data, now)) {
                // the Python callback logs its own errors; one that escapes is a bug: say so
                self.note(format!("the joint-state callback raised: {e}"));
            }
        });
    }

    fn on_state(&self, payload: &[u8]) {
        let now = monotonic_s();
        self.states.fetch_add(1, Ordering::Relaxed);
        let Some(law) = self.law.as_ref().map(Py::get) else {
            return self.forward(payload, now);
        };
        let Ok(st) = JointState::from_bytes(payload) else {
            return self.forward(payload, now); // Python decodes it again, counts and logs it
        };
        let Some(p_bar) = self.answers(&st, law, now) else {
            return self.forward(payload, now);
        };
        let n = st.q_rad.len();
        {
            let mut last = self.last.lock().unwrap_or_else(|p| p.into_inner());
            last.0 = st.cycle;
            last.1[..n].copy_from_slice(&st.q_rad);
            last.2[..n].copy_from_slice(&st.dq_rad_s);
            last.3 = n;
        }
        let state = State {
            cycle: st.cycle,
            flags: u32::from(st.flags),
            period_s: st.cycle_period_s,
            q: &st.q_rad,
            dq: &st.dq_rad_s,
            q_cmd: &st.q_cmd_rad,
            dq_cmd: &st.dq_cmd_rad_s,
            current_a: &st.current_a,
        };
        let mut q_cmd = [0.0; MAX_JOINTS];
        let mut dq_cmd = [0.0; MAX_JOINTS];
        if let Err(e) = law.answer_state(&state, &p_bar, &mut q_cmd[..n], &mut dq_cmd[..n]) {
            law.disengage_now();
            self.errors.fetch_add(1, Ordering::Relaxed);
            return self.note(format!(
                "command not sent: cycle {}: model torque undefined ({e})",
                st.cycle
            ));
        }
        let mut buf = self.buf.lock().unwrap_or_else(|p| p.into_inner());
        let packed = JointCommand::pack(
            &mut buf,
            st.cycle,
            st.stamp_s,
            monotonic_s(),
            &q_cmd[..n],
            &dq_cmd[..n],
            now,
        );
        if let Err(e) = packed {
            law.disengage_now();
            self.errors.fetch_add(1, Ordering::Relaxed);
            return self.note(format!("command not sent: {e}"));
        }
        match self.publisher.put(buf.as_slice()).wait() {
            Ok(()) => {
                self.commands.fetch_add(1, Ordering::Relaxed);
            }
            Err(e) => self.note(format!("command not published: {e}")),
        }
    }
}

/// The compiled joint-state subscription (module docs).
#[pyclass(frozen, name = "CycleLoop", module = "control._rt")]
pub struct PyCycleLoop {
    shared: Arc<Shared>,
    inner: Mutex<Option<(Session, Subscriber<()>)>>,
}

#[pymethods]
impl PyCycleLoop {
    /// Open the session (`zenoh_config`: (key, JSON5 value) pairs), declare the command
    /// publisher and the joint-state subscriber. `law`: the zero-moment law's compiled cycle,
    /// or None (every state goes to `forward(payload: bytes, rx_s: float)`).
    #[new]
    #[pyo3(signature = (zenoh_config, joint_state_key, joint_command_key, law, forward))]
    fn new(
        py: Python<'_>,
        zenoh_config: Vec<(String, String)>,
        joint_state_key: String,
        joint_command_key: String,
        law: Option<Py<PyZeroMomentCycle>>,
        forward: Py<PyAny>,
    ) -> PyResult<Self> {
        if !forward.bind(py).is_callable() {
            return Err(PyValueError::new_err("forward must be callable"));
        }
        let opened = py.detach(|| -> Result<(Session, Publisher<'static>), String> {
            let mut cfg = zenoh::Config::default();
            for (k, v) in &zenoh_config {
                cfg.insert_json5(k, v)
                    .map_err(|e| format!("zenoh config {k} = {v}: {e}"))?;
            }
            let session = zenoh::open(cfg)
                .wait()
                .map_err(|e| format!("zenoh session: {e}"))?;
            // the loop's data: never blocks (a slow peer must not stall the loop), sent at once
            let publisher = session
                .declare_publisher(joint_command_key.clone())
                .congestion_control(CongestionControl::Drop)
                .priority(Priority::RealTime)
                .express(true)
                .wait();
            match publisher {
                Ok(p) => Ok((session, p)),
                Err(e) => {
                    let _ = session.close().wait();
                    Err(format!("zenoh declaration: {e}"))
                }
            }
        });
        let (session, publisher) = opened.map_err(PyRuntimeError::new_err)?;
        let shared = Arc::new(Shared {
            law,
            forward,
            mode: Mutex::new(Mode {
                teaching: false,
                lifecycle_rx_s: f64::NEG_INFINITY,
                lifecycle_timeout_s: 0.0,
                p_bar: [0.0; 2],
                io_stamp_s: f64::NEG_INFINITY,
                io_timeout_s: 0.0,
            }),
            publisher,
            buf: Mutex::new(Vec::with_capacity(JointCommand::size(MAX_JOINTS))),
            states: AtomicU64::new(0),
            commands: AtomicU64::new(0),
            forwarded: AtomicU64::new(0),
            errors: AtomicU64::new(0),
            notes: Mutex::new(Vec::with_capacity(MAX_NOTES)),
            last: Mutex::new((-1, [0.0; MAX_JOINTS], [0.0; MAX_JOINTS], 0)),
        });
        let s = shared.clone();
        let declared = py.detach(|| {
            session
                .declare_subscriber(joint_state_key)
                .callback(move |sample| s.on_state(&sample.payload().to_bytes()))
                .wait()
        });
        let subscriber = match declared {
            Ok(sub) => sub,
            Err(e) => {
                py.detach(|| {
                    let _ = session.close().wait();
                });
                return Err(PyRuntimeError::new_err(format!("zenoh declaration: {e}")));
            }
        };
        Ok(PyCycleLoop {
            shared,
            inner: Mutex::new(Some((session, subscriber))),
        })
    }

    /// The gateway's lifecycle as the control process received it: TEACHING with the
    /// compiled law (`teaching`), when [s], and how long it stays fresh [s].
    fn set_lifecycle(&self, teaching: bool, rx_s: f64, timeout_s: f64) {
        let mut m = self.shared.mode.lock().unwrap_or_else(|p| p.into_inner());
        m.teaching = teaching;
        m.lifecycle_rx_s = rx_s;
        m.lifecycle_timeout_s = timeout_s;
    }

    /// The cylinders' pressures [bar], when they were read [s] and how long they stay fresh.
    fn set_io(&self, p2_bar: f64, p3_bar: f64, stamp_s: f64, timeout_s: f64) {
        let mut m = self.shared.mode.lock().unwrap_or_else(|p| p.into_inner());
        m.p_bar = [p2_bar, p3_bar];
        m.io_stamp_s = stamp_s;
        m.io_timeout_s = timeout_s;
    }

    /// States received, commands published, states handed to Python, states the law could
    /// not answer.
    fn counters<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        let d = PyDict::new(py);
        let s = &self.shared;
        d.set_item("states", s.states.load(Ordering::Relaxed))?;
        d.set_item("commands", s.commands.load(Ordering::Relaxed))?;
        d.set_item("forwarded", s.forwarded.load(Ordering::Relaxed))?;
        d.set_item("errors", s.errors.load(Ordering::Relaxed))?;
        Ok(d)
    }

    /// The last state the law answered: `(cycle, q, dq)`, or None before the first.
    #[allow(clippy::type_complexity)]
    fn last_state(&self) -> Option<(i64, Vec<f64>, Vec<f64>)> {
        let last = self.shared.last.lock().unwrap_or_else(|p| p.into_inner());
        let n = last.3;
        (n > 0).then(|| (last.0, last.1[..n].to_vec(), last.2[..n].to_vec()))
    }

    /// The notes since the last call (oldest first).
    fn take_notes(&self) -> Vec<String> {
        std::mem::take(&mut *self.shared.notes.lock().unwrap_or_else(|p| p.into_inner()))
    }

    /// Undeclare the subscription and close the session (idempotent). The GIL is released
    /// meanwhile: a callback in flight may be waiting for it.
    fn close(&self, py: Python<'_>) {
        let taken = self.inner.lock().unwrap_or_else(|p| p.into_inner()).take();
        if let Some((session, subscriber)) = taken {
            py.detach(|| {
                let _ = subscriber.undeclare().wait();
                let _ = session.close().wait();
            });
        }
    }
}

pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<PyCycleLoop>()?;
    Ok(())
}
