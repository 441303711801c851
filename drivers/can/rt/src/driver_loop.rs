//! The CAN driver's loop thread and its zenoh session: the cycle with no Python on it.
//!
//! Threads (as drivers/can/driver.py had them, in Rust): the loop thread blocks in `poll` on
//! the CAN socket until a frame arrives or the core's next deadline (an answer, a heartbeat) is
//! due; zenoh's receiving threads run the subscribers' callbacks directly, which decode, decide
//! and send under the one lock and never wait for anything else. A callback that answers a
//! cycle sends its frames itself, so the answer leaves as soon as the command arrives. Python
//! (the driver process) builds this from the cell config, reads health and notes at its own
//! pace and closes it; nothing it does is on the cycle.
//!
//! Asked to stop (SIGTERM: the gateway's stop, or the kernel's when the gateway dies), the loop
//! sends the BRAKE itself at its next wake-up (within [`MAX_WAIT_S`]): the signal's handler
//! only sets a flag. The Python shell's close sends it too, whichever comes first, but needs its
//! main thread and the GIL after a wake-up by the signal's watcher thread: once, beside a busy
//! suite, a killed gateway's CiA 402 drives ran on for 90 ms after the last command, until
//! their heartbeat watch stopped them (2026-12-03); the close's line now says how long after
//! the signal it began.

use std::sync::atomic::{AtomicBool, AtomicI32, AtomicU64, Ordering};
use std::sync::{Arc, Mutex, MutexGuard};
use std::thread::JoinHandle;

use zenoh::pubsub::{Publisher, Subscriber};
use zenoh::qos::{CongestionControl, Priority};
use zenoh::{Session, Wait};

use crate::can_socket::{CanSocket, Transport};
use crate::core::{Answer, HostCore};
use crate::frame::Frame;
use crate::histogram::Histogram;

/// Longest the loop sleeps with nothing due: a lifecycle change or an operator reset (which
/// arrive through callbacks) turns into a request frame within this [s].
pub const MAX_WAIT_S: f64 = 0.005;
/// Most frames taken in one wake-up before the deadlines are checked again.
pub const MAX_BURST: usize = 64;
/// Longest a CAN send may block (tx queue full) [s].
pub const SEND_TIMEOUT_S: f64 = 0.005;
/// Longest a note queue grows before the oldest are dropped (the shell drains it at 10 Hz).
const MAX_NOTES: usize = 256;

/// The stages of one cycle the driver times (health "stages"), CLOCK_MONOTONIC throughout:
/// decode — the cycle's last frame received → its JointState handed to zenoh; zenoh_out —
/// handed to zenoh → received by control; control — received by control → its JointCommand
/// handed to zenoh; zenoh_back — handed to zenoh → received here; encode — received here →
/// the answer's frames handed to the CAN socket (checks included); answer — the cycle's last
/// frame received → its computed answer handed to the CAN socket.
pub const STAGES: [&str; 6] = [
    "decode",
    "zenoh_out",
    "control",
    "zenoh_back",
    "encode",
    "answer",
];

/// CLOCK_MONOTONIC [s]: Python's `time.monotonic()`, one clock for every process.
pub fn monotonic_s() -> f64 {
    let mut ts = libc::timespec {
        tv_sec: 0,
        tv_nsec: 0,
    };
    // SAFETY: a valid timespec.
    unsafe { libc::clock_gettime(libc::CLOCK_MONOTONIC, &mut ts) };
    ts.tv_sec as f64 + ts.tv_nsec as f64 * 1e-9
}

/// The zenoh keys the cycle uses (gateway/messages.py Keys).
#[derive(Clone, Debug)]
pub struct Keys {
    pub joint_state: String,
    pub state_window: String,
    pub joint_command: String,
    pub lifecycle: String,
    pub io_state: String,
}

/// What the lock guards: the core, its scratch buffers, the stage timers and the sends.
pub struct Locked {
    pub core: HostCore,
    out: Vec<Frame>,
    closing: bool,
    pub stages: [Histogram; 6],
    /// (cycle, its stamp, when its JointState was handed to zenoh) of the newest cycle
    published: (i64, f64, f64),
    pub send_errors: u64,
    pub recv_errors: u64,
    /// the loop's own notes (send/receive failures), drained with the core's
    notes: Vec<(u8, String, String)>,
    last_io_note_s: f64,
    /// the exit BRAKE once sent (sent once, by whichever asked first)
    exit_brake: Option<ExitBrake>,
}

