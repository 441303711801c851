//! The zenoh messages the compiled cycles read and write, bit-exact with
//! gateway/messages.py: the fixed little-endian binary layouts (a 4-byte magic naming the type,
//! a 1-byte layout version, then fields) of [`JointState`], [`JointCommand`], [`IoState`] and
//! [`StateWindow`], the `JointState.flags` bits and the gateway's [`Lifecycle`].
//!
//! Decoding checks what Python's `from_bytes` checks (magic, version, length, joint count,
//! every float finite) and names what was wrong in a [`MessageError`] worded like Python's.
//! Encoding and the per-cycle decoding ([`JointCommand`], [`IoState`]) never allocate: an
//! encoder writes into a caller's `Vec<u8>` whose capacity it keeps, a decoded command holds
//! fixed arrays. Stamps are CLOCK_MONOTONIC seconds, as in Python.
//!
//! The helpers at the end format numbers as Python's `repr` and `format(v, "g")` do, so the
//! messages of every ported module read as the Python driver's did.

pub use crate::ControllerState;
use crate::MAX_JOINTS;

/// Layout version of every binary message except [`JointCommand`].
pub const LAYOUT_VERSION: u8 = 1;

/// `JointState.flags`: the controller sees its e-stop input open.
pub const FLAG_ESTOP: u8 = 1;
/// `JointState.flags`: the drives are powered.
pub const FLAG_SERVO_POWER: u8 = 2;
/// `JointState.flags`: the previous cycle was answered with a hold (or not at all, which
/// freezes the controller's reference).
pub const FLAG_PREV_HOLD: u8 = 4;
/// `JointState.flags`: the previous cycle was answered by coasting on the last command.
pub const FLAG_PREV_COAST: u8 = 8;

/// A payload that is not the message it claims to be (gateway/errors.py MessageError); the
/// text names the message, the field and what is wrong, as Python's does.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct MessageError(pub String);

impl std::fmt::Display for MessageError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.0)
    }
}

impl std::error::Error for MessageError {}

/// The gateway's lifecycle (gateway/messages.py Lifecycle). STOPPED is the default and the
/// state every error path leads back to.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[repr(u8)]
pub enum Lifecycle {
    /// brakes on; nothing moves
    Stopped = 0,
    /// servo on, holding position; waiting for the enabling device
    Ready = 1,
    /// enabling device held; the control process's commands reach the robot
    Teaching = 2,
    /// an error stopped the robot; `reset` once the cause is gone
    Fault = 3,
    /// enabling device held; the control process plays an excitation plan
    Identifying = 4,
    /// enabling device held; the control process plays a taught program back
    Replaying = 5,
}

/// Every lifecycle state, in value order (Python's `tuple(Lifecycle)`).
pub const LIFECYCLE_STATES: [Lifecycle; 6] = [
    Lifecycle::Stopped,
    Lifecycle::Ready,
    Lifecycle::Teaching,
    Lifecycle::Fault,
    Lifecycle::Identifying,
    Lifecycle::Replaying,
];

/// Lifecycle states in which the control process's commands may reach the robot.
pub const COMMANDING: [Lifecycle; 3] = [
    Lifecycle::Teaching,
    Lifecycle::Identifying,
    Lifecycle::Replaying,
];

/// Lifecycle states in which the control process plays a plan.
pub const PLAYING: [Lifecycle; 2] = [Lifecycle::Identifying, Lifecycle::Replaying];

impl Lifecycle {
    /// The Python member name ("STOPPED" ...).
    pub fn name(self) -> &'static str {
        match self {
            Lifecycle::Stopped => "STOPPED",
            Lifecycle::Ready => "READY",
            Lifecycle::Teaching => "TEACHING",
            Lifecycle::Fault => "FAULT",
            Lifecycle::Identifying => "IDENTIFYING",
            Lifecycle::Replaying => "REPLAYING",
        }
    }

    /// The name on the wire of a lifecycle message ("stopped" ...).
    pub fn wire_name(self) -> &'static str {
        match self {
            Lifecycle::Stopped => "stopped",
            Lifecycle::Ready => "ready",
            Lifecycle::Teaching => "teaching",
            Lifecycle::Fault => "fault",
            Lifecycle::Identifying => "identifying",
            Lifecycle::Replaying => "replaying",
        }
    }

    /// The state of a member name ("TEACHING"), as Python's `Lifecycle[name]`.
    pub fn from_name(name: &str) -> Option<Lifecycle> {
        LIFECYCLE_STATES.iter().copied().find(|s| s.name() == name)
    }

    pub fn from_u8(v: u8) -> Option<Lifecycle> {
        LIFECYCLE_STATES.get(v as usize).copied()
    }

    /// One of [`COMMANDING`]: the control process's commands may reach the robot.
    pub fn commanding(self) -> bool {
        COMMANDING.contains(&self)
    }

    /// One of [`PLAYING`].
    pub fn playing(self) -> bool {
        PLAYING.contains(&self)
    }
}

// --- little-endian field access -------------------------------------------------------------

fn f64_at(data: &[u8], offset: usize) -> f64 {
    let mut b = [0u8; 8];
    b.copy_from_slice(&data[offset..offset + 8]);
    f64::from_le_bytes(b)
}

fn u32_at(data: &[u8], offset: usize) -> u32 {
    u32::from_le_bytes([
        data[offset],
        data[offset + 1],
        data[offset + 2],
        data[offset + 3],
    ])
}

fn put_f64s(out: &mut Vec<u8>, values: &[f64]) {
    for v in values {
        out.extend_from_slice(&v.to_le_bytes());
    }
}

