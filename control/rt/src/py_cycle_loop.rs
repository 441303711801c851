//! `control._rt.CycleLoop`: the control process's joint-state subscription, compiled (issue 48:
//! no Python between the joint state in and the command out).
//!
//! The loop opens its own zenoh session (the zenoh crate at the Python wheel's version, with the
//! settings `gateway/bus.py peer_config_entries` gives the process's own session, as the CAN
//! driver's compiled loop does) and subscribes to the joint states on zenoh's receiving thread.
//! Each state is decided there, once:
//!
//! - teaching (the gateway's lifecycle fresh and TEACHING, the drives following, the cylinders'
//!   pressures fresh): the compiled law answers it ([`Law`]: the zero-moment law's or the
//!   admittance's), their pieces borrowed without the GIL, and the command is encoded and
//!   published from that thread, stamped at receipt and at sending as the Python did;
//! - identifying or replaying with a built plan ([`PyPlanPlay`], installed by
//!   control/plan_player.py once its worker built it): the plan's sample answers it, with the
//!   law's hold offset on a replay's (eq. 21's steady state: a taught path is where the tool
//!   must be), and a replay's state goes to a buffer for eq. (29), which Python's slow loop
//!   drains ([`PyCycleLoop::take_samples`]);
//! - anything else (a hold to observe, a plan being built, stale pressures, a malformed
//!   payload): the payload and its receipt time go to the Python callback
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
use crate::py_cycle_law::Law;
use crate::py_plan_play::{playable, PyPlanPlay};

/// Notes kept for Python at most (the oldest go first).
const MAX_NOTES: usize = 64;
/// A replay's states kept for eq. (29) until the slow loop takes them (16 s at 125 Hz, 4 s at
/// 500 Hz; the slow loop takes them several times a second): the newest wait when it is full.
const MAX_SAMPLES: usize = 2048;

/// What the lifecycle lets the loop play (set by Python).
#[derive(Clone, Copy, PartialEq, Eq)]
enum Playing {
    Nothing,
    Identifying,
    Replaying,
}

/// A replay's state for eq. (29): cycle, stamp [s], q [rad], dq [rad/s], motor torque [N·m],
/// pressures [bar], joints.
type Sample = (
    i64,
    f64,
    [f64; MAX_JOINTS],
    [f64; MAX_JOINTS],
    [f64; MAX_JOINTS],
    [f64; 2],
    usize,
);

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
    /// ... or IDENTIFYING or REPLAYING.
    playing: Playing,
    lifecycle_rx_s: f64,
    lifecycle_timeout_s: f64,
    /// The cylinders' pressures [bar] and when the Modbus driver read them.
    p_bar: [f64; 2],
    io_stamp_s: f64,
    io_timeout_s: f64,
}

struct Shared {
    law: Option<Law>,
    player: Option<Py<PyPlanPlay>>,
    /// Collect a replay's states for eq. (29).
    sampling: bool,
    samples: Mutex<Vec<Sample>>,
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
    fn answers(&self, st: &JointState, law: &Law, now: f64) -> Option<[f64; 2]> {
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
        if self.law.is_none() && self.player.is_none() {
            return self.forward(payload, now);
        }
        let Ok(st) = JointState::from_bytes(payload) else {
            return self.forward(payload, now); // Python decodes it again, counts and logs it
        };
        if let Some(law) = self.law.as_ref() {
            if let Some(p_bar) = self.answers(&st, law, now) {
                return self.teach(&st, law, &p_bar, now);
            }
        }
        if !self.play(&st, now) {
            self.forward(payload, now);
        }
    }

    fn remember(&self, st: &JointState) {
        let n = st.q_rad.len();
        let mut last = self.last.lock().unwrap_or_else(|p| p.into_inner());
        last.0 = st.cycle;
        last.1[..n].copy_from_slice(&st.q_rad);
        last.2[..n].copy_from_slice(&st.dq_rad_s);
        last.3 = n;
    }

