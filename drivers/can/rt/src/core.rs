//! The CAN host's per-cycle decisions, free of I/O: decode → decide → encode (the compiled
//! drivers/can/core.py).
//!
//! [`HostCore`] is what the CAN driver does each control cycle, with the sockets taken out, so
//! every decision can be tested cycle by cycle with an injected clock and profiled alone. Its
//! inputs are received CAN frames, zenoh payloads and the time; its outputs are the frames to
//! send and the JointState payload to publish. It never blocks, sleeps, sends or publishes;
//! the loop thread does, around it.
//!
//! Every cycle the controller sends its joint feedback; the core turns it into a JointState
//! and answers the cycle exactly once (PROTOCOL.md §3), with either
//!
//! * [`Answer::Command`]: the control process's JointCommand for that cycle, forwarded only
//!   if every check passes (lifecycle TEACHING, IDENTIFYING or REPLAYING, enabling device held
//!   and e-stop chain closed, controller servoing, the command fresh, for this very cycle,
//!   within the following-error, joint-limit and velocity limits);
//! * [`Answer::Coast`]: when the command is late, the last forwarded command moved on by its
//!   own velocity (what the controller's interpolation does within a cycle, §5), as long as
//!   that command answered one of the `coast_max_cycles` cycles before; one late answer then
//!   costs the operator nothing;
//! * [`Answer::Hold`]: a hold set (hold=1, zero velocity) at a position latched when holding
//!   began — at once when forwarding is not allowed, otherwise when the cycle's answer
//!   deadline passes;
//! * [`Answer::Ramp`]: a controlled stop (stop_ramp.rs) — the enabling device released, or
//!   the lifecycle gone from a commanding state to READY or STOPPED, while everything else is
//!   in order: the last command continues along its path with its velocity falling to zero at
//!   `[can] stop_deceleration_rad_s2`, then the ramp's end is held (stop category 2; for
//!   STOPPED the servo power stays on until the ramp ends, then the brakes: category 1).
//!   Faults hold at once.
//!
//! While the driver holds with the servo on, a standstill monitor watches the measured
//! positions (stop_ramp.rs); a drive that does not hold the arm trips it: the brakes, and the
//! gateway faults.
//!
//! The answer deadline of a cycle is `min(deadline_s, answer_by_period_fraction × period)`
//! after its JointState stamp: a command set must reach the controller before the next cycle
//! begins or it is a missed cycle (§3). A command arriving after its cycle was answered is
//! rejected as `late_cycle`. Against a lock-step virtual controller (`lockstep_answer_wait_s`
//! > 0), which starts its next cycle only when answered, the deadline and a command's age
//! limit are that wait instead: a product process slowed by a loaded machine then slows the
//! virtual plant rather than cutting holds into its motion.
//!
//! Servo power is requested from the gateway's lifecycle (READY, TEACHING, IDENTIFYING or
//! REPLAYING, and fresh: SERVO_ON; anything else, including silence: BRAKE), repeated with
//! every host heartbeat. The default and [`HostCore::closing_frames`] lead to BRAKE.
//!
//! Every published current is the reported one less the current sensors' zero, measured while
//! the servo power is off (current_zero.rs); the first SERVO_ON waits until that measurement
//! is complete.
//!
//! Conditions worth a log line become *notes* (level, key, message), rate-limited per key
//! inside the core like gateway/ratelog.py's RateLimitedLog and queued for the shell to drain
//! ([`HostCore::take_notes`]); a note's text is only built when the note is kept, so a cycle
//! blocked for minutes does not allocate.
//!
//! The normal forwarding path (a cycle's frames in, its JointState out, a command in, its
//! frames out) does not allocate: frames go into the caller's `Vec<Frame>`, the JointState and
//! the StateWindow into the caller's byte buffers, and every per-joint value lives in fixed
//! arrays of [`MAX_JOINTS`].

use std::collections::VecDeque;
use std::fmt::Write as _;

use serde_json::{Map, Value};

use crate::adapter::{Adapter, ControllerState, Feedback, FrameError, HostRequest, MAX_JOINTS};
use crate::bus_errors::BusErrors;
use crate::current_zero::CurrentZero;
use crate::frame::Frame;
use crate::lifecycle::{LifecycleMsg, LifecycleOrder};
use crate::lost_cycles::LostCycles;
use crate::messages::{
    fmt_g, IoState, JointCommand, JointState, Lifecycle, COMMANDING, FLAG_ESTOP, FLAG_PREV_COAST,
    FLAG_PREV_HOLD, FLAG_SERVO_POWER,
};
use crate::plausibility::{FeedbackPlausibility, DEFAULT_TOLERANCE_RAD};
use crate::speed_monitor::{SpeedMonitor, DEFAULT_CONFIRM, DEFAULT_WINDOW};
use crate::stop_ramp::{StandstillMonitor, StopRamp};
use crate::window::StateWindowBuilder;

pub use crate::core_config::{CoreConfig, LostCycleAnswer};
pub use crate::speed_monitor::KinematicChain;

/// Why a JointCommand was not forwarded (the keys of the health message's "rejected").
pub const REJECT_REASONS: [&str; 10] = [
    "stale",              // older than deadline_s
    "blocked_lifecycle",  // lifecycle not commanding, or silent
    "blocked_enabling",   // enabling device released, e-stop chain open, or I/O silent
    "blocked_controller", // controller not servoing (BRAKED/FAULT) or its link is down
    "bad_message",        // undecodable payload, NaN, wrong joint count
    "out_of_range",       // following error, velocity, or a value the protocol cannot carry
    "late_cycle",         // not for the current cycle, or that cycle was already answered
    "blocked_speed",      // the speed monitor tripped and the lifecycle still runs
    "blocked_bus",        // a CAN bus fault is latched (bus-off, a burst of errors)
    "blocked_lost",       // too many lost command cycles, until the cell is stopped
];

/// A controlled stop continues a forwarded command at most this many cycles old.
pub const RAMP_MAX_AGE_CYCLES: i64 = 5;

/// Lifecycle states in which the arm moves at hand-guiding speeds: the speed monitor applies.
pub const MONITORED: [Lifecycle; 2] = [Lifecycle::Teaching, Lifecycle::Replaying];

/// Log levels of notes (Python's logging levels).
pub const DEBUG: u8 = 10;
pub const INFO: u8 = 20;
pub const WARNING: u8 = 30;
pub const ERROR: u8 = 40;

/// At most one note per key per this long; the next says how many were held back [s]
/// (driver.py LOG_PERIOD_S).
pub const NOTE_PERIOD_S: f64 = 1.0;
/// Notes kept until the shell drains them; more are counted and dropped.
pub const NOTE_QUEUE: usize = 64;

/// How a cycle was answered.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Answer {
    /// Not answered (yet), or a command rejected without an answer.
    None,
    /// The control process's command, forwarded.
    Command,
    /// The last forwarded command moved on by its own velocity.
    Coast,
    /// A hold set.
    Hold,
    /// A controlled stop's ramp.
    Ramp,
}

impl Answer {
    /// Python's spelling: "", "command", "coast", "hold", "ramp".
    pub fn as_str(self) -> &'static str {
        match self {
            Answer::None => "",
            Answer::Command => "command",
            Answer::Coast => "coast",
            Answer::Hold => "hold",
            Answer::Ramp => "ramp",
        }
    }
}

/// Both the sender's stamp and our receipt are recent (a future stamp never keeps it fresh).
/// All times [s].
pub fn fresh(stamp_s: f64, received_s: f64, now_s: f64, timeout_s: f64) -> bool {
    (now_s - received_s) < timeout_s
        && -timeout_s < (now_s - stamp_s)
        && (now_s - stamp_s) < timeout_s
}

/// Next time of a periodic action: on the grid, or one period from now if behind [s].
pub fn next_tick(previous_s: f64, period_s: f64, now_s: f64) -> f64 {
    let following = previous_s + period_s;
    if following > now_s {
        following
    } else {
        now_s + period_s
    }
}

/// The newest complete controller cycle, waiting for (or given) its answer.
#[derive(Clone, Copy, Debug)]
pub struct Cycle {
    /// widened cycle counter (JointState.cycle)
    pub cycle: i64,
    /// the counter as on the wire
    pub counter: u32,
    /// JointState.stamp_s: when its last frame arrived [s]
    pub stamp_s: f64,
    /// coast or hold if still unanswered at this time [s]
    pub answer_by_s: f64,
    /// measured positions of the cycle [rad]; the first `n` are joints
    pub q_rad: [f64; MAX_JOINTS],
    pub n: usize,
    /// how it was answered ([`Answer::None`] until it is)
    pub answer: Answer,
}