/// gateway/messages.py `_check_header`: length at least `min_len`, the magic, the version.
fn check_header(
    data: &[u8],
    magic: &[u8; 4],
    what: &str,
    min_len: usize,
    version: u8,
) -> Result<(), MessageError> {
    if data.len() < min_len {
        return Err(MessageError(format!(
            "{what}: payload is {} bytes, shorter than its header",
            data.len()
        )));
    }
    if &data[..4] != magic {
        return Err(MessageError(format!(
            "{what}: magic {} is not {}",
            py_bytes_repr(&data[..4]),
            py_bytes_repr(magic)
        )));
    }
    if data[4] != version {
        return Err(MessageError(format!(
            "{what}: layout version {} unsupported (want {version})",
            data[4]
        )));
    }
    Ok(())
}

/// gateway/messages.py `_finite`: the first value that is not finite, named.
fn check_finite(name: &str, values: &[f64]) -> Result<(), MessageError> {
    match values.iter().position(|v| !v.is_finite()) {
        None => Ok(()),
        Some(bad) => Err(MessageError(format!(
            "{name}[{bad}] is {}; every value must be finite",
            py_repr(values[bad])
        ))),
    }
}

// --- JointState -----------------------------------------------------------------------------

/// One controller cycle of joint feedback as the CAN driver publishes it (gateway/messages.py
/// JointState). The driver only encodes it ([`JointState::pack`]); the decoded form, with its
/// vectors, is for tests and tools.
#[derive(Clone, Debug, PartialEq)]
pub struct JointState {
    /// controller cycle counter (32 bits on the wire, widened by the driver)
    pub cycle: i64,
    /// driver monotonic time when the full cycle had arrived [s]
    pub stamp_s: f64,
    pub controller_state: ControllerState,
    /// FLAG_* bits
    pub flags: u8,
    /// measured joint positions [rad]
    pub q_rad: Vec<f64>,
    /// measured joint velocities [rad/s]
    pub dq_rad_s: Vec<f64>,
    /// motor currents less the sensors' zero [A]
    pub current_a: Vec<f64>,
    /// the position command last sent to the controller [rad]
    pub q_cmd_rad: Vec<f64>,
    /// the velocity command last sent [rad/s]
    pub dq_cmd_rad_s: Vec<f64>,
    /// the controller's command cycle [s]; 0 = not reported
    pub cycle_period_s: f64,
}

impl JointState {
    pub const MAGIC: &'static [u8; 4] = b"LTJS";
    /// `<4sBBIdBBd`: magic, version, n, cycle, stamp, controller state, flags, period [bytes].
    pub const HEAD_SIZE: usize = 28;

    /// Bytes of a JointState of `n` joints.
    pub fn size(n: usize) -> usize {
        Self::HEAD_SIZE + 5 * n * 8
    }

    /// Number of joints.
    pub fn n(&self) -> usize {
        self.q_rad.len()
    }

    /// The wire bytes of a JointState into `out` (cleared first), straight from the slices
    /// (the CAN driver's hot path; the arguments after `out` are Python's `JointState.pack`'s,
    /// `controller_state` its value as there). `out` is not reallocated when its capacity
    /// holds [`JointState::size`]`(n)` bytes: reserve that once. The caller guarantees finite
    /// values (decoded frames, sent commands); Err if the five slices differ in length or
    /// their length is no joint count (1..16), and then `out` is left empty.
    #[allow(clippy::too_many_arguments)]
    pub fn pack(
        out: &mut Vec<u8>,
        cycle: i64,
        stamp_s: f64,
        controller_state: u8,
        flags: u8,
        cycle_period_s: f64,
        q_rad: &[f64],
        dq_rad_s: &[f64],
        current_a: &[f64],
        q_cmd_rad: &[f64],
        dq_cmd_rad_s: &[f64],
    ) -> Result<(), MessageError> {
        out.clear();
        let n = q_rad.len();
        if [dq_rad_s, current_a, q_cmd_rad, dq_cmd_rad_s]
            .iter()
            .any(|v| v.len() != n)
            || !(1..=MAX_JOINTS).contains(&n)
        {
            return Err(MessageError(format!(
                "JointState: {n}, {}, {}, {}, {} values; each must be 1..{MAX_JOINTS} joints",
                dq_rad_s.len(),
                current_a.len(),
                q_cmd_rad.len(),
                dq_cmd_rad_s.len()
            )));
        }
        out.extend_from_slice(Self::MAGIC);
        out.push(LAYOUT_VERSION);
        out.push(n as u8);
        out.extend_from_slice(&((cycle & 0xFFFF_FFFF) as u32).to_le_bytes());
        out.extend_from_slice(&stamp_s.to_le_bytes());
        out.push(controller_state);
        out.push(flags);
        out.extend_from_slice(&cycle_period_s.to_le_bytes());
        for values in [q_rad, dq_rad_s, current_a, q_cmd_rad, dq_cmd_rad_s] {
            put_f64s(out, values);
        }
        Ok(())
    }

    /// The wire bytes (allocates; tests and tools).
    pub fn to_bytes(&self) -> Result<Vec<u8>, MessageError> {
        let mut out = Vec::with_capacity(Self::size(self.n()));
        Self::pack(
            &mut out,
            self.cycle,
            self.stamp_s,
            self.controller_state as u8,
            self.flags,
            self.cycle_period_s,
            &self.q_rad,
            &self.dq_rad_s,
            &self.current_a,
            &self.q_cmd_rad,
            &self.dq_cmd_rad_s,
        )?;
        Ok(out)
    }