/// The exit BRAKE's outcome (frames sent, or why not) and who sent it.
struct ExitBrake {
    outcome: Result<usize, String>,
    /// sent by the loop on a stop signal (else by a close)
    on_signal: bool,
}

/// [`Shared::signal_s`] before any stop signal (the bits of a NaN: no time reads as it).
const NO_SIGNAL: u64 = u64::MAX;

struct Shared {
    locked: Mutex<Locked>,
    socket: CanSocket,
    stop: AtomicBool,
    failed: Mutex<Option<String>>,
    /// set by a stop signal's handler (async-signal-safe: atomics only), the number before
    /// the time: the signal's number, and its CLOCK_MONOTONIC time (f64 bits) or
    /// [`NO_SIGNAL`]. The loop brakes once it reads a time.
    signal_number: AtomicI32,
    signal_s: AtomicU64,
}

impl Shared {
    fn lock(&self) -> MutexGuard<'_, Locked> {
        // A panic elsewhere poisons the lock; the state is still the best we have to brake.
        self.locked.lock().unwrap_or_else(|p| p.into_inner())
    }

    /// When a stop signal reached the process (CLOCK_MONOTONIC [s]), or None.
    fn signal_s(&self) -> Option<f64> {
        match self.signal_s.load(Ordering::SeqCst) {
            NO_SIGNAL => None,
            bits => Some(f64::from_bits(bits)),
        }
    }
}

/// The signals a stop may be asked with; others are refused (SIGKILL/SIGSTOP cannot be
/// caught, and a fault signal must not be taken for a stop).
pub const STOP_SIGNALS: [libc::c_int; 4] =
    [libc::SIGTERM, libc::SIGINT, libc::SIGHUP, libc::SIGQUIT];

/// Send the exit BRAKE (the core's closing frames) unless it went already, then send nothing
/// more: every send checks `closing` under the lock. Its outcome (frames sent, or why not),
/// and whether this call sent it. `why` (the occasion, for a failed send's message) is only
/// called when this call sends: a braked loop asks again on every wake-up.
fn brake_on_exit(
    shared: &Shared,
    why: impl FnOnce() -> String,
    on_signal: bool,
) -> (Result<usize, String>, bool) {
    let mut l = shared.lock();
    if let Some(done) = &l.exit_brake {
        return (done.outcome.clone(), false);
    }
    l.closing = true;
    let mut out = std::mem::take(&mut l.out);
    out.clear();
    l.core.closing_frames(&mut out);
    l.out = out;
    let n = l.out.len();
    let outcome = if l.send_out(&shared.socket) {
        Ok(n)
    } else {
        Err(format!(
            "could not send the BRAKE request and hold set ({})",
            why()
        ))
    };
    l.exit_brake = Some(ExitBrake {
        outcome: outcome.clone(),
        on_signal,
    });
    (outcome, true)
}

/// The loop's answer to a stop signal that reached the process at `at_s`: the BRAKE now,
/// unless a close sent it first, and a note saying how long after the signal it went.
fn brake_on_signal(shared: &Shared, at_s: f64) {
    let signum = shared.signal_number.load(Ordering::SeqCst);
    let (outcome, sent_now) = brake_on_exit(shared, || format!("on signal {signum}"), true);
    if !sent_now {
        return;
    }
    let after_ms = (monotonic_s() - at_s) * 1e3;
    let mut l = shared.lock();
    if l.notes.len() < MAX_NOTES {
        let (level, msg) = match outcome {
            Ok(n) => (
                20,
                format!("BRAKE sent by the loop on signal {signum}, {after_ms:.1} ms after it ({n} frames)"),
            ),
            Err(e) => (40, format!("{e}, {after_ms:.1} ms after the signal")),
        };
        l.notes.push((level, "exit_brake".to_string(), msg));
    }
}

impl Locked {
    fn io_note(&mut self, level: u8, key: &str, msg: impl FnOnce() -> String, now: f64) {
        if now - self.last_io_note_s >= 1.0 && self.notes.len() < MAX_NOTES {
            self.last_io_note_s = now;
            self.notes.push((level, key.to_string(), msg()));
        }
    }