impl Cycle {
    pub fn answered(&self) -> bool {
        self.answer != Answer::None
    }

    /// The measured positions [rad].
    pub fn q(&self) -> &[f64] {
        &self.q_rad[..self.n]
    }
}

/// The stamps of a decoded JointCommand: the shell times its stages from them.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CommandStamps {
    /// the JointState.cycle the command answers (32 bits on the wire)
    pub cycle: i64,
    /// JointState.stamp_s it was computed from [s]
    pub state_stamp_s: f64,
    /// control-process time at publication [s]
    pub sent_stamp_s: f64,
    /// control-process time the JointState arrived [s]; 0 = not reported
    pub state_rx_stamp_s: f64,
}

/// What one JointCommand asked of the driver (Python's CommandResult without the frames,
/// which went into the caller's `out`).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CommandOutcome {
    /// [`Answer::Command`], [`Answer::Hold`]/[`Answer::Ramp`] (rejected, its cycle answered
    /// by the driver), or [`Answer::None`] (rejected without an answer)
    pub answer: Answer,
    /// None if the payload could not be decoded
    pub command: Option<CommandStamps>,
}

/// What one received CAN frame produced (Python's FrameResult; frames went into `out`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub struct FrameOutcome {
    /// the frame completed a cycle: its JointState is in the state buffer
    pub state: bool,
    /// a StateWindow closed: it is in the window buffer
    pub window: bool,
}

/// The last forwarded command: what a coast or a ramp continues.
#[derive(Clone, Copy, Debug)]
struct LastForward {
    /// min(the command's state stamp, its cycle's stamp) [s]
    stamp_s: f64,
    cycle: i64,
    q: [f64; MAX_JOINTS],
    dq: [f64; MAX_JOINTS],
    /// the controller's period when it was forwarded [s]
    period_s: f64,
}

/// The gateway's lifecycle as the core keeps it.
#[derive(Clone, Copy, Debug)]
struct LifecycleIn {
    state: Lifecycle,
    seq: i64,
    stamp_s: f64,
}

/// The Modbus driver's I/O as the core keeps it.
#[derive(Clone, Copy, Debug)]
struct IoIn {
    stamp_s: f64,
    enabling: bool,
    estop_ok: bool,
}

/// Why a JointCommand is not forwarded, with what its note says, formatted only when the
/// note is kept.
enum Problem {
    Joints {
        n: usize,
        expected: usize,
    },
    Blocked {
        reason: &'static str,
        cycle: i64,
    },
    NotCurrent {
        cycle: i64,
        current: Option<i64>,
    },
    Answered {
        cycle: i64,
    },
    Stale {
        cycle: i64,
        age_s: f64,
    },
    FollowingError {
        k: usize,
        error: f64,
        limit: f64,
    },
    OutsideLimits {
        k: usize,
        q: f64,
        lower: f64,
        upper: f64,
    },
    Velocity {
        k: usize,
        speed: f64,
        limit: f64,
    },
    Frame(FrameError),
}

impl Problem {
    fn reason(&self) -> &'static str {
        match self {
            Problem::Joints { .. } => "bad_message",
            Problem::Blocked { reason, .. } => reason,
            Problem::NotCurrent { .. } | Problem::Answered { .. } => "late_cycle",
            Problem::Stale { .. } => "stale",
            Problem::FollowingError { .. }
            | Problem::OutsideLimits { .. }
            | Problem::Velocity { .. }
            | Problem::Frame(_) => "out_of_range",
        }
    }

    fn detail(&self) -> String {
        match self {
            Problem::Joints { n, expected } => format!("{n} joints, expected {expected}"),
            Problem::Blocked { cycle, .. } => format!("cycle {cycle}"),
            Problem::NotCurrent { cycle, current } => match current {
                Some(c) => format!("for cycle {cycle}, current cycle is {c}"),
                None => format!("for cycle {cycle}, current cycle is None"),
            },
            Problem::Answered { cycle } => format!("cycle {cycle} was already answered"),
            Problem::Stale { cycle, age_s } => format!("cycle {cycle} is {:.1} ms old", age_s * 1e3),
            Problem::FollowingError { k, error, limit } => format!(
                "joint {}: |q_cmd - q| = {error:.4} rad > {} rad",
                k + 1,
                fmt_g(*limit)
            ),
            Problem::OutsideLimits { k, q, lower, upper } => format!(
                "joint {}: q_cmd = {q:.4} rad outside the driver's limits [{lower:.4}, {upper:.4}] rad",
                k + 1
            ),
            Problem::Velocity { k, speed, limit } => format!(
                "joint {}: |dq_cmd| = {speed:.4} rad/s > {} rad/s",
                k + 1,
                fmt_g(*limit)
            ),
            Problem::Frame(exc) => exc.0.clone(),
        }
    }
}

/// `round(x, digits)` for the health message.
fn round_to(x: f64, digits: i32) -> f64 {
    let scale = 10f64.powi(digits);
    (x * scale).round() / scale
}

fn rounded(values: &[f64], digits: i32) -> Value {
    Value::Array(
        values
            .iter()
            .map(|&v| Value::from(round_to(v, digits)))
            .collect(),
    )
}

fn any_nonzero(values: &[f64]) -> bool {
    values.iter().any(|&v| v != 0.0) // NaN counts, as numpy's any() does
}

/// The rate-limited, bounded note queue (gateway/ratelog.py RateLimitedLog, per key).
struct Notes {
    queue: VecDeque<(u8, String, String)>,
    /// (key, when its last note was kept [s], notes held back since)
    keys: Vec<(&'static str, f64, u64)>,
    /// notes that found the queue full
    dropped: u64,
}

impl Notes {
    fn new() -> Notes {
        Notes {
            queue: VecDeque::with_capacity(NOTE_QUEUE),
            keys: Vec::with_capacity(64),
            dropped: 0,
        }
    }

    /// At most one note per `key` and [`NOTE_PERIOD_S`]; `message` runs only for a kept one.
    fn note(&mut self, level: u8, key: &'static str, now: f64, message: impl FnOnce() -> String) {
        let suppressed = match self.keys.iter_mut().find(|e| e.0 == key) {
            Some(entry) => {
                if now - entry.1 < NOTE_PERIOD_S {
                    entry.2 += 1;
                    return;
                }
                entry.1 = now;
                std::mem::take(&mut entry.2)
            }
            None => {
                self.keys.push((key, now, 0));
                0
            }
        };
        self.push(level, key, suppressed, message);
    }

    /// A note that is not rate-limited (Python logged these directly: each happens once per
    /// change of state).
    fn always(&mut self, level: u8, key: &'static str, message: impl FnOnce() -> String) {
        self.push(level, key, 0, message);
    }

    fn push(
        &mut self,
        level: u8,
        key: &'static str,
        suppressed: u64,
        message: impl FnOnce() -> String,
    ) {
        if self.queue.len() >= NOTE_QUEUE {
            self.dropped += 1;
            return;
        }
        let mut text = message();
        if suppressed > 0 {
            let _ = write!(
                text,
                " (+{suppressed} similar in the last {} s)",
                fmt_g(NOTE_PERIOD_S)
            );
        }
        self.queue.push_back((level, key.to_string(), text));
    }

    fn take(&mut self) -> Vec<(u8, String, String)> {
        let mut out: Vec<_> = self.queue.drain(..).collect();
        if self.dropped > 0 {
            out.push((
                WARNING,
                "notes".to_string(),
                format!(
                    "{} notes dropped: the queue of {NOTE_QUEUE} was full",
                    self.dropped
                ),
            ));
            self.dropped = 0;
        }
        out
    }
}

/// The CAN host's decisions (module docs). Not thread-safe: the loop calls it under one lock.
pub struct HostCore {
    /// the settings (read through [`HostCore::config`]: the per-joint limits were taken from
    /// them at construction)
    config: CoreConfig,
    /// The controller's protocol (the shell may read its stats; the core feeds it).
    pub adapter: Box<dyn Adapter>,
    /// Period of the health messages [s].
    pub health_period_s: f64,
    n: usize,
    /// the joint range a forwarded command stays in: the limits less joint_limit_margin_rad [rad]
    lower: [f64; MAX_JOINTS],
    upper: [f64; MAX_JOINTS],
    max_fe: [f64; MAX_JOINTS],
    max_dq: [f64; MAX_JOINTS],
    stop_decel: Vec<f64>,
    zeros: [f64; MAX_JOINTS],

    // inputs from zenoh
    lifecycle: Option<LifecycleIn>,
    /// The gateway's lifecycle stream, its order checked (messages dropped are counted).
    pub lifecycle_order: LifecycleOrder,
    lifecycle_rx_s: f64,
    io: Option<IoIn>,
    io_rx_s: f64,
    reset_wanted: bool,