    /// Decode with every check of Python's `JointState.from_bytes` (allocates).
    pub fn from_bytes(data: &[u8]) -> Result<JointState, MessageError> {
        check_header(
            data,
            Self::MAGIC,
            "JointState",
            Self::HEAD_SIZE,
            LAYOUT_VERSION,
        )?;
        let n = data[5] as usize;
        let cycle = u32_at(data, 6) as i64;
        let stamp = f64_at(data, 10);
        let cstate = data[18];
        let flags = data[19];
        let period = f64_at(data, 20);
        if !(1..=MAX_JOINTS).contains(&n) {
            return Err(MessageError(format!(
                "JointState: joint count {n} outside 1..16"
            )));
        }
        let want = Self::size(n);
        if data.len() != want {
            return Err(MessageError(format!(
                "JointState: {} bytes, expected {want} for {n} joints",
                data.len()
            )));
        }
        if !(stamp.is_finite() && period.is_finite() && period >= 0.0) {
            return Err(MessageError(format!(
                "JointState: stamp_s {} / cycle_period_s {} invalid",
                py_repr(stamp),
                py_repr(period)
            )));
        }
        let controller_state = ControllerState::from_u8(cstate).ok_or_else(|| {
            MessageError(format!("JointState: controller_state {cstate} unknown"))
        })?;
        let block = |k: usize| -> Vec<f64> {
            (0..n)
                .map(|j| f64_at(data, Self::HEAD_SIZE + (k * n + j) * 8))
                .collect()
        };
        let names = [
            "q_rad",
            "dq_rad_s",
            "current_a",
            "q_cmd_rad",
            "dq_cmd_rad_s",
        ];
        let mut body: Vec<Vec<f64>> = (0..5).map(block).collect();
        for (values, name) in body.iter().zip(names) {
            check_finite(&format!("JointState.{name}"), values)?;
        }
        let dq_cmd = body.pop().unwrap_or_default();
        let q_cmd = body.pop().unwrap_or_default();
        let current = body.pop().unwrap_or_default();
        let dq = body.pop().unwrap_or_default();
        let q = body.pop().unwrap_or_default();
        Ok(JointState {
            cycle,
            stamp_s: stamp,
            controller_state,
            flags,
            q_rad: q,
            dq_rad_s: dq,
            current_a: current,
            q_cmd_rad: q_cmd,
            dq_cmd_rad_s: dq_cmd,
            cycle_period_s: period,
        })
    }
}

// --- JointCommand ---------------------------------------------------------------------------

/// A position/velocity command computed from one JointState (gateway/messages.py
/// JointCommand), decoded without allocating: only the first `n` entries of each array are
/// joints.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct JointCommand {
    /// the JointState.cycle this command answers (32 bits on the wire)
    pub cycle: i64,
    /// JointState.stamp_s it was computed from: ages the command [s]
    pub state_stamp_s: f64,
    /// control-process monotonic time at publication [s]
    pub sent_stamp_s: f64,
    /// number of joints
    pub n: usize,
    /// position command [rad]; see [`JointCommand::q_cmd_rad`]
    pub q_cmd_rad: [f64; MAX_JOINTS],
    /// velocity command [rad/s]; see [`JointCommand::dq_cmd_rad_s`]
    pub dq_cmd_rad_s: [f64; MAX_JOINTS],
    /// control-process monotonic time the JointState arrived [s]; 0 = not reported
    pub state_rx_stamp_s: f64,
}

impl JointCommand {
    pub const MAGIC: &'static [u8; 4] = b"LTJC";
    /// Layout 2 added `state_rx_stamp_s`.
    pub const VERSION: u8 = 2;
    /// `<4sBBIddd`: magic, version, n, cycle, three stamps [bytes].
    pub const HEAD_SIZE: usize = 34;

    /// Bytes of a JointCommand of `n` joints.
    pub fn size(n: usize) -> usize {
        Self::HEAD_SIZE + 2 * n * 8
    }

    /// The position command's joints [rad].
    pub fn q_cmd_rad(&self) -> &[f64] {
        &self.q_cmd_rad[..self.n]
    }

    /// The velocity command's joints [rad/s].
    pub fn dq_cmd_rad_s(&self) -> &[f64] {
        &self.dq_cmd_rad_s[..self.n]
    }

    /// Decode with every check of Python's `JointCommand.from_bytes`; no allocation unless
    /// the payload is refused.
    pub fn from_bytes(data: &[u8]) -> Result<JointCommand, MessageError> {
        check_header(
            data,
            Self::MAGIC,
            "JointCommand",
            Self::HEAD_SIZE,
            Self::VERSION,
        )?;
        let n = data[5] as usize;
        let cycle = u32_at(data, 6) as i64;
        let state_stamp = f64_at(data, 10);
        let sent_stamp = f64_at(data, 18);
        let rx_stamp = f64_at(data, 26);
        if !(1..=MAX_JOINTS).contains(&n) {
            return Err(MessageError(format!(
                "JointCommand: joint count {n} outside 1..16"
            )));
        }
        let want = Self::size(n);
        if data.len() != want {
            return Err(MessageError(format!(
                "JointCommand: {} bytes, expected {want} for {n} joints",
                data.len()
            )));
        }
        if !(state_stamp.is_finite() && sent_stamp.is_finite() && rx_stamp.is_finite()) {
            return Err(MessageError("JointCommand: stamps must be finite".into()));
        }
        let mut cmd = JointCommand {
            cycle,
            state_stamp_s: state_stamp,
            sent_stamp_s: sent_stamp,
            n,
            q_cmd_rad: [0.0; MAX_JOINTS],
            dq_cmd_rad_s: [0.0; MAX_JOINTS],
            state_rx_stamp_s: rx_stamp,
        };
        for j in 0..n {
            cmd.q_cmd_rad[j] = f64_at(data, Self::HEAD_SIZE + j * 8);
            cmd.dq_cmd_rad_s[j] = f64_at(data, Self::HEAD_SIZE + (n + j) * 8);
        }
        check_finite("JointCommand.q_cmd_rad", cmd.q_cmd_rad())?;
        check_finite("JointCommand.dq_cmd_rad_s", cmd.dq_cmd_rad_s())?;
        Ok(cmd)
    }