    /// Send `self.out` (all of it or until a send fails); false if one failed.
    fn send_out(&mut self, socket: &CanSocket) -> bool {
        let mut failed = None;
        for frame in self.out.iter() {
            if let Err(e) = socket.send(frame, SEND_TIMEOUT_S) {
                failed = Some(e);
                break;
            }
        }
        match failed {
            None => true,
            Some(e) => {
                self.send_errors += 1;
                let now = monotonic_s();
                self.io_note(40, "send", || format!("CAN send failed: {e}"), now);
                false
            }
        }
    }
}

/// The running cycle: the loop thread, the zenoh session and its declarations.
pub struct DriverLoop {
    shared: Arc<Shared>,
    session: Session,
    subscribers: Vec<Subscriber<()>>,
    thread: Option<JoinHandle<()>>,
    closed: bool,
    /// the stop signals' registrations, removed on close
    signal_ids: Vec<signal_hook_registry::SigId>,
}

impl DriverLoop {
    /// Open the CAN socket and the zenoh session (configured by `zenoh_config`: (key, JSON5
    /// value) pairs, the same the Python session gets), declare the publishers and
    /// subscribers and start the loop thread. Err names what failed.
    ///
    /// Each of `brake_signals` (of [`STOP_SIGNALS`]) makes the loop send the BRAKE at once.
    /// The handler is chained after the one installed before (the Python process's, which
    /// stops it), and a handler must be installed: a signal whose disposition is the default
    /// would no longer end the process, so pass only signals the process already handles.
    pub fn start(
        core: HostCore,
        transport: &Transport,
        zenoh_config: &[(String, String)],
        keys: &Keys,
        brake_signals: &[libc::c_int],
    ) -> Result<DriverLoop, String> {
        if let Some(s) = brake_signals.iter().find(|s| !STOP_SIGNALS.contains(s)) {
            return Err(format!(
                "signal {s} is not a stop signal (SIGTERM, SIGINT, SIGHUP, SIGQUIT)"
            ));
        }
        let mut cfg = zenoh::Config::default();
        for (k, v) in zenoh_config {
            cfg.insert_json5(k, v)
                .map_err(|e| format!("zenoh config {k} = {v}: {e}"))?;
        }
        let session = zenoh::open(cfg)
            .wait()
            .map_err(|e| format!("zenoh session: {e}"))?;
        let socket = CanSocket::open(transport).map_err(|e| format!("CAN link: {e}"))?;
        let out = Vec::with_capacity(64);
        let shared = Arc::new(Shared {
            locked: Mutex::new(Locked {
                core,
                out,
                closing: false,
                stages: Default::default(),
                published: (-1, 0.0, 0.0),
                send_errors: 0,
                recv_errors: 0,
                notes: Vec::with_capacity(MAX_NOTES),
                last_io_note_s: f64::NEG_INFINITY,
                exit_brake: None,
            }),
            socket,
            stop: AtomicBool::new(false),
            failed: Mutex::new(None),
            signal_number: AtomicI32::new(0),
            signal_s: AtomicU64::new(NO_SIGNAL),
        });
        let declared = (|| -> Result<_, String> {
            let z = |e: zenoh::Error| format!("zenoh declaration: {e}");
            // the loop's data: never blocks (a slow peer must not stall the loop: the message
            // is dropped and the receiver's deadline handles it), sent at once, real-time
            let state_pub = session
                .declare_publisher(keys.joint_state.clone())
                .congestion_control(CongestionControl::Drop)
                .priority(Priority::RealTime)
                .express(true)
                .wait()
                .map_err(z)?;
            let window_pub = session
                .declare_publisher(keys.state_window.clone())
                .congestion_control(CongestionControl::Drop)
                .wait()
                .map_err(z)?;
            // each subscriber's callback runs on zenoh's receiving thread (no hand-off)
            let subscribe = |key: &String, handler: fn(&Shared, &[u8])| {
                let s = shared.clone();
                session
                    .declare_subscriber(key.clone())
                    .callback(move |sample| handler(&s, &sample.payload().to_bytes()))
                    .wait()
                    .map_err(z)
            };
            let subscribers = vec![
                subscribe(&keys.joint_command, on_command)?,
                subscribe(&keys.lifecycle, on_lifecycle)?,
                subscribe(&keys.io_state, on_io)?,
            ];
            Ok((state_pub, window_pub, subscribers))
        })();
        let (state_pub, window_pub, subscribers) = match declared {
            Ok(d) => d,
            Err(e) => {
                let _ = session.close().wait();
                return Err(e);
            }
        };
        let s = shared.clone();
        let thread = std::thread::Builder::new()
            .name("can-cycle".into())
            .spawn(move || run(&s, &state_pub, &window_pub))
            .map_err(|e| format!("loop thread: {e}"))?;
        let mut started = DriverLoop {
            shared,
            session,
            subscribers,
            thread: Some(thread),
            closed: false,
            signal_ids: Vec::new(),
        };
        for &signum in brake_signals {
            let s = started.shared.clone();
            // SAFETY: the action only stores atomics and reads CLOCK_MONOTONIC
            // (clock_gettime is async-signal-safe); the signal is not one of FORBIDDEN.
            let id = unsafe {
                signal_hook_registry::register(signum, move || {
                    s.signal_number.store(signum, Ordering::SeqCst);
                    s.signal_s.store(monotonic_s().to_bits(), Ordering::SeqCst);
                })
            };
            match id {
                Ok(id) => started.signal_ids.push(id),
                Err(e) => {
                    let _ = started.close();
                    return Err(format!("signal {signum}: {e}"));
                }
            }
        }
        Ok(started)
    }