    // controller
    /// The current sensors' zero, measured with the servo power off.
    pub current_zero: CurrentZero,
    /// The newest complete cycle's feedback.
    pub feedback: Option<Feedback>,
    last_cycle_rx_s: f64,
    last_counter: Option<u32>,
    cycle: i64,
    pending: Option<Cycle>,

    // what we asked for and sent
    /// The host request last sent.
    pub request_sent: Option<HostRequest>,
    next_heartbeat_s: f64,
    /// when the next host-clocked cycle starts (the adapter's clock period; inf: never)
    next_clock_s: f64,
    next_health_s: f64,
    last_sent_q: Option<[f64; MAX_JOINTS]>,
    last_sent_dq: Option<[f64; MAX_JOINTS]>,
    /// the last forwarded (or coasted) position since servo-on
    last_forwarded_q: Option<[f64; MAX_JOINTS]>,
    last_forward: Option<LastForward>,
    hold_q: Option<[f64; MAX_JOINTS]>,
    holding: bool,
    /// the controlled stop under way, None when there is none
    ramp: Option<StopRamp>,

    /// Error frames and the bus fault they latch.
    pub bus: BusErrors,
    /// Lost command cycles and the policy's latched trip.
    pub lost: LostCycles,
    /// Monitored standstill while the driver holds with the servo on.
    pub standstill: StandstillMonitor,
    /// Hand guiding's speed monitor (None when `hand_guiding_max_speed_m_s` is 0).
    pub speed: Option<SpeedMonitor>,
    /// Measured positions that jump further than the arm can move.
    pub plausibility: FeedbackPlausibility,
    /// The StateWindow the readers off the cycle get.
    pub window: StateWindowBuilder,

    notes: Notes,
    /// the latest `now` the core was given (for notes of calls without one) [s]
    last_now: f64,

    // counters (monotonic, reported in health)
    /// Commands not forwarded, per reason (indexed as [`REJECT_REASONS`]).
    pub rejected: [u64; REJECT_REASONS.len()],
    pub cycles: u64,
    pub forwarded: u64,
    pub coasted: u64,
    pub held: u64,
    pub ramped: u64,
    pub unanswered: u64,
    pub bad_inputs: u64,
}

impl HostCore {
    /// The core for `config` and `adapter`. `health_period_s` [s]; `stored_zero` the
    /// commissioning's current zero (zero [A], samples, per-cycle noise [A]);
    /// `speed_points` the kinematics of the speed monitor (required when
    /// `hand_guiding_max_speed_m_s` > 0); `joint_limits_rad` (lower, upper) [rad], the
    /// robot description's, which the driver's own limits lie `joint_limit_margin_rad`
    /// inside. Err names what does not fit.
    pub fn new(
        config: CoreConfig,
        adapter: Box<dyn Adapter>,
        health_period_s: f64,
        stored_zero: Option<(Vec<f64>, i64, Vec<f64>)>,
        speed_points: Option<KinematicChain>,
        joint_limits_rad: (Vec<f64>, Vec<f64>),
    ) -> Result<HostCore, String> {
        let n = config.joints;
        if !(1..=MAX_JOINTS).contains(&n) {
            return Err(format!("[can].joints: {n} outside 1..{MAX_JOINTS}"));
        }
        if adapter.n_joints() != n {
            return Err(format!(
                "[can].joints: {n} but the adapter is built for {}",
                adapter.n_joints()
            ));
        }
        let half_timeout_s = adapter.host_heartbeat_timeout_s() / 2.0;
        if config.heartbeat_period_s.is_nan() || config.heartbeat_period_s > half_timeout_s {
            return Err(format!(
                "[can].heartbeat_period_s: {} s; the controller faults after {} s without a \
                 heartbeat, so send at least twice within that",
                config.heartbeat_period_s,
                adapter.host_heartbeat_timeout_s()
            ));
        }
        if !(health_period_s.is_finite() && health_period_s > 0.0) {
            return Err(format!("health period {health_period_s} s must be > 0"));
        }
        if adapter.counter_modulus() == 0 {
            return Err(format!("adapter {}: counter modulus 0", adapter.name()));
        }
        for (name, values) in [
            ("max_following_error_rad", &config.max_following_error_rad),
            ("max_velocity_rad_s", &config.max_velocity_rad_s),
            ("stop_deceleration_rad_s2", &config.stop_deceleration_rad_s2),
        ] {
            if values.len() != n {
                return Err(format!(
                    "[can].{name}: has {} values for {n} joints",
                    values.len()
                ));
            }
        }
        let (lo, hi) = &joint_limits_rad;
        if lo.len() != n || hi.len() != n {
            return Err(format!(
                "joint limits: {} lower and {} upper for {n} joints",
                lo.len(),
                hi.len()
            ));
        }
        let mut lower = [0.0; MAX_JOINTS];
        let mut upper = [0.0; MAX_JOINTS];
        let mut max_fe = [0.0; MAX_JOINTS];
        let mut max_dq = [0.0; MAX_JOINTS];
        for k in 0..n {
            if lo[k].is_nan() || hi[k].is_nan() || lo[k] > hi[k] {
                return Err(format!(
                    "joint limits: J{} [{}, {}] rad",
                    k + 1,
                    lo[k],
                    hi[k]
                ));
            }
            lower[k] = lo[k] + config.joint_limit_margin_rad;
            upper[k] = hi[k] - config.joint_limit_margin_rad;
            max_fe[k] = config.max_following_error_rad[k];
            max_dq[k] = config.max_velocity_rad_s[k];
        }
        let current_zero = CurrentZero::new(
            n,
            config.current_zero_cycles as i64,
            config.current_zero_settle_cycles as i64,
            stored_zero,
        )?;
        let speed = if config.hand_guiding_max_speed_m_s > 0.0 {
            let points = speed_points.ok_or_else(|| {
                "[can].hand_guiding_max_speed_m_s > 0 needs the kinematics (speed_points)"
                    .to_string()
            })?;
            if points.n_joints() != n {
                return Err(format!(
                    "the kinematic chain has {} joints, [can].joints {n}",
                    points.n_joints()
                ));
            }
            Some(SpeedMonitor::new(
                points,
                config.hand_guiding_max_speed_m_s,
                DEFAULT_WINDOW,
                DEFAULT_CONFIRM,
            )?)
        } else {
            None
        };
        let lost = LostCycles::new(
            config.lost_cycles_max_consecutive as i64,
            config.lost_cycles_max_per_window as i64,
            config.lost_cycles_window_s,
        )?;
        let next_clock_s = if adapter.clock_period_s().is_some() {
            f64::NEG_INFINITY
        } else {
            f64::INFINITY
        };
        Ok(HostCore {
            health_period_s,
            n,
            lower,
            upper,
            max_fe,
            max_dq,
            stop_decel: config.stop_deceleration_rad_s2.clone(),
            zeros: [0.0; MAX_JOINTS],
            lifecycle: None,
            lifecycle_order: LifecycleOrder::new(),
            lifecycle_rx_s: f64::NEG_INFINITY,
            io: None,
            io_rx_s: f64::NEG_INFINITY,
            reset_wanted: false,
            current_zero,
            feedback: None,
            last_cycle_rx_s: f64::NEG_INFINITY,
            last_counter: None,
            cycle: 0,
            pending: None,
            request_sent: None,
            next_heartbeat_s: f64::NEG_INFINITY,
            next_clock_s,
            next_health_s: f64::NEG_INFINITY,
            last_sent_q: None,
            last_sent_dq: None,
            last_forwarded_q: None,
            last_forward: None,
            hold_q: None,
            holding: false,
            ramp: None,
            bus: BusErrors::new(config.bus_error_limit as i64, config.bus_error_window_s),
            lost,
            standstill: StandstillMonitor::new(
                config.standstill_band_rad,
                config.standstill_settle_s,
                config.standstill_confirm_cycles as i64,
            ),
            speed,
            plausibility: FeedbackPlausibility::new(
                config.feedback_max_joint_speed_rad_s,
                DEFAULT_TOLERANCE_RAD,
            ),
            window: StateWindowBuilder::new(config.state_window_s),
            notes: Notes::new(),
            last_now: f64::NEG_INFINITY,
            rejected: [0; REJECT_REASONS.len()],
            cycles: 0,
            forwarded: 0,
            coasted: 0,
            held: 0,
            ramped: 0,
            unanswered: 0,
            bad_inputs: 0,
            config,
            adapter,
        })
    }

    // --- accessors ------------------------------------------------------------------------