    /// The wire bytes of a JointCommand into `out` (cleared first; not reallocated when its
    /// capacity holds [`JointCommand::size`]`(n)`), with Python's `JointCommand.pack`
    /// checks: a command that is not finite is never encoded.
    pub fn pack(
        out: &mut Vec<u8>,
        cycle: i64,
        state_stamp_s: f64,
        sent_stamp_s: f64,
        q_cmd_rad: &[f64],
        dq_cmd_rad_s: &[f64],
        state_rx_stamp_s: f64,
    ) -> Result<(), MessageError> {
        out.clear();
        let n = q_cmd_rad.len();
        if dq_cmd_rad_s.len() != n || !(1..=MAX_JOINTS).contains(&n) {
            return Err(MessageError(format!(
                "JointCommand: {n} positions and {} velocities",
                dq_cmd_rad_s.len()
            )));
        }
        for (name, values) in [("q_cmd_rad", q_cmd_rad), ("dq_cmd_rad_s", dq_cmd_rad_s)] {
            if let Some(k) = values.iter().position(|v| !v.is_finite()) {
                return Err(MessageError(format!(
                    "JointCommand.{name}[{k}] is {}; must be finite",
                    py_repr(values[k])
                )));
            }
        }
        let stamps = [state_stamp_s, sent_stamp_s, state_rx_stamp_s];
        if !stamps.iter().all(|v| v.is_finite()) {
            return Err(MessageError("JointCommand: stamps must be finite".into()));
        }
        out.extend_from_slice(Self::MAGIC);
        out.push(Self::VERSION);
        out.push(n as u8);
        out.extend_from_slice(&((cycle & 0xFFFF_FFFF) as u32).to_le_bytes());
        put_f64s(out, &stamps);
        put_f64s(out, q_cmd_rad);
        put_f64s(out, dq_cmd_rad_s);
        Ok(())
    }

    /// The wire bytes (allocates; tests and tools).
    pub fn to_bytes(&self) -> Result<Vec<u8>, MessageError> {
        let mut out = Vec::with_capacity(Self::size(self.n));
        Self::pack(
            &mut out,
            self.cycle,
            self.state_stamp_s,
            self.sent_stamp_s,
            self.q_cmd_rad(),
            self.dq_cmd_rad_s(),
            self.state_rx_stamp_s,
        )?;
        Ok(out)
    }
}

// --- IoState --------------------------------------------------------------------------------

/// Cylinder pressures and safety inputs as the Modbus driver reads them (gateway/messages.py
/// IoState).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct IoState {
    /// Modbus driver monotonic time of the poll [s]
    pub stamp_s: f64,
    /// measured pressure, assist cylinder of joint 2 [bar]
    pub p2_bar: f64,
    /// measured pressure, assist cylinder of joint 3 [bar]
    pub p3_bar: f64,
    /// set-point read back from the valve [bar]
    pub p2_set_bar: f64,
    /// set-point read back from the valve [bar]
    pub p3_set_bar: f64,
    /// enabling device held (3-position switch in its middle position)
    pub enabling: bool,
    /// e-stop chain closed (false: e-stop pressed or wire broken)
    pub estop_ok: bool,
    /// the teach handle's mark button pressed (false: no such button)
    pub mark: bool,
}

impl IoState {
    pub const MAGIC: &'static [u8; 4] = b"LTIO";
    /// `<4sBdddddBBB` [bytes].
    pub const SIZE: usize = 48;
    /// `<4sBdddddBB`, the layout before the mark button (read as "not pressed") [bytes].
    pub const SIZE_NO_MARK: usize = 47;

    /// The wire bytes (the current layout, with the mark button).
    pub fn to_bytes(&self) -> [u8; Self::SIZE] {
        let mut out = [0u8; Self::SIZE];
        out[..4].copy_from_slice(Self::MAGIC);
        out[4] = LAYOUT_VERSION;
        let values = [
            self.stamp_s,
            self.p2_bar,
            self.p3_bar,
            self.p2_set_bar,
            self.p3_set_bar,
        ];
        for (k, v) in values.iter().enumerate() {
            out[5 + 8 * k..13 + 8 * k].copy_from_slice(&v.to_le_bytes());
        }
        out[45] = self.enabling as u8;
        out[46] = self.estop_ok as u8;
        out[47] = self.mark as u8;
        out
    }

    /// Decode either layout with every check of Python's `IoState.from_bytes`.
    pub fn from_bytes(data: &[u8]) -> Result<IoState, MessageError> {
        check_header(data, Self::MAGIC, "IoState", 5, LAYOUT_VERSION)?;
        let mark = match data.len() {
            Self::SIZE => data[47],
            Self::SIZE_NO_MARK => 0,
            size => {
                return Err(MessageError(format!(
                    "IoState: {size} bytes, expected {}",
                    Self::SIZE
                )))
            }
        };
        let values = [
            f64_at(data, 5),
            f64_at(data, 13),
            f64_at(data, 21),
            f64_at(data, 29),
            f64_at(data, 37),
        ];
        check_finite("IoState(stamp, p2, p3, p2_set, p3_set)", &values)?;
        let (en, es) = (data[45], data[46]);
        if en > 1 || es > 1 || mark > 1 {
            return Err(MessageError(format!(
                "IoState: flags enabling={en} estop_ok={es} mark={mark} must be 0 or 1"
            )));
        }
        Ok(IoState {
            stamp_s: values[0],
            p2_bar: values[1],
            p3_bar: values[2],
            p2_set_bar: values[3],
            p3_set_bar: values[4],
            enabling: en == 1,
            estop_ok: es == 1,
            mark: mark == 1,
        })
    }
}

// --- StateWindow ----------------------------------------------------------------------------

/// The joint states of a window of controller cycles, for readers off the cycle
/// (gateway/messages.py StateWindow): how many, the fastest joint speed any of them read,
/// each joint's lowest and highest position, and the newest JointState whole. The driver only
/// encodes it ([`StateWindow::pack`]); the decoded form is for tests and tools.
#[derive(Clone, Debug, PartialEq)]
pub struct StateWindow {
    /// controller cycles in the window (>= 1)
    pub states: u32,
    /// the fastest joint's measured speed in any of them [rad/s]
    pub max_speed_rad_s: f64,
    /// each joint's lowest measured position in the window [rad]
    pub q_lo_rad: Vec<f64>,
    /// ... and its highest [rad]
    pub q_hi_rad: Vec<f64>,
    /// the window's last JointState payload
    pub newest: Vec<u8>,
}