    /// Teaching: the law answers `st`.
    fn teach(&self, st: &JointState, law: &Law, p_bar: &[f64; 2], now: f64) {
        let n = st.q_rad.len();
        self.remember(st);
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
        if let Err(e) = law.answer_state(&state, p_bar, &mut q_cmd[..n], &mut dq_cmd[..n]) {
            law.disengage_now();
            self.errors.fetch_add(1, Ordering::Relaxed);
            return self.note(format!(
                "command not sent: cycle {}: model torque undefined ({e})",
                st.cycle
            ));
        }
        if let Err((e, unencodable)) = self.publish(st, &q_cmd[..n], &dq_cmd[..n], now) {
            if unencodable {
                law.disengage_now();
            }
            self.note(e);
        }
    }

    /// Encode and publish the command answering `st`, received at `rx_s` and stamped as sent
    /// now. Err: why it was not sent, and whether it could not be encoded (counted as an error:
    /// the law disengages) rather than not published.
    fn publish(
        &self,
        st: &JointState,
        q_cmd: &[f64],
        dq_cmd: &[f64],
        rx_s: f64,
    ) -> Result<(), (String, bool)> {
        let mut buf = self.buf.lock().unwrap_or_else(|p| p.into_inner());
        let tx_s = monotonic_s();
        let packed = JointCommand::pack(&mut buf, st.cycle, st.stamp_s, tx_s, q_cmd, dq_cmd, rx_s);
        if let Err(e) = packed {
            self.errors.fetch_add(1, Ordering::Relaxed);
            return Err((format!("command not sent: {e}"), true));
        }
        match self.publisher.put(buf.as_slice()).wait() {
            Ok(()) => {
                self.commands.fetch_add(1, Ordering::Relaxed);
                Ok(())
            }
            Err(e) => Err((format!("command not published: {e}"), false)),
        }
    }

    /// Identifying or replaying with a built plan: its sample answers `st` (true), else
    /// Python does (false). Module docs.
    fn play(&self, st: &JointState, now: f64) -> bool {
        let Some(player) = self.player.as_ref().map(Py::get) else {
            return false;
        };
        let (playing, p_bar, io_seen, io_fresh) = {
            let m = self.mode.lock().unwrap_or_else(|p| p.into_inner());
            let fresh = now - m.lifecycle_rx_s <= m.lifecycle_timeout_s;
            let playing = if fresh { m.playing } else { Playing::Nothing };
            let io_seen = m.io_stamp_s > f64::NEG_INFINITY;
            (
                playing,
                m.p_bar,
                io_seen,
                now - m.io_stamp_s <= m.io_timeout_s,
            )
        };
        if playing == Playing::Nothing || !st.controller_state.servoing() {
            return false;
        }
        let n = st.q_rad.len();
        let mut q_cmd = [0.0; MAX_JOINTS];
        let mut dq_cmd = [0.0; MAX_JOINTS];
        let law = self.law.as_ref();
        {
            let Ok(mut slot) = player.slot() else {
                return false; // Python reports the poisoned lock
            };
            if !playable(&slot, n) {
                return false;
            }
            let Some(plan) = slot.as_mut() else {
                return false;
            };
            if let Some(law) = law {
                law.disengage_now(); // a plan plays: the law follows no hand
            }
            if !plan.command(
                st.cycle,
                u32::from(st.flags),
                &mut q_cmd[..n],
                &mut dq_cmd[..n],
            ) {
                return true; // the plan failed: nothing more is sent for it
            }
            if playing == Playing::Replaying && io_seen {
                if let Some(law) = law {
                    // a taught path is where the tool must be: the load's offset on top
                    let mut offset = [0.0; MAX_JOINTS];
                    let got = law.zero_moment().offset_at(
                        &q_cmd[..n],
                        &dq_cmd[..n],
                        &p_bar,
                        &mut offset[..n],
                    );
                    if let Err(e) = got {
                        plan.fail(format!("the model is undefined on the path: {e}"));
                        return true;
                    }
                    for j in 0..n {
                        q_cmd[j] += offset[j];
                    }
                }
            }
        }
        self.remember(st);
        if let Err((e, unencodable)) = self.publish(st, &q_cmd[..n], &dq_cmd[..n], now) {
            if unencodable {
                if let Ok(mut slot) = player.slot() {
                    if let Some(plan) = slot.as_mut() {
                        plan.fail(e.clone()); // a sample that cannot be sent ends the plan
                    }
                }
            }
            self.note(e);
            return true;
        }
        if playing == Playing::Replaying && self.sampling && io_fresh {
            if let Some(law) = law {
                self.sample(st, law, p_bar);
            }
        }
        true
    }