    /// The settings the core was built with.
    pub fn config(&self) -> &CoreConfig {
        &self.config
    }

    /// The newest complete cycle (waiting for, or given, its answer).
    pub fn pending(&self) -> Option<&Cycle> {
        self.pending.as_ref()
    }

    /// The newest cycle's number (JointState.cycle), None before the first.
    pub fn pending_cycle(&self) -> Option<i64> {
        self.pending.map(|p| p.cycle)
    }

    /// How the newest cycle was answered ([`Answer::None`] before the first, or unanswered).
    pub fn pending_answer(&self) -> Answer {
        self.pending.map_or(Answer::None, |p| p.answer)
    }

    /// Commands rejected for `reason` (one of [`REJECT_REASONS`]; 0 for another string).
    pub fn rejected_for(&self, reason: &str) -> u64 {
        REJECT_REASONS
            .iter()
            .position(|r| *r == reason)
            .map_or(0, |k| self.rejected[k])
    }

    /// The notes since the last call, oldest first: (level 10 debug, 20 info, 30 warning,
    /// 40 error; key; message). Rate-limited per key (one per [`NOTE_PERIOD_S`]; the next
    /// says how many were held back) and bounded ([`NOTE_QUEUE`]; a last note says how many
    /// were dropped).
    pub fn take_notes(&mut self) -> Vec<(u8, String, String)> {
        self.notes.take()
    }

    // --- inputs from zenoh ----------------------------------------------------------------

    /// A Lifecycle payload (JSON) from the gateway. A bad one is counted (`bad_inputs`); an
    /// older or conflicting one is dropped (`lifecycle_order`); FAULT → STOPPED is the
    /// operator's reset, sent to a faulted controller on the next tick.
    pub fn on_lifecycle(&mut self, payload: &[u8], now: f64) {
        self.last_now = now;
        let msg = match LifecycleMsg::from_bytes(payload) {
            Ok(msg) => msg,
            Err(exc) => {
                self.bad_inputs += 1;
                self.notes.note(WARNING, "lifecycle", now, || {
                    format!("bad lifecycle message: {exc}")
                });
                return;
            }
        };
        let previous = self.lifecycle;
        let incoming = LifecycleIn {
            state: msg.state,
            seq: msg.seq,
            stamp_s: msg.stamp_s,
        };
        if let Some(dropped) = self.lifecycle_order.admit(&msg) {
            let key = match dropped {
                "out_of_order" => "lifecycle_out_of_order",
                "conflicting" => "lifecycle_conflicting",
                _ => "lifecycle_dropped",
            };
            self.notes.note(WARNING, key, now, || {
                let (seq, state) = match previous {
                    Some(p) => (p.seq.to_string(), p.state.name()),
                    None => ("-".to_string(), "-"),
                };
                format!(
                    "lifecycle message dropped ({dropped}): seq {} {} after seq {seq} {state}",
                    incoming.seq,
                    incoming.state.name()
                )
            });
            return;
        }
        if let Some(p) = previous {
            if p.state == Lifecycle::Fault && incoming.state == Lifecycle::Stopped {
                self.reset_wanted = true; // the operator's reset reached the gateway
            }
        }
        self.lifecycle = Some(incoming);
        self.lifecycle_rx_s = now;
    }

    /// An IoState payload from the Modbus driver (a bad one is counted in `bad_inputs`).
    pub fn on_io(&mut self, payload: &[u8], now: f64) {
        self.last_now = now;
        match IoState::from_bytes(payload) {
            Ok(msg) => {
                self.io = Some(IoIn {
                    stamp_s: msg.stamp_s,
                    enabling: msg.enabling,
                    estop_ok: msg.estop_ok,
                });
                self.io_rx_s = now;
            }
            Err(exc) => {
                self.bad_inputs += 1;
                self.notes
                    .note(WARNING, "io", now, || format!("bad IoState message: {exc}"));
            }
        }
    }

    /// Decide on one JointCommand: forward it, hold the cycle it was for, or neither. The
    /// frames to send (the forwarded command, or the hold/ramp answering its cycle) are
    /// appended to `out`.
    pub fn on_command(&mut self, payload: &[u8], now: f64, out: &mut Vec<Frame>) -> CommandOutcome {
        self.last_now = now;
        let cmd = match JointCommand::from_bytes(payload) {
            Ok(cmd) => cmd,
            Err(exc) => {
                self.reject_with("bad_message", now, || exc.to_string());
                return CommandOutcome {
                    answer: Answer::None,
                    command: None,
                };
            }
        };
        let cmd_cycle = cmd.cycle;
        let stamps = CommandStamps {
            cycle: cmd_cycle,
            state_stamp_s: cmd.state_stamp_s,
            sent_stamp_s: cmd.sent_stamp_s,
            state_rx_stamp_s: cmd.state_rx_stamp_s,
        };
        let (q_cmd, dq_cmd) = (cmd.q_cmd_rad(), cmd.dq_cmd_rad_s());
        let mut problem = self.check_command(cmd_cycle, cmd.state_stamp_s, q_cmd, dq_cmd, now);
        if problem.is_none() {
            if let Some(pending) = self.pending {
                let mark = out.len();
                if let Err(exc) =
                    self.adapter
                        .command_frames(pending.counter, q_cmd, dq_cmd, false, out)
                {
                    out.truncate(mark);
                    problem = Some(Problem::Frame(exc));
                }
            }
        }
        if let Some(problem) = problem {
            let reason = problem.reason();
            self.reject(&problem, now);
            if let Some(pending) = self.pending {
                let mine = cmd_cycle == (pending.cycle & 0xFFFF_FFFF);
                if mine && !pending.answered() && (reason == "stale" || reason == "out_of_range") {
                    self.hold(now, out); // no better answer comes
                    self.record_lost(now);
                    let answer = match self.pending_answer() {
                        Answer::None => Answer::Hold,
                        answer => answer,
                    };
                    return CommandOutcome {
                        answer,
                        command: Some(stamps),
                    };
                }
            }
            return CommandOutcome {
                answer: Answer::None,
                command: Some(stamps),
            };
        }
        let Some(pending) = self.pending.as_mut() else {
            return CommandOutcome {
                answer: Answer::None,
                command: Some(stamps),
            }; // unreachable
        };
        pending.answer = Answer::Command;
        let (cycle, stamp_s) = (pending.cycle, pending.stamp_s);
        self.forwarded += 1;
        self.lost.record(false, now);
        let n = self.n;
        let mut q = [0.0; MAX_JOINTS];
        let mut dq = [0.0; MAX_JOINTS];
        q[..n].copy_from_slice(q_cmd);
        dq[..n].copy_from_slice(dq_cmd);
        self.last_sent_q = Some(q);
        self.last_sent_dq = Some(dq);
        self.last_forwarded_q = Some(q);
        let period_s = self.feedback.map_or(0.0, |fb| fb.period_s);
        self.last_forward = Some(LastForward {
            stamp_s: cmd.state_stamp_s.min(stamp_s),
            cycle,
            q,
            dq,
            period_s,
        });
        self.holding = false;
        self.ramp = None;
        CommandOutcome {
            answer: Answer::Command,
            command: Some(stamps),
        }
    }

    // --- input from CAN -------------------------------------------------------------------

    /// Take one received frame. A frame that completes a cycle fills `state` with its
    /// JointState (and `window` with a StateWindow when one closes); a blocked cycle's hold
    /// goes into `out` at once.
    pub fn on_frame(
        &mut self,
        frame: &Frame,
        now: f64,
        out: &mut Vec<Frame>,
        state: &mut Vec<u8>,
        window: &mut Vec<u8>,
    ) -> FrameOutcome {
        self.last_now = now;
        if frame.len as usize > frame.data.len() {
            // not a frame from_wire makes: nothing in it can be read
            self.notes.note(WARNING, "frame", now, || {
                format!("CAN: a frame of {} data bytes dropped", frame.len)
            });
            return FrameOutcome::default();
        }
        if frame.error {
            if let Some(fault) = self.bus.on_error_frame(frame, now) {
                self.notes.note(ERROR, "bus", now, || {
                    format!("CAN bus fault: {fault}; holding, brakes")
                });
            }
        }
        let dropped = {
            let s = self.adapter.stats();
            s.bad_frames + s.incomplete_cycles + s.corrupt_cycles
        };
        match self.adapter.feed(frame, now) {
            Some(fb) => self.on_cycle(fb, now, out, state, window),
            None => {
                let s = self.adapter.stats();
                if s.bad_frames + s.incomplete_cycles + s.corrupt_cycles != dropped {
                    let adapter = &self.adapter;
                    self.notes.note(WARNING, "frame", now, || {
                        format!("CAN: {}", adapter.stats().last_error)
                    });
                }
                FrameOutcome::default()
            }
        }
    }