    /// When a stop signal reached the process (CLOCK_MONOTONIC [s]; the loop then brakes
    /// within [`MAX_WAIT_S`]), or None.
    pub fn signal_s(&self) -> Option<f64> {
        self.shared.signal_s()
    }

    /// Whether the exit BRAKE went out from the loop on a stop signal (false before it went,
    /// or when a close sent it first).
    pub fn braked_on_signal(&self) -> bool {
        self.shared
            .lock()
            .exit_brake
            .as_ref()
            .is_some_and(|b| b.on_signal)
    }

    /// The lock, for health, notes and counters (never held long: the cycle waits for it).
    pub fn lock(&self) -> MutexGuard<'_, Locked> {
        self.shared.lock()
    }

    pub fn running(&self) -> bool {
        self.thread.as_ref().is_some_and(|t| !t.is_finished())
    }

    /// The error that ended the loop thread, if one did.
    pub fn failed(&self) -> Option<String> {
        self.shared
            .failed
            .lock()
            .unwrap_or_else(|p| p.into_inner())
            .clone()
    }

    /// The notes of the core and the loop since the last call.
    pub fn take_notes(&self) -> Vec<(u8, String, String)> {
        let mut l = self.shared.lock();
        let mut notes = std::mem::take(&mut l.notes);
        notes.extend(l.core.take_notes());
        notes
    }

    /// Ask the controller to brake (and hold) at once, then stop the loop and release every
    /// link; the number of frames sent on the way out. Idempotent.
    ///
    /// The BRAKE goes out before the loop thread is joined (every send checks `closing` under
    /// the lock, so nothing follows it): a controller reads it at its next cycle boundary, and
    /// a cycle it misses is one more cycle of the arm at speed.
    pub fn close(&mut self) -> Result<usize, String> {
        if self.closed {
            return Ok(0);
        }
        self.closed = true;
        let (sent, _) = brake_on_exit(&self.shared, || "on exit".to_string(), false);
        for id in self.signal_ids.drain(..) {
            signal_hook_registry::unregister(id);
        }
        self.shared.stop.store(true, Ordering::SeqCst);
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
        for s in self.subscribers.drain(..) {
            let _ = s.undeclare().wait();
        }
        let _ = self.session.close().wait();
        sent
    }
}

impl Drop for DriverLoop {
    fn drop(&mut self) {
        let _ = self.close();
    }
}

fn run(shared: &Shared, state_pub: &Publisher<'static>, window_pub: &Publisher<'static>) {
    let mut state = Vec::with_capacity(1024);
    let mut window = Vec::with_capacity(2048);
    while !shared.stop.load(Ordering::Relaxed) {
        let timeout = {
            let l = shared.lock();
            if l.closing {
                // braked: nothing is due any more (the core's deadlines stay in the past, and
                // polling on them would spin this thread, at the cycle's priority, until the
                // close joins it: it starved the closing process on one CPU, 2026-12-04)
                MAX_WAIT_S
            } else {
                (l.core.next_tick_s() - monotonic_s()).clamp(0.0, MAX_WAIT_S)
            }
        };
        match shared.socket.wait_readable(timeout) {
            Ok(true) => {
                for _ in 0..MAX_BURST {
                    match shared.socket.try_recv() {
                        Ok(Some(frame)) => on_frame(
                            shared,
                            &frame,
                            &mut state,
                            &mut window,
                            state_pub,
                            window_pub,
                        ),
                        Ok(None) => break,
                        Err(e) => {
                            recv_failed(shared, &e);
                            break;
                        }
                    }
                }
            }
            Ok(false) => {}
            Err(e) => recv_failed(shared, &e),
        }
        if let Some(at_s) = shared.signal_s() {
            brake_on_signal(shared, at_s);
        }
        periodic(shared);
    }
}