    /// Keep a replay's state for eq. (29) (free motion), with the motor torque it reports.
    fn sample(&self, st: &JointState, law: &Law, p_bar: [f64; 2]) {
        let n = st.q_rad.len();
        let mut tau = [0.0; MAX_JOINTS];
        if law
            .zero_moment()
            .motor_torque_at(&st.current_a, &mut tau[..n])
            .is_err()
        {
            return;
        }
        let (mut q, mut dq) = ([0.0; MAX_JOINTS], [0.0; MAX_JOINTS]);
        q[..n].copy_from_slice(&st.q_rad);
        dq[..n].copy_from_slice(&st.dq_rad_s);
        let mut samples = self.samples.lock().unwrap_or_else(|p| p.into_inner());
        if samples.len() < MAX_SAMPLES {
            samples.push((st.cycle, st.stamp_s, q, dq, tau, p_bar, n));
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
    /// publisher and the joint-state subscriber. `law`: the zero-moment law's or the
    /// admittance's compiled cycle, or None; `player`: the slot of the plan being played, or None; without either every
    /// state goes to `forward(payload: bytes, rx_s: float)`. `sampling`: keep a replay's states
    /// for eq. (29) ([`PyCycleLoop::take_samples`]).
    #[new]
    #[pyo3(signature = (zenoh_config, joint_state_key, joint_command_key, law, forward, player=None, sampling=false))]
    #[allow(clippy::too_many_arguments)]
    fn new(
        py: Python<'_>,
        zenoh_config: Vec<(String, String)>,
        joint_state_key: String,
        joint_command_key: String,
        law: Option<Bound<'_, PyAny>>,
        forward: Py<PyAny>,
        player: Option<Py<PyPlanPlay>>,
        sampling: bool,
    ) -> PyResult<Self> {
        if !forward.bind(py).is_callable() {
            return Err(PyValueError::new_err("forward must be callable"));
        }
        let law = law.as_ref().map(Law::from_py).transpose()?;
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
            player,
            sampling,
            samples: Mutex::new(Vec::with_capacity(MAX_SAMPLES)),
            forward,
            mode: Mutex::new(Mode {
                teaching: false,
                playing: Playing::Nothing,
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
    /// compiled law (`teaching`), or the plan it plays (`playing`: "identifying",
    /// "replaying" or None), when [s], and how long it stays fresh [s].
    #[pyo3(signature = (teaching, rx_s, timeout_s, playing=None))]
    fn set_lifecycle(
        &self,
        teaching: bool,
        rx_s: f64,
        timeout_s: f64,
        playing: Option<&str>,
    ) -> PyResult<()> {
        let playing = match playing {
            None => Playing::Nothing,
            Some("identifying") => Playing::Identifying,
            Some("replaying") => Playing::Replaying,
            Some(other) => {
                return Err(PyValueError::new_err(format!(
                    "playing {other:?}: neither \"identifying\" nor \"replaying\""
                )))
            }
        };
        let mut m = self.shared.mode.lock().unwrap_or_else(|p| p.into_inner());
        m.teaching = teaching;
        m.playing = playing;
        m.lifecycle_rx_s = rx_s;
        m.lifecycle_timeout_s = timeout_s;
        Ok(())
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

    /// A replay's states kept for eq. (29) since the last call, oldest first: `(cycle, stamp_s,
    /// q, dq, motor torque [N·m], (p2, p3) [bar])` each.
    #[allow(clippy::type_complexity)]
    fn take_samples(&self) -> Vec<(i64, f64, Vec<f64>, Vec<f64>, Vec<f64>, (f64, f64))> {
        let taken = std::mem::take(
            &mut *self
                .shared
                .samples
                .lock()
                .unwrap_or_else(|p| p.into_inner()),
        );
        taken
            .into_iter()
            .map(|(c, t, q, dq, tau, p, n)| {
                (
                    c,
                    t,
                    q[..n].to_vec(),
                    dq[..n].to_vec(),
                    tau[..n].to_vec(),
                    (p[0], p[1]),
                )
            })
            .collect()
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