    /// Wire counter → monotonically increasing cycle number; None for a repeated counter.
    fn widen(&mut self, counter: u32) -> Option<i64> {
        match self.last_counter {
            None => self.cycle = counter as i64,
            Some(last) => {
                let modulus = self.adapter.counter_modulus().max(1) as i64;
                let delta = (counter as i64 - last as i64).rem_euclid(modulus);
                if delta == 0 {
                    return None;
                }
                self.cycle += delta;
            }
        }
        self.last_counter = Some(counter);
        Some(self.cycle)
    }

    fn on_cycle(
        &mut self,
        fb: Feedback,
        now: f64,
        out: &mut Vec<Frame>,
        state: &mut Vec<u8>,
        window: &mut Vec<u8>,
    ) -> FrameOutcome {
        let n = self.n;
        if fb.n != n {
            self.notes.note(ERROR, "frame", now, || {
                format!(
                    "CAN: a cycle of {} joints from the adapter, expected {n}; dropped",
                    fb.n
                )
            });
            return FrameOutcome::default();
        }
        let Some(cycle) = self.widen(fb.counter) else {
            self.notes.note(WARNING, "dup", now, || {
                format!("controller repeated cycle {}", fb.counter)
            });
            return FrameOutcome::default();
        };
        if let Some(implausible) = self.plausibility.check(cycle, fb.q(), fb.period_s) {
            self.notes.note(ERROR, "implausible", now, || {
                format!("CAN: cycle dropped, {implausible}")
            });
            return FrameOutcome::default();
        }
        let previous = self.pending;
        if let Some(p) = previous {
            if !p.answered() {
                self.unanswered += 1;
                self.notes.note(WARNING, "unanswered", now, || {
                    format!(
                        "cycle {} got no answer before cycle {cycle} arrived",
                        p.cycle
                    )
                });
            }
        }
        self.cycles += 1;
        self.bus.on_cycle();
        self.feedback = Some(fb);
        self.last_cycle_rx_s = now;
        self.current_zero.update(fb.current(), fb.servo_power);
        if !fb.controller_state.servoing() {
            // On its brakes the arm is where it is: the next hold starts from there.
            self.holding = false;
            self.last_forwarded_q = None;
            self.last_forward = None;
            self.ramp = None;
        }
        // a lock-step controller waits for the answer; a real one starts its next cycle
        let mut budget_s = self.command_age_limit_s();
        if self.config.lockstep_answer_wait_s == 0.0 && fb.period_s > 0.0 {
            budget_s = budget_s.min(self.config.answer_by_period_fraction * fb.period_s);
        }
        self.pending = Some(Cycle {
            cycle,
            counter: fb.counter,
            stamp_s: now,
            answer_by_s: now + budget_s,
            q_rad: fb.q,
            n,
            answer: Answer::None,
        });
        self.monitor_speed(&fb, cycle, now);

        let q_cmd = self.last_sent_q.unwrap_or(fb.q);
        let dq_cmd = self.last_sent_dq.unwrap_or(self.zeros);
        let mut flags = 0u8;
        if fb.estop {
            flags |= FLAG_ESTOP;
        }
        if fb.servo_power {
            flags |= FLAG_SERVO_POWER;
        }
        if let Some(p) = previous {
            if p.cycle == cycle - 1 {
                if p.answer == Answer::Coast {
                    flags |= FLAG_PREV_COAST;
                } else if p.answer != Answer::Command {
                    flags |= FLAG_PREV_HOLD; // a hold, or none (the controller froze)
                }
            }
        }
        let mut current = [0.0; MAX_JOINTS];
        self.current_zero.correct(fb.current(), &mut current[..n]);
        // n is a joint count (checked at construction) and every slice has n values: packs
        let packed = JointState::pack(
            state,
            cycle,
            now,
            fb.controller_state as u8,
            flags,
            fb.period_s,
            fb.q(),
            fb.dq(),
            &current[..n],
            &q_cmd[..n],
            &dq_cmd[..n],
        )
        .is_ok();
        if self.blocked(now).is_some() {
            self.hold(now, out);
            self.lost.record(false, now);
        }
        if self.wants_servo(now) {
            self.watch_standstill(&fb, cycle, now);
        } else {
            self.clear_latched(now);
        }
        let key = (
            fb.controller_state as i64,
            (flags & (FLAG_ESTOP | FLAG_SERVO_POWER)) as i64,
        );
        if !packed {
            return FrameOutcome::default();
        }
        let window_closed = self.window.add(fb.q(), fb.dq(), key, state, now, window);
        FrameOutcome {
            state: true,
            window: window_closed,
        }
    }

    /// Hand guiding's speed from this cycle's measured positions, while the lifecycle
    /// teaches or replays and the controller servos; anything else resets the monitor (and
    /// clears a trip: the gateway has left the state the trip stopped).
    fn monitor_speed(&mut self, fb: &Feedback, cycle: i64, now: f64) {
        let lc = self.lifecycle;
        let applies = lc.is_some_and(|lc| {
            MONITORED.contains(&lc.state)
                && fresh(
                    lc.stamp_s,
                    self.lifecycle_rx_s,
                    now,
                    self.config.lifecycle_timeout_s,
                )
        });
        let Some(monitor) = self.speed.as_mut() else {
            return;
        };
        if !applies {
            if monitor.trip.is_some() {
                self.notes.always(INFO, "speed", || {
                    format!(
                        "speed monitor cleared: lifecycle {}",
                        lc.map_or("None", |l| l.state.name())
                    )
                });
            }
            monitor.reset();
            return;
        }
        if !fb.controller_state.servoing() || fb.period_s <= 0.0 {
            monitor.gap();
            return;
        }
        let tripped = monitor.trip.is_some();
        monitor.update(cycle, fb.q(), fb.period_s);
        if !tripped {
            if let Some(trip) = monitor.trip.as_ref() {
                self.notes.note(ERROR, "speed", now, || {
                    format!("speed monitor: {}; holding", trip.message())
                });
            }
        }
    }

    // --- time -----------------------------------------------------------------------------

    /// Deadline answers, servo requests, heartbeats and (host-clocked links) the cycle's
    /// clock frames due at `now`, appended to `out`.
    pub fn on_tick(&mut self, now: f64, out: &mut Vec<Frame>) {
        self.last_now = now;
        if let Some(pending) = self.pending {
            if !pending.answered() && now >= pending.answer_by_s {
                let allowed = self.blocked(now).is_none();
                if !self.coast(now, out) {
                    self.hold(now, out);
                }
                if allowed {
                    self.record_lost(now);
                }
            }
        }
        let (desired, waits_for_zero) = self.desire(now);
        if waits_for_zero {
            let zero = &self.current_zero;
            self.notes.note(INFO, "zero", now, || {
                format!(
                    "servo on waits for the current sensors' zero ({} of {} cycles with the servo power off)",
                    zero.samples, zero.window
                )
            });
        }
        let heartbeat_due = now >= self.next_heartbeat_s;
        if heartbeat_due {
            out.push(self.adapter.heartbeat_frame());
            self.next_heartbeat_s =
                next_tick(self.next_heartbeat_s, self.config.heartbeat_period_s, now);
        }
        if Some(desired) != self.request_sent || heartbeat_due {
            if desired == HostRequest::ServoOn && self.request_sent != Some(desired) {
                // A new servo-on period: nothing forwarded in it yet.
                self.holding = false;
                self.last_forwarded_q = None;
                self.last_forward = None;
            }
            if Some(desired) != self.request_sent {
                self.notes.always(INFO, "request", || {
                    format!("requesting {} from the controller", desired.name())
                });
            }
            self.adapter.request_frames(desired, out);
            self.request_sent = Some(desired);
        }
        if self.reset_wanted {
            self.reset_wanted = false;
            if let Some(fb) = self.feedback {
                if fb.controller_state == ControllerState::Fault {
                    self.notes.always(INFO, "reset", || {
                        format!(
                            "operator reset: asking the controller to leave FAULT ({})",
                            fb.fault
                        )
                    });
                    self.adapter.request_frames(HostRequest::ResetFault, out);
                    self.request_sent = Some(HostRequest::ResetFault); // BRAKE follows next pass
                }
            }
        }
        if let Some(period) = self.adapter.clock_period_s() {
            if now >= self.next_clock_s {
                // Last: the answers and requests above take effect at this cycle's start.
                self.adapter.clock_frames(out);
                self.next_clock_s = next_tick(self.next_clock_s, period, now);
            }
        }
    }