impl StateWindow {
    pub const MAGIC: &'static [u8; 4] = b"LTSW";
    /// `<4sBBId`: magic, version, n, states, max speed [bytes].
    pub const HEAD_SIZE: usize = 18;

    /// Bytes of a window of `n` joints whose newest state is `newest_len` bytes.
    pub fn size(n: usize, newest_len: usize) -> usize {
        Self::HEAD_SIZE + 2 * n * 8 + newest_len
    }

    /// The wire bytes of a window into `out` (cleared first; not reallocated when its
    /// capacity holds [`StateWindow::size`]). Err (and `out` empty) if the bounds differ in
    /// length or are no joint count (1..16).
    pub fn pack(
        out: &mut Vec<u8>,
        states: u32,
        max_speed_rad_s: f64,
        q_lo_rad: &[f64],
        q_hi_rad: &[f64],
        newest: &[u8],
    ) -> Result<(), MessageError> {
        out.clear();
        let n = q_lo_rad.len();
        if q_hi_rad.len() != n || !(1..=MAX_JOINTS).contains(&n) {
            return Err(MessageError(format!(
                "StateWindow: {n} lowest and {} highest positions",
                q_hi_rad.len()
            )));
        }
        out.extend_from_slice(Self::MAGIC);
        out.push(LAYOUT_VERSION);
        out.push(n as u8);
        out.extend_from_slice(&states.to_le_bytes());
        out.extend_from_slice(&max_speed_rad_s.to_le_bytes());
        put_f64s(out, q_lo_rad);
        put_f64s(out, q_hi_rad);
        out.extend_from_slice(newest);
        Ok(())
    }

    /// Decode with every check of Python's `StateWindow.from_bytes` (the newest state is
    /// checked by whoever decodes it; allocates).
    pub fn from_bytes(data: &[u8]) -> Result<StateWindow, MessageError> {
        check_header(
            data,
            Self::MAGIC,
            "StateWindow",
            Self::HEAD_SIZE,
            LAYOUT_VERSION,
        )?;
        let n = data[5] as usize;
        let states = u32_at(data, 6);
        let speed = f64_at(data, 10);
        if !(1..=MAX_JOINTS).contains(&n) {
            return Err(MessageError(format!(
                "StateWindow: joint count {n} outside 1..16"
            )));
        }
        let end = Self::HEAD_SIZE + 2 * n * 8;
        if data.len() <= end {
            return Err(MessageError(format!(
                "StateWindow: {} bytes, no state after {n} bounds",
                data.len()
            )));
        }
        if states < 1 || !(speed.is_finite() && speed >= 0.0) {
            return Err(MessageError(format!(
                "StateWindow: {states} states / max speed {} invalid",
                py_repr(speed)
            )));
        }
        let lo: Vec<f64> = (0..n)
            .map(|j| f64_at(data, Self::HEAD_SIZE + j * 8))
            .collect();
        let hi: Vec<f64> = (0..n)
            .map(|j| f64_at(data, Self::HEAD_SIZE + (n + j) * 8))
            .collect();
        check_finite("StateWindow.q_lo_rad", &lo)?;
        check_finite("StateWindow.q_hi_rad", &hi)?;
        if lo.iter().zip(&hi).any(|(l, h)| l > h) {
            return Err(MessageError(
                "StateWindow: a joint's lowest position is above its highest".into(),
            ));
        }
        Ok(StateWindow {
            states,
            max_speed_rad_s: speed,
            q_lo_rad: lo,
            q_hi_rad: hi,
            newest: data[end..].to_vec(),
        })
    }
}

// --- Python's number and bytes texts --------------------------------------------------------

/// Python's `repr(float)`: the shortest text that reads back the same double, `nan`, `inf`,
/// `-inf`; exponent notation below 1e-4 and from 1e16 (`1e-05`, `1.5e+16`).
pub fn py_repr(v: f64) -> String {
    if v.is_nan() {
        return "nan".into();
    }
    if v.is_infinite() {
        return if v > 0.0 { "inf".into() } else { "-inf".into() };
    }
    let sign = if v.is_sign_negative() { "-" } else { "" };
    // shortest round-trip digits and their decimal exponent
    let sci = format!("{:e}", v.abs());
    let (mantissa, exp) = sci.split_once('e').unwrap_or((&sci, "0"));
    let exp: i32 = exp.parse().unwrap_or(0);
    let digits: String = mantissa.chars().filter(|c| *c != '.').collect();
    if (-4..16).contains(&exp) {
        if exp >= 0 {
            let int_len = exp as usize + 1;
            if digits.len() <= int_len {
                format!("{sign}{digits}{}.0", "0".repeat(int_len - digits.len()))
            } else {
                format!("{sign}{}.{}", &digits[..int_len], &digits[int_len..])
            }
        } else {
            format!("{sign}0.{}{digits}", "0".repeat((-exp - 1) as usize))
        }
    } else {
        let rest = if digits.len() > 1 {
            format!(".{}", &digits[1..])
        } else {
            String::new()
        };
        let esign = if exp < 0 { '-' } else { '+' };
        format!("{sign}{}{rest}e{esign}{:02}", &digits[..1], exp.abs())
    }
}