fn recv_failed(shared: &Shared, e: &std::io::Error) {
    let now = monotonic_s();
    {
        let mut l = shared.lock();
        l.recv_errors += 1;
        l.io_note(40, "recv", || format!("CAN receive failed: {e}"), now);
    }
    if e.kind() == std::io::ErrorKind::BrokenPipe {
        *shared.failed.lock().unwrap_or_else(|p| p.into_inner()) =
            Some(format!("CAN link lost: {e}"));
        shared.stop.store(true, Ordering::SeqCst);
        return;
    }
    std::thread::sleep(std::time::Duration::from_millis(10));
}

fn on_frame(
    shared: &Shared,
    frame: &Frame,
    state: &mut Vec<u8>,
    window: &mut Vec<u8>,
    state_pub: &Publisher<'static>,
    window_pub: &Publisher<'static>,
) {
    let now = monotonic_s();
    let outcome = {
        let mut l = shared.lock();
        if l.closing {
            return;
        }
        let mut out = std::mem::take(&mut l.out);
        out.clear();
        let outcome = l.core.on_frame(frame, now, &mut out, state, window);
        l.out = out;
        if !l.out.is_empty() {
            l.send_out(&shared.socket);
        }
        if outcome.state {
            let handed = monotonic_s();
            let cycle = l.core.pending_cycle().unwrap_or(-1);
            l.published = (cycle, now, handed);
            l.stages[0].add(handed - now);
        }
        outcome
    };
    if outcome.state {
        if let Err(e) = state_pub.put(state.as_slice()).wait() {
            let mut l = shared.lock();
            l.io_note(
                40,
                "put",
                || format!("cannot publish the joint state: {e}"),
                now,
            );
        }
        if outcome.window {
            let _ = window_pub.put(window.as_slice()).wait();
        }
    }
}

fn periodic(shared: &Shared) {
    let now = monotonic_s();
    let mut l = shared.lock();
    if l.closing {
        return;
    }
    let mut out = std::mem::take(&mut l.out);
    out.clear();
    l.core.on_tick(now, &mut out);
    l.out = out;
    if !l.out.is_empty() {
        l.send_out(&shared.socket);
    }
}

fn on_lifecycle(shared: &Shared, payload: &[u8]) {
    let now = monotonic_s();
    shared.lock().core.on_lifecycle(payload, now);
}

fn on_io(shared: &Shared, payload: &[u8]) {
    let now = monotonic_s();
    shared.lock().core.on_io(payload, now);
}

fn on_command(shared: &Shared, payload: &[u8]) {
    let now = monotonic_s();
    let mut l = shared.lock();
    if l.closing {
        return;
    }
    let mut out = std::mem::take(&mut l.out);
    out.clear();
    let outcome = l.core.on_command(payload, now, &mut out);
    l.out = out;
    if l.out.is_empty() {
        return;
    }
    let sent = l.send_out(&shared.socket);
    if sent && outcome.answer == Answer::Command {
        if let Some(c) = outcome.command {
            let sent_s = monotonic_s();
            let (cycle, _stamp, handed) = l.published;
            l.stages[4].add(sent_s - now);
            l.stages[3].add(now - c.sent_stamp_s);
            l.stages[5].add(sent_s - c.state_stamp_s);
            if c.state_rx_stamp_s > 0.0 {
                l.stages[2].add(c.sent_stamp_s - c.state_rx_stamp_s);
                if cycle == c.cycle {
                    l.stages[1].add(c.state_rx_stamp_s - handed);
                }
            }
        }
    }
}

/// The stages' summaries as health's "stages" object.
pub fn stages_json(stages: &[Histogram; 6]) -> serde_json::Value {
    let mut m = serde_json::Map::new();
    for (name, h) in STAGES.iter().zip(stages.iter()) {
        m.insert((*name).to_string(), h.summary());
    }
    serde_json::Value::Object(m)
}