    /// The earliest time [`HostCore::on_tick`] has something due (an answer, a heartbeat, a
    /// clock frame) [s]; -inf when a reset waits. A change of request (a lifecycle message)
    /// arrives through a call of its own; the loop also wakes for those at least every few
    /// milliseconds.
    pub fn next_tick_s(&self) -> f64 {
        if self.reset_wanted {
            return f64::NEG_INFINITY;
        }
        let mut due = self.next_heartbeat_s.min(self.next_clock_s);
        if let Some(p) = self.pending {
            if !p.answered() {
                due = due.min(p.answer_by_s);
            }
        }
        due
    }

    /// True once per health period (and then schedules the next).
    pub fn health_due(&mut self, now: f64) -> bool {
        if now < self.next_health_s {
            return false;
        }
        self.next_health_s = next_tick(self.next_health_s, self.health_period_s, now);
        true
    }

    /// BRAKE, then a hold for the cycle still waiting for its answer (on exit); on a
    /// host-clocked link, then the cycle start that makes them take effect.
    pub fn closing_frames(&mut self, out: &mut Vec<Frame>) {
        self.adapter.request_frames(HostRequest::Brake, out);
        self.request_sent = Some(HostRequest::Brake);
        if let Some(pending) = self.pending {
            let mark = out.len();
            if let Err(exc) = self.hold_frames(&pending, out) {
                out.truncate(mark);
                let now = self.last_now;
                self.notes.note(ERROR, "hold", now, || {
                    format!("cannot build a hold set on exit: {exc}")
                });
            }
        }
        if self.adapter.clock_period_s().is_some() {
            // A host-clocked cycle's frames take effect at its next SYNC: without one the
            // BRAKE would wait for the drives' heartbeat watch (120 ms and 13-22 mm at
            // 120-220 mm/s on the virtual CiA 402 drives, 2026-11-28).
            self.adapter.clock_frames(out);
        }
    }

    // --- decisions ------------------------------------------------------------------------

    /// The lifecycle, fresh at `now`.
    fn fresh_lifecycle(&self, now: f64) -> Option<LifecycleIn> {
        self.lifecycle.filter(|lc| {
            fresh(
                lc.stamp_s,
                self.lifecycle_rx_s,
                now,
                self.config.lifecycle_timeout_s,
            )
        })
    }

    /// What the power stage should be asked for now.
    pub fn desired_request(&self, now: f64) -> HostRequest {
        self.desire(now).0
    }

    /// The request, and whether it is BRAKE only because the current sensors' zero is still
    /// being measured (the first SERVO_ON waits for it).
    fn desire(&self, now: f64) -> (HostRequest, bool) {
        let Some(lc) = self.fresh_lifecycle(now) else {
            return (HostRequest::Brake, false);
        };
        if self.standstill.trip.is_some() {
            return (HostRequest::Brake, false); // the drives do not hold the arm: nothing else is left
        }
        if self.speed.as_ref().is_some_and(|s| s.trip.is_some()) {
            // A hand that outran the limit fights a rigid hold until the controller faults on
            // its following error and cuts the power: the arm is then free for the brakes'
            // engagement time. The brakes at once instead.
            return (HostRequest::Brake, false);
        }
        if self.bus.fault.is_some() {
            return (HostRequest::Brake, false); // stopped until the operator re-arms (bus_errors.rs)
        }
        if lc.state == Lifecycle::Stopped && (self.ramp.is_some() || self.ramp_due(now)) {
            return (HostRequest::ServoOn, false); // stop category 1: the brakes once the ramp has ended
        }
        if lc.state == Lifecycle::Ready || COMMANDING.contains(&lc.state) {
            if !self.current_zero.ready {
                return (HostRequest::Brake, true);
            }
            return (HostRequest::ServoOn, false);
        }
        (HostRequest::Brake, false)
    }

    /// The controller link is up: a complete cycle arrived within `controller_timeout_s`
    /// (plus `lockstep_answer_wait_s`: a lock-step controller's next cycle waits for our
    /// answer to the last one).
    pub fn link_ok(&self, now: f64) -> bool {
        let allowed_s = self.config.controller_timeout_s + self.config.lockstep_answer_wait_s;
        (now - self.last_cycle_rx_s) < allowed_s
    }

    /// The reason forwarding is not allowed right now (one of [`REJECT_REASONS`]), or None
    /// if it is.
    pub fn blocked(&self, now: f64) -> Option<&'static str> {
        match self.fresh_lifecycle(now) {
            Some(lc) if COMMANDING.contains(&lc.state) => {}
            _ => return Some("blocked_lifecycle"),
        }
        match self.io {
            Some(io)
                if io.enabling
                    && io.estop_ok
                    && fresh(io.stamp_s, self.io_rx_s, now, self.config.io_timeout_s) => {}
            _ => return Some("blocked_enabling"),
        }
        match self.feedback {
            Some(fb) if fb.controller_state.servoing() && self.link_ok(now) => {}
            _ => return Some("blocked_controller"),
        }
        if self.speed.as_ref().is_some_and(|s| s.trip.is_some()) {
            return Some("blocked_speed");
        }
        if self.bus.fault.is_some() {
            return Some("blocked_bus");
        }
        if self.lost.trip.is_some() {
            return Some("blocked_lost");
        }
        None
    }

    /// The pending cycle was lost (lost_cycles.rs): count it, and say so if it trips.
    fn record_lost(&mut self, now: f64) {
        if let Some(trip) = self.lost.record(true, now) {
            self.notes.note(ERROR, "lost", now, || {
                format!("lost command cycles: {}; stopping the arm", trip.message())
            });
        }
    }

    /// Why the command (`cycle`, `state_stamp_s`, `q`, `dq`) must not be forwarded, or None.
    fn check_command(
        &self,
        cycle: i64,
        state_stamp_s: f64,
        q: &[f64],
        dq: &[f64],
        now: f64,
    ) -> Option<Problem> {
        let n = self.n;
        if q.len() != n || dq.len() != n {
            return Some(Problem::Joints {
                n: q.len(),
                expected: n,
            });
        }
        if let Some(reason) = self.blocked(now) {
            return Some(Problem::Blocked { reason, cycle });
        }
        let pending = match self.pending {
            Some(p) if cycle == (p.cycle & 0xFFFF_FFFF) => p,
            other => {
                return Some(Problem::NotCurrent {
                    cycle,
                    current: other.map(|p| p.cycle),
                })
            }
        };
        if pending.answered() {
            return Some(Problem::Answered { cycle });
        }
        let age_s = now - state_stamp_s.min(pending.stamp_s);
        if age_s > self.command_age_limit_s() {
            return Some(Problem::Stale { cycle, age_s });
        }
        // the worst joint, as numpy's argmax (the first of equals) picks it
        let worst = |value: &dyn Fn(usize) -> f64| -> (usize, f64) {
            let mut best = (0, value(0));
            for k in 1..n {
                let v = value(k);
                if v > best.1 {
                    best = (k, v);
                }
            }
            best
        };
        let q_meas = pending.q();
        if (0..n).any(|k| (q[k] - q_meas[k]).abs() > self.max_fe[k]) {
            let (k, _) = worst(&|k| (q[k] - q_meas[k]).abs() - self.max_fe[k]);
            return Some(Problem::FollowingError {
                k,
                error: (q[k] - q_meas[k]).abs(),
                limit: self.max_fe[k],
            });
        }
        let outside = |k: usize| (self.lower[k] - q[k]).max(q[k] - self.upper[k]);
        if (0..n).any(|k| outside(k) > 0.0) {
            let (k, _) = worst(&outside);
            return Some(Problem::OutsideLimits {
                k,
                q: q[k],
                lower: self.lower[k],
                upper: self.upper[k],
            });
        }
        if (0..n).any(|k| dq[k].abs() > self.max_dq[k]) {
            let (k, _) = worst(&|k| dq[k].abs() - self.max_dq[k]);
            return Some(Problem::Velocity {
                k,
                speed: dq[k].abs(),
                limit: self.max_dq[k],
            });
        }
        None
    }

    /// The hold set for `pending` into `out`; holding begins (at the last forwarded command
    /// when it is within the following error of the measured position, else at the measured
    /// position) if it had not.
    fn hold_frames(&mut self, pending: &Cycle, out: &mut Vec<Frame>) -> Result<(), FrameError> {
        let n = self.n;
        if !self.holding {
            let q_meas = pending.q_rad;
            let near = |last: &[f64; MAX_JOINTS]| {
                (0..n).all(|k| (last[k] - q_meas[k]).abs() <= self.max_fe[k])
            };
            self.hold_q = Some(match self.last_forwarded_q {
                Some(last) if near(&last) => last,
                _ => q_meas,
            });
            self.holding = true;
        }
        let hold_q = self.hold_q.unwrap_or(pending.q_rad);
        self.adapter
            .command_frames(pending.counter, &hold_q[..n], &self.zeros[..n], true, out)
    }