/// Python's `format(v, "g")`: 6 significant digits, trailing zeros dropped, exponent notation
/// below 1e-4 and from 1e6 (`0.004`, `1`, `1e+06`, `2.5e-05`).
pub fn fmt_g(v: f64) -> String {
    if v.is_nan() {
        return "nan".into();
    }
    if v.is_infinite() {
        return if v > 0.0 { "inf".into() } else { "-inf".into() };
    }
    const P: i32 = 6;
    let sci = format!("{:.*e}", (P - 1) as usize, v);
    let (mantissa, exp) = sci.split_once('e').unwrap_or((&sci, "0"));
    let exp: i32 = exp.parse().unwrap_or(0);
    let strip = |s: &str| -> String {
        if s.contains('.') {
            s.trim_end_matches('0').trim_end_matches('.').to_string()
        } else {
            s.to_string()
        }
    };
    if (-4..P).contains(&exp) {
        strip(&format!("{:.*}", (P - 1 - exp) as usize, v))
    } else {
        let esign = if exp < 0 { '-' } else { '+' };
        format!("{}e{esign}{:02}", strip(mantissa), exp.abs())
    }
}

/// Python's `repr(bytes)`: `b'LTJS'`, with `\xNN` for what is not printable ASCII.
pub fn py_bytes_repr(data: &[u8]) -> String {
    let quote = if data.contains(&b'\'') && !data.contains(&b'"') {
        '"'
    } else {
        '\''
    };
    let mut s = String::with_capacity(3 + 4 * data.len());
    s.push('b');
    s.push(quote);
    for &b in data {
        match b {
            b'\\' => s.push_str("\\\\"),
            b'\t' => s.push_str("\\t"),
            b'\n' => s.push_str("\\n"),
            b'\r' => s.push_str("\\r"),
            _ if b as char == quote => {
                s.push('\\');
                s.push(quote);
            }
            0x20..=0x7E => s.push(b as char),
            _ => s.push_str(&format!("\\x{b:02x}")),
        }
    }
    s.push(quote);
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    fn unhex(s: &str) -> Vec<u8> {
        (0..s.len())
            .step_by(2)
            .map(|i| u8::from_str_radix(&s[i..i + 2], 16).unwrap())
            .collect()
    }

    // Golden bytes made by gateway/messages.py (cd /work/main; .venv/bin/python -c "from
    // gateway.messages import *; print(JointState.pack(70001, 12.5, 2, 6, 0.004, [0.1,-0.2],
    // [0.5,-1.5], [1.25,-2.0], [0.125,-0.25], [0.0,3.0]).hex())")
    const JS_HEX: &str = "4c544a5301027111010000000000000029400206fca9f1d24d62703f9a9999999999\
        b93f9a9999999999c9bf000000000000e03f000000000000f8bf000000000000f43f00000000000000c000\
        0000000000c03f000000000000d0bf00000000000000000000000000000840";
    // JointCommand.pack(9, 1.5, 1.6, [0.1, -0.2, 0.3], [0.01, 0.0, -0.5], 1.55).hex()
    const JC_HEX: &str = "4c544a43020309000000000000000000f83f9a9999999999f93fcdccccccccccf83f9a\
        9999999999b93f9a9999999999c9bf333333333333d33f7b14ae47e17a843f0000000000000000000000000\
        000e0bf";
    // IoState(1.0, 6.0, 4.0, 6.5, 4.5, True, True, mark=True).to_bytes().hex()
    const IO_HEX: &str = "4c54494f01000000000000f03f000000000000184000000000000010400000000000001a\
        400000000000001240010101";
    // IoState(2.0, 5.0, 3.0, 5.5, 3.5, True, False).to_bytes()[:-1].hex() (before the mark)
    const IO47_HEX: &str = "4c54494f0100000000000000400000000000001440000000000000084000000000000\
        016400000000000000c400100";
    // newest = JointState.pack(5, 1.0, 1, 2, 0.004, [0.1,-0.2], [0.5,-1.5], [1.25,-2.0],
    // [0.125,-0.25], [0.0,3.0]); StateWindow(3, 1.5, np.array([0.0,-0.25]),
    // np.array([0.1,-0.2]), newest).to_bytes().hex()
    const SW_HEX: &str = "4c545357010203000000000000000000f83f0000000000000000000000000000d0bf9a99\
        99999999b93f9a9999999999c9bf4c544a53010205000000000000000000f03f0102fca9f1d24d62703f9a9\
        999999999b93f9a9999999999c9bf000000000000e03f000000000000f8bf000000000000f43f0000000000\
        0000c0000000000000c03f000000000000d0bf00000000000000000000000000000840";

    const Q: [f64; 2] = [0.1, -0.2];
    const DQ: [f64; 2] = [0.5, -1.5];
    const I: [f64; 2] = [1.25, -2.0];
    const QC: [f64; 2] = [0.125, -0.25];
    const DQC: [f64; 2] = [0.0, 3.0];

    #[test]
    fn joint_state_packs_bit_exact_with_python_without_reallocating() {
        let mut out = Vec::with_capacity(JointState::size(MAX_JOINTS));
        let before = out.as_ptr();
        JointState::pack(
            &mut out,
            70001,
            12.5,
            ControllerState::External as u8,
            FLAG_SERVO_POWER | FLAG_PREV_HOLD,
            0.004,
            &Q,
            &DQ,
            &I,
            &QC,
            &DQC,
        )
        .unwrap();
        assert_eq!(out, unhex(JS_HEX));
        assert_eq!(out.as_ptr(), before, "written within the reserved capacity");
        // the cycle is 32 bits on the wire
        JointState::pack(
            &mut out,
            (1 << 32) + 70001,
            12.5,
            2,
            6,
            0.004,
            &Q,
            &DQ,
            &I,
            &QC,
            &DQC,
        )
        .unwrap();
        assert_eq!(out, unhex(JS_HEX));
        let short = JointState::pack(&mut out, 1, 0.0, 1, 0, 0.0, &Q, &DQ[..1], &I, &QC, &DQC);
        assert!(short.is_err() && out.is_empty());
    }

    #[test]
    fn joint_state_round_trip_and_python_checks() {
        let st = JointState::from_bytes(&unhex(JS_HEX)).unwrap();
        assert_eq!(st.cycle, 70001);
        assert_eq!(st.stamp_s, 12.5);
        assert_eq!(st.controller_state, ControllerState::External);
        assert_eq!(st.flags, 6);
        assert_eq!(st.cycle_period_s, 0.004);
        assert_eq!(
            (st.q_rad.as_slice(), st.dq_rad_s.as_slice()),
            (&Q[..], &DQ[..])
        );
        assert_eq!(st.current_a, I);
        assert_eq!(st.q_cmd_rad, QC);
        assert_eq!(st.dq_cmd_rad_s, DQC);
        assert_eq!(st.to_bytes().unwrap(), unhex(JS_HEX));

        // test_messages.py test_joint_state_rejects_nan_naming_the_field
        let mut data = unhex(JS_HEX);
        let at = JointState::HEAD_SIZE + 8 * 2 + 8;
        data[at..at + 8].copy_from_slice(&f64::NAN.to_le_bytes());
        let err = JointState::from_bytes(&data).unwrap_err().0;
        assert_eq!(
            err,
            "JointState.dq_rad_s[1] is nan; every value must be finite"
        );
        // test_joint_state_rejects_garbage
        let good = unhex(JS_HEX);
        let err = |d: &[u8]| JointState::from_bytes(d).unwrap_err().0;
        assert_eq!(
            err(&good[..good.len() - 1]),
            "JointState: 107 bytes, expected 108 for 2 joints"
        );
        let mut bad = good.clone();
        bad[..4].copy_from_slice(b"XXXX");
        assert_eq!(err(&bad), "JointState: magic b'XXXX' is not b'LTJS'");
        let mut bad = good.clone();
        bad[4] = 9;
        assert_eq!(
            err(&bad),
            "JointState: layout version 9 unsupported (want 1)"
        );
        assert_eq!(
            err(&good[..3]),
            "JointState: payload is 3 bytes, shorter than its header"
        );
        let mut bad = good.clone();
        bad[5] = 0;
        assert_eq!(err(&bad), "JointState: joint count 0 outside 1..16");
        let mut bad = good.clone();
        bad[18] = 4;
        assert_eq!(err(&bad), "JointState: controller_state 4 unknown");
        let mut bad = good.clone();
        bad[20..28].copy_from_slice(&(-1.0f64).to_le_bytes());
        assert_eq!(
            err(&bad),
            "JointState: stamp_s 12.5 / cycle_period_s -1.0 invalid"
        );
    }

    #[test]
    fn joint_command_decodes_python_bytes_with_every_check() {
        let data = unhex(JC_HEX);
        let cmd = JointCommand::from_bytes(&data).unwrap();
        assert_eq!((cmd.cycle, cmd.n), (9, 3));
        assert_eq!(
            (cmd.state_stamp_s, cmd.sent_stamp_s, cmd.state_rx_stamp_s),
            (1.5, 1.6, 1.55)
        );
        assert_eq!(cmd.q_cmd_rad(), &[0.1, -0.2, 0.3]);
        assert_eq!(cmd.dq_cmd_rad_s(), &[0.01, 0.0, -0.5]);
        assert_eq!(cmd.to_bytes().unwrap(), data);

        let err = |d: &[u8]| JointCommand::from_bytes(d).unwrap_err().0;
        assert_eq!(
            err(&data[..33]),
            "JointCommand: payload is 33 bytes, shorter than its header"
        );
        let mut bad = data.clone();
        bad[..4].copy_from_slice(b"LTJS");
        assert_eq!(err(&bad), "JointCommand: magic b'LTJS' is not b'LTJC'");
        let mut bad = data.clone();
        bad[4] = 1;
        assert_eq!(
            err(&bad),
            "JointCommand: layout version 1 unsupported (want 2)"
        );
        let mut bad = data.clone();
        bad[5] = 17;
        assert_eq!(err(&bad), "JointCommand: joint count 17 outside 1..16");
        assert_eq!(
            err(&data[..data.len() - 8]),
            "JointCommand: 74 bytes, expected 82 for 3 joints"
        );
        let mut bad = data.clone();
        bad[18..26].copy_from_slice(&f64::INFINITY.to_le_bytes());
        assert_eq!(err(&bad), "JointCommand: stamps must be finite");
        let mut bad = data.clone();
        let at = JointCommand::HEAD_SIZE + 8;
        bad[at..at + 8].copy_from_slice(&f64::NEG_INFINITY.to_le_bytes());
        assert_eq!(
            err(&bad),
            "JointCommand.q_cmd_rad[1] is -inf; every value must be finite"
        );
        let mut bad = data.clone();
        let at = JointCommand::HEAD_SIZE + 5 * 8;
        bad[at..at + 8].copy_from_slice(&f64::NAN.to_le_bytes());
        assert_eq!(
            err(&bad),
            "JointCommand.dq_cmd_rad_s[2] is nan; every value must be finite"
        );
    }

    #[test]
    fn joint_command_pack_equals_python_and_refuses_nan() {
        // test_messages.py test_joint_command_pack_equals_the_dataclass_encoding_and_refuses_nan
        let mut out = Vec::with_capacity(JointCommand::size(3));
        let (q, dq) = ([0.1, -0.2, 0.3], [0.01, 0.0, -0.5]);
        JointCommand::pack(&mut out, 9, 1.5, 1.6, &q, &dq, 1.55).unwrap();
        assert_eq!(out, unhex(JC_HEX));
        let nan = JointCommand::pack(&mut out, 9, 1.5, 1.6, &q, &[0.0, f64::NAN, 0.0], 0.0);
        assert_eq!(
            nan.unwrap_err().0,
            "JointCommand.dq_cmd_rad_s[1] is nan; must be finite"
        );
        let inf = JointCommand::pack(&mut out, 9, f64::INFINITY, 1.6, &q, &dq, 0.0);
        assert!(inf.unwrap_err().0.contains("stamps"));
        let short = JointCommand::pack(&mut out, 9, 1.0, 1.0, &q, &dq[..2], 0.0);
        assert_eq!(
            short.unwrap_err().0,
            "JointCommand: 3 positions and 2 velocities"
        );
    }

    #[test]
    fn io_state_decodes_both_layouts_and_refuses_garbage() {
        let io = IoState::from_bytes(&unhex(IO_HEX)).unwrap();
        let want = IoState {
            stamp_s: 1.0,
            p2_bar: 6.0,
            p3_bar: 4.0,
            p2_set_bar: 6.5,
            p3_set_bar: 4.5,
            enabling: true,
            estop_ok: true,
            mark: true,
        };
        assert_eq!(io, want);
        assert_eq!(io.to_bytes().to_vec(), unhex(IO_HEX));
        let old = IoState::from_bytes(&unhex(IO47_HEX)).unwrap();
        assert_eq!(
            old,
            IoState {
                stamp_s: 2.0,
                p2_bar: 5.0,
                p3_bar: 3.0,
                p2_set_bar: 5.5,
                p3_set_bar: 3.5,
                enabling: true,
                estop_ok: false,
                mark: false,
            }
        );
        // test_io_and_setpoint_round_trip_and_validation
        let mut marked = unhex(IO_HEX);
        marked[47] = 2;
        assert_eq!(
            IoState::from_bytes(&marked).unwrap_err().0,
            "IoState: flags enabling=1 estop_ok=1 mark=2 must be 0 or 1"
        );
        let bad = IoState {
            p2_bar: f64::NAN,
            ..want
        }
        .to_bytes();
        assert_eq!(
            IoState::from_bytes(&bad).unwrap_err().0,
            "IoState(stamp, p2, p3, p2_set, p3_set)[1] is nan; every value must be finite"
        );
        assert_eq!(
            IoState::from_bytes(&unhex(IO_HEX)[..40]).unwrap_err().0,
            "IoState: 40 bytes, expected 48"
        );
        assert!(IoState::from_bytes(b"LTIO")
            .unwrap_err()
            .0
            .contains("shorter"));
    }

    #[test]
    fn state_window_packs_bit_exact_with_python() {
        let mut newest = Vec::new();
        JointState::pack(
            &mut newest,
            5,
            1.0,
            ControllerState::Hold as u8,
            FLAG_SERVO_POWER,
            0.004,
            &Q,
            &DQ,
            &I,
            &QC,
            &DQC,
        )
        .unwrap();
        let mut out = Vec::with_capacity(StateWindow::size(2, newest.len()));
        let before = out.as_ptr();
        StateWindow::pack(&mut out, 3, 1.5, &[0.0, -0.25], &[0.1, -0.2], &newest).unwrap();
        assert_eq!(out, unhex(SW_HEX));
        assert_eq!(out.as_ptr(), before);
        let w = StateWindow::from_bytes(&out).unwrap();
        assert_eq!((w.states, w.max_speed_rad_s), (3, 1.5));
        assert_eq!(
            (w.q_lo_rad, w.q_hi_rad),
            (vec![0.0, -0.25], vec![0.1, -0.2])
        );
        assert_eq!(w.newest, newest);
        // test_joint_state_watch.py test_a_malformed_window_is_refused_naming_what_is_wrong
        let good = unhex(SW_HEX);
        let head = StateWindow::HEAD_SIZE;
        let err = |d: &[u8]| StateWindow::from_bytes(d).unwrap_err().0;
        assert!(err(&good[..head + 32]).contains("no state"));
        let mut bad = good.clone();
        bad[head..head + 8].copy_from_slice(&9.0f64.to_le_bytes());
        assert!(err(&bad).contains("above"));
        let mut bad = good.clone();
        bad[head..head + 8].copy_from_slice(&f64::NAN.to_le_bytes());
        assert!(err(&bad).contains("finite"));
        let mut bad = good.clone();
        bad[6..10].copy_from_slice(&0u32.to_le_bytes());
        assert!(err(&bad).contains("states"));
        let mut bad = good.clone();
        bad[..4].copy_from_slice(b"LTJS");
        assert!(err(&bad).contains("magic"));
    }

    #[test]
    fn lifecycle_values_and_names_are_pythons() {
        assert_eq!(Lifecycle::Replaying as u8, 5);
        assert_eq!(Lifecycle::from_u8(3), Some(Lifecycle::Fault));
        assert_eq!(Lifecycle::from_u8(6), None);
        assert_eq!(
            Lifecycle::from_name("IDENTIFYING"),
            Some(Lifecycle::Identifying)
        );
        assert!(Lifecycle::Teaching.commanding() && !Lifecycle::Ready.commanding());
        assert!(Lifecycle::Replaying.playing() && !Lifecycle::Teaching.playing());
        assert_eq!(
            (
                FLAG_ESTOP,
                FLAG_SERVO_POWER,
                FLAG_PREV_HOLD,
                FLAG_PREV_COAST
            ),
            (1, 2, 4, 8)
        );
    }

    #[test]
    fn numbers_read_as_python_writes_them() {
        for (v, repr, g) in [
            (0.004, "0.004", "0.004"),
            (1.0, "1.0", "1"),
            (-1.0, "-1.0", "-1"),
            (12.5, "12.5", "12.5"),
            (1e-5, "1e-05", "1e-05"),
            (1.5e16, "1.5e+16", "1.5e+16"),
            (1e16, "1e+16", "1e+16"),
            (123456789.0, "123456789.0", "1.23457e+08"),
            (0.1, "0.1", "0.1"),
            (1e6, "1000000.0", "1e+06"),
            (999999.0, "999999.0", "999999"),
            (0.0001, "0.0001", "0.0001"),
            (0.0, "0.0", "0"),
            (f64::NAN, "nan", "nan"),
            (f64::NEG_INFINITY, "-inf", "-inf"),
        ] {
            assert_eq!(py_repr(v), repr, "repr of {v}");
            assert_eq!(fmt_g(v), g, "g of {v}");
        }
        assert_eq!(py_bytes_repr(b"LT\x00'"), "b\"LT\\x00'\"");
    }
}
