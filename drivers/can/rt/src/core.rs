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

use crate::adapter::{Adapter, Feedback, HostRequest, MAX_JOINTS};
use crate::bus_errors::BusErrors;
use crate::current_zero::CurrentZero;
use crate::lifecycle::LifecycleOrder;
use crate::lost_cycles::LostCycles;
use crate::messages::Lifecycle;
use crate::plausibility::{FeedbackPlausibility, DEFAULT_TOLERANCE_RAD};
use crate::ramp_start::PathHistory;
use crate::speed_monitor::{SpeedMonitor, DEFAULT_CONFIRM, DEFAULT_WINDOW};
use crate::stop_ramp::{StandstillMonitor, StopRamp};
use crate::window::StateWindowBuilder;

pub use crate::core_config::{CoreConfig, LostCycleAnswer};
pub use crate::speed_monitor::KinematicChain;

mod answers;
mod can_input;
mod command_checks;
mod gates;
mod health;
mod monitors;
mod notes;
mod ticks;
mod zenoh_input;

use self::notes::Notes;
pub use self::notes::{DEBUG, ERROR, INFO, NOTE_PERIOD_S, NOTE_QUEUE, WARNING};

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
    /// the forwarded commands' path, for the velocity a ramp starts from (ramp_start.rs)
    path: PathHistory,
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
            path: PathHistory::new(),
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
}