    /// Forwarding is blocked by an ordinary stop, the drives to stay powered through it: the
    /// enabling device released, or the lifecycle gone to READY or STOPPED, with the
    /// lifecycle and I/O fresh, the e-stop chain closed, the controller servoing and no
    /// monitor tripped; or the lost-cycle rule tripped (lost_cycles.rs: only the command
    /// source failed). Anything else is a fault, held at once.
    fn controlled_stop(&self, now: f64) -> bool {
        let (Some(lc), Some(io), Some(fb)) = (self.lifecycle, self.io, self.feedback) else {
            return false;
        };
        let cfg = &self.config;
        if !(fresh(
            lc.stamp_s,
            self.lifecycle_rx_s,
            now,
            cfg.lifecycle_timeout_s,
        ) && fresh(io.stamp_s, self.io_rx_s, now, cfg.io_timeout_s)
            && io.estop_ok
            && fb.controller_state.servoing()
            && self.link_ok(now)
            && self.speed.as_ref().is_none_or(|s| s.trip.is_none())
            && self.standstill.trip.is_none()
            && self.bus.fault.is_none())
        {
            return false;
        }
        matches!(lc.state, Lifecycle::Ready | Lifecycle::Stopped)
            || (COMMANDING.contains(&lc.state) && (!io.enabling || self.lost.trip.is_some()))
    }

    /// A controlled stop is about to begin: the arm was commanded moving a moment ago and the
    /// stop is an ordinary one, so the next cycle starts a ramp ([`HostCore::ramp_for`]). The
    /// servo request is decided between cycles too: without this, the operator's stop
    /// arriving between two cycles asked for the brakes before the ramp could begin (the
    /// fault campaign's `operator_stop`: 135 mm/s to rest in 32 ms, not a ramp).
    fn ramp_due(&self, now: f64) -> bool {
        let (Some(last), Some(pending)) = (self.last_forward, self.pending) else {
            return false;
        };
        if self.holding || !any_nonzero(&last.dq[..self.n]) {
            return false;
        }
        let age = pending.cycle + 1 - last.cycle; // at the cycle the ramp would begin
        age <= RAMP_MAX_AGE_CYCLES && self.controlled_stop(now)
    }

    /// Whether the pending cycle belongs to a controlled stop: the one under way, or a new one
    /// (started here, in `self.ramp`) from the last forwarded command when a controlled stop
    /// begins while the arm was commanded; false (and a ramp under way ends where it got to)
    /// when the cycle is to be held.
    fn ramp_for(&mut self, pending: &Cycle, now: f64) -> bool {
        let n = self.n;
        if let Some(ramp) = self.ramp.as_ref() {
            if self.controlled_stop(now) {
                return true;
            }
            let mut q = [0.0; MAX_JOINTS];
            let mut dq = [0.0; MAX_JOINTS];
            ramp.at(pending.cycle, &mut q[..n], &mut dq[..n]); // a fault: hold where it is
            self.ramp = None;
            self.hold_q = Some(q);
            self.holding = true;
            return false;
        }
        let Some(last) = self.last_forward else {
            return false;
        };
        if self.holding || !self.controlled_stop(now) {
            return false;
        }
        let age = pending.cycle - last.cycle;
        if last.period_s <= 0.0
            || !(0..=RAMP_MAX_AGE_CYCLES).contains(&age)
            || !any_nonzero(&last.dq[..n])
        {
            return false;
        }
        // where the last command (or its coasting) has got to
        let mut q_now = [0.0; MAX_JOINTS];
        for ((q, &q0), &dq) in q_now.iter_mut().zip(&last.q).zip(&last.dq).take(n) {
            *q = q0 + dq * age as f64 * last.period_s;
        }
        let ramp = StopRamp::start(
            pending.cycle,
            &q_now[..n],
            &last.dq[..n],
            &self.stop_decel,
            last.period_s,
        );
        let duration_s = ramp.duration_s;
        self.ramp = Some(ramp);
        self.notes.note(INFO, "ramp", now, || {
            format!(
                "controlled stop: ramping to standstill in {:.0} ms",
                duration_s * 1e3
            )
        });
        true
    }

    /// Answer the pending cycle with the controlled stop's ramp while one runs, else with a
    /// hold set (none if the position cannot be encoded).
    fn hold(&mut self, now: f64, out: &mut Vec<Frame>) {
        let Some(pending) = self.pending else {
            return;
        };
        let n = self.n;
        if self.ramp_for(&pending, now) {
            let mut q = [0.0; MAX_JOINTS];
            let mut dq = [0.0; MAX_JOINTS];
            let done = match self.ramp.as_ref() {
                Some(ramp) => ramp.at(pending.cycle, &mut q[..n], &mut dq[..n]),
                None => true,
            };
            if !done {
                let mark = out.len();
                match self
                    .adapter
                    .command_frames(pending.counter, &q[..n], &dq[..n], false, out)
                {
                    Ok(()) => {
                        self.set_answer(Answer::Ramp);
                        self.ramped += 1;
                        self.last_sent_q = Some(q);
                        self.last_sent_dq = Some(dq);
                        return;
                    }
                    Err(exc) => {
                        out.truncate(mark);
                        self.notes.note(ERROR, "ramp", now, || {
                            format!("cannot send the ramp: {exc}; holding")
                        });
                    }
                }
            }
            self.ramp = None; // hold where it ended
            self.hold_q = Some(q);
            self.holding = true;
        }
        let mark = out.len();
        if let Err(exc) = self.hold_frames(&pending, out) {
            // measured q the protocol cannot carry: nothing to hold
            out.truncate(mark);
            self.notes.note(ERROR, "hold", now, || {
                format!("cannot build a hold set: {exc}")
            });
            return;
        }
        self.set_answer(Answer::Hold);
        self.held += 1;
        self.last_sent_q = self.hold_q;
        self.last_sent_dq = Some(self.zeros);
    }

    fn set_answer(&mut self, answer: Answer) {
        if let Some(p) = self.pending.as_mut() {
            p.answer = answer;
        }
    }

    /// How old a command may be when it is forwarded [s]: `deadline_s`, or against a lock-step
    /// virtual controller (which waits for the answer) `lockstep_answer_wait_s`.
    fn command_age_limit_s(&self) -> f64 {
        if self.config.lockstep_answer_wait_s > 0.0 {
            self.config.lockstep_answer_wait_s
        } else {
            self.config.deadline_s
        }
    }

    /// Answer a cycle whose command is late with the last forwarded command, moved on by its
    /// own velocity, as long as that command answered one of the `coast_max_cycles` cycles
    /// before this one (and, against a controller whose cycles stalled, is at most
    /// `deadline_s` plus one period more than that many old), and moved on stays within the
    /// following error and limits a forwarded command must meet; false if coasting is not
    /// allowed. A hold after it keeps the coasted position: the controller was sent there.
    ///
    /// The bound counts the periods the coast spans: the command of the cycle before is one
    /// period plus the answer deadline old when it coasts, 12 ms at LTC-1's 8 ms, so a bound
    /// of `deadline_s` (10 ms) alone let nothing coast at that rate and every late command
    /// became a hold, a dead stop of an arm the hand was moving (0.2 rad/s to 0 within one
    /// cycle on J2, 54 A, in the stack's release test, 2026-11-29). The age bound stays: a
    /// controller whose cycles stalled gets a hold, not a command extrapolated over the
    /// stall.
    fn coast(&mut self, now: f64, out: &mut Vec<Frame>) -> bool {
        let (Some(pending), Some(last)) = (self.pending, self.last_forward) else {
            return false;
        };
        let max_cycles = self.config.coast_max_cycles;
        if self.config.lost_cycle_answer == LostCycleAnswer::Hold
            || self.holding
            || pending.cycle - last.cycle > max_cycles
            || now - last.stamp_s
                > self.command_age_limit_s() + (max_cycles + 1) as f64 * last.period_s
        {
            return false;
        }
        let n = self.n;
        let mut q_coast = [0.0; MAX_JOINTS];
        let age = (pending.cycle - last.cycle) as f64;
        for ((q, &q0), &dq) in q_coast.iter_mut().zip(&last.q).zip(&last.dq).take(n) {
            *q = q0 + dq * age * last.period_s;
        }
        // what a forwarded command must meet: near the arm's measured position, in the limits
        if (0..n).any(|k| {
            (q_coast[k] - pending.q_rad[k]).abs() > self.max_fe[k]
                || q_coast[k] < self.lower[k]
                || q_coast[k] > self.upper[k]
        }) {
            return false;
        }
        let mark = out.len();
        if self
            .adapter
            .command_frames(pending.counter, &q_coast[..n], &last.dq[..n], false, out)
            .is_err()
        {
            out.truncate(mark);
            return false;
        }
        self.set_answer(Answer::Coast);
        self.coasted += 1;
        self.last_sent_q = Some(q_coast);
        self.last_sent_dq = Some(last.dq);
        self.last_forwarded_q = Some(q_coast); // a hold that follows does not pull the arm back
        true
    }

    /// The gateway's lifecycle, fresh, is one that keeps the drives powered.
    fn wants_servo(&self, now: f64) -> bool {
        self.fresh_lifecycle(now)
            .is_some_and(|lc| lc.state == Lifecycle::Ready || COMMANDING.contains(&lc.state))
    }

    /// The cell is stopped (STOPPED, FAULT, or a silent gateway): the standstill and
    /// lost-cycle trips clear, and a bus fault once the bus has worked again
    /// (bus_errors.rs); a re-arm is still the operator's.
    fn clear_latched(&mut self, now: f64) {
        if self.bus.fault.is_some() && self.bus.clear(now) {
            self.notes.always(INFO, "bus", || {
                "CAN bus fault cleared: the bus works again and the cell is stopped".to_string()
            });
        }
        let state = self.lifecycle.map_or("None", |lc| lc.state.name());
        if self.standstill.trip.is_some() {
            self.notes.always(INFO, "standstill", || {
                format!("standstill monitor cleared: lifecycle {state}")
            });
        }
        self.standstill.reset();
        if self.lost.trip.is_some() {
            self.notes.always(INFO, "lost", || {
                format!("lost cycles cleared: lifecycle {state}")
            });
        }
        self.lost.reset();
    }

    /// Monitored standstill (stop_ramp.rs) while the driver holds with the servo on and the
    /// lifecycle wants the servo.
    fn watch_standstill(&mut self, fb: &Feedback, cycle: i64, now: f64) {
        let hold_q = match self.hold_q {
            Some(q) if self.holding && fb.controller_state.servoing() => q,
            _ => {
                self.standstill.idle();
                return;
            }
        };
        let monitor = &mut self.standstill;
        monitor.watch(&hold_q[..self.n], now);
        let tripped = monitor.trip.is_some();
        monitor.update(fb.q(), cycle, now);
        if !tripped {
            if let Some(trip) = monitor.trip.as_ref() {
                self.notes.note(ERROR, "standstill", now, || {
                    format!("standstill monitor: {}; brakes", trip.message())
                });
            }
        }
    }

    fn reject(&mut self, problem: &Problem, now: f64) {
        self.reject_with(problem.reason(), now, || problem.detail());
    }

    fn reject_with(&mut self, reason: &'static str, now: f64, detail: impl FnOnce() -> String) {
        if let Some(k) = REJECT_REASONS.iter().position(|r| *r == reason) {
            self.rejected[k] += 1;
        }
        let level = if reason.starts_with("blocked_") {
            INFO
        } else {
            WARNING
        };
        self.notes.note(level, reason, now, || {
            format!("JointCommand not forwarded ({reason}): {}", detail())
        });
    }

    // --- health ---------------------------------------------------------------------------

    /// The current zero's part of the health (current_zero.rs), and a warning when the fresh
    /// zero has drifted from the commissioning's.
    fn zero_health(&mut self, now: f64, h: &mut Map<String, Value>) {
        let zero = &self.current_zero;
        let noise = zero.noise_a();
        let drift = zero.drift_a();
        if let Some(d) = drift.as_ref() {
            if zero.drift_significant(Some(&noise)) {
                self.notes.note(WARNING, "zero-drift", now, || {
                    let rounded: Vec<f64> = d.iter().map(|&v| round_to(v, 4)).collect();
                    format!(
                        "the current sensors' zero measured now differs from the commissioning's by \
                         {rounded:?} A, more than noise explains: commission again (`leadthrough identify`)"
                    )
                });
            }
        }
        let zero = &self.current_zero;
        h.insert(
            "current_zero_a".into(),
            rounded(&zero.offset_a[..self.n], 4),
        );
        h.insert("current_zero_source".into(), Value::from(zero.source()));
        h.insert(
            "current_zero_samples".into(),
            Value::from(zero.samples as u64),
        );
        h.insert("current_zero_ready".into(), Value::from(zero.ready));
        h.insert(
            "current_zero_measured_a".into(),
            rounded(&zero.measured_a[..self.n], 4),
        );
        h.insert("current_zero_noise_a".into(), rounded(&noise, 5));
        h.insert(
            "current_zero_drift_a".into(),
            drift.map_or(Value::Null, |d| rounded(&d, 4)),
        );
    }

    /// The health message's entries (Python's `HostCore.health()`: the same keys and value
    /// types), then the adapter's own entries (a key the core has keeps the core's value).
    pub fn health(&mut self, now: f64) -> Map<String, Value> {
        self.last_now = now;
        let mut h = Map::new();
        let fb = self.feedback;
        let (bad_frames, incomplete_cycles, corrupt_cycles) = {
            let s = self.adapter.stats();
            (s.bad_frames, s.incomplete_cycles, s.corrupt_cycles)
        };
        let opt_str = |s: Option<String>| s.map_or(Value::Null, Value::from);
        h.insert(
            "controller_state".into(),
            fb.map_or(Value::Null, |f| Value::from(f.controller_state.name())),
        );
        h.insert(
            "controller_fault".into(),
            fb.map_or(Value::Null, |f| Value::from(f.fault)),
        );
        // the operator's reason for a FAULT: the adapter's words, else the fault's kind
        let faulted = fb.filter(|f| f.controller_state == ControllerState::Fault);
        h.insert(
            "controller_fault_text".into(),
            faulted.map_or(Value::Null, |f| {
                Value::from(self.adapter.fault_detail().unwrap_or(f.fault))
            }),
        );
        h.insert("link_ok".into(), Value::from(self.link_ok(now)));
        h.insert(
            "servo_request".into(),
            self.request_sent
                .map_or(Value::Null, |r| Value::from(r.name())),
        );
        h.insert("cycles".into(), Value::from(self.cycles));
        h.insert("forwarded".into(), Value::from(self.forwarded));
        h.insert("held".into(), Value::from(self.held));
        h.insert("ramped".into(), Value::from(self.ramped));
        h.insert(
            "standstill_trip".into(),
            opt_str(self.standstill.trip.as_ref().map(|t| t.message())),
        );
        h.insert("lost_cycles".into(), Value::from(self.lost.lost as u64));
        h.insert(
            "lost_cycles_trip".into(),
            opt_str(self.lost.trip.as_ref().map(|t| t.message())),
        );
        h.insert("coasted".into(), Value::from(self.coasted));
        h.insert("unanswered".into(), Value::from(self.unanswered));
        let mut rejected = Map::new();
        for (reason, count) in REJECT_REASONS.iter().zip(self.rejected) {
            rejected.insert((*reason).into(), Value::from(count));
        }
        h.insert("rejected".into(), Value::Object(rejected));
        h.insert("bad_frames".into(), Value::from(bad_frames));
        // frames of ids the protocol does not define: ignored, counted (the fuzz tests read it)
        h.insert(
            "unknown_frames".into(),
            Value::from(self.adapter.stats().unknown_frames),
        );
        h.insert(
            "implausible_cycles".into(),
            Value::from(self.plausibility.dropped),
        );
        h.insert("incomplete_cycles".into(), Value::from(incomplete_cycles));
        h.insert("corrupt_cycles".into(), Value::from(corrupt_cycles));
        h.insert("bad_inputs".into(), Value::from(self.bad_inputs));
        h.insert(
            "lifecycle_dropped".into(),
            Value::Object(self.lifecycle_order.dropped()),
        );
        match self.speed.as_ref() {
            None => {
                h.insert("speed_trip".into(), Value::Null);
                h.insert("speed_peak_m_s".into(), Value::Null);
            }
            Some(monitor) => {
                h.insert(
                    "speed_trip".into(),
                    opt_str(monitor.trip.as_ref().map(|t| t.message())),
                );
                h.insert(
                    "speed_peak_m_s".into(),
                    Value::from(round_to(monitor.peak_m_s, 4)),
                );
            }
        }
        for (k, v) in self.bus.health() {
            h.insert(k, v);
        }
        self.zero_health(now, &mut h);
        for (k, v) in self.adapter.health(now) {
            h.entry(k).or_insert(v);
        }
        h
    }
}
