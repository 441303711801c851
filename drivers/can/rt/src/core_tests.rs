//! The host core cycle by cycle (the Rust port of tests/unit/test_can_core.py, the core's
//! scenarios of test_can_driver_logic.py, test_lost_cycles.py, test_speed_monitor.py and
//! test_cia402_cycle.py): frames and payloads in, frames and payloads out, an explicit clock,
//! and a fake adapter with a trivial protocol so the tests do not depend on a vendor's codec.

use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell as StdCell;

use serde_json::json;

use crate::adapter::{
    Adapter, AdapterStats, ControllerState, Feedback, FrameError, HostRequest, MAX_JOINTS,
};
use crate::core::{Answer, HostCore, KinematicChain, REJECT_REASONS};
use crate::core_config::{CoreConfig, LostCycleAnswer};
use crate::frame::Frame;

// --- allocations of this thread (the no-allocation test) ------------------------------------

/// The system allocator, counting the allocations each thread makes.
struct CountingAlloc;

thread_local! {
    static ALLOCATIONS: StdCell<u64> = const { StdCell::new(0) };
}

unsafe impl GlobalAlloc for CountingAlloc {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        let _ = ALLOCATIONS.try_with(|n| n.set(n.get() + 1));
        System.alloc(layout)
    }

    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        System.dealloc(ptr, layout)
    }

    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        let _ = ALLOCATIONS.try_with(|n| n.set(n.get() + 1));
        System.realloc(ptr, layout, new_size)
    }
}

#[global_allocator]
static COUNTING_ALLOC: CountingAlloc = CountingAlloc;

fn allocations() -> u64 {
    ALLOCATIONS.with(|n| n.get())
}

#[test]
fn core_the_allocation_counter_counts() {
    let before = allocations();
    let probe: Vec<u64> = std::hint::black_box(Vec::with_capacity(4));
    assert!(allocations() > before);
    drop(probe);
}

// --- the fake adapter ----------------------------------------------------------------------

const FB_ID: u32 = 0x100; // + joint: counter u16, q f64, dq f64, current f64
const STATUS_ID: u32 = 0x180; // counter u16, state u8, servo u8, estop u8, period_us u32
const CMD_ID: u32 = 0x200; // + joint: counter u16, hold u8, q f64, dq f64
const REQUEST_ID: u32 = 0x020; // request u8
const HEARTBEAT_ID: u32 = 0x700; // 5
const SYNC_ID: u32 = 0x080;
/// The fake protocol carries |q| up to this [rad].
const Q_RANGE: f64 = 100.0;

fn f64_at(data: &[u8], at: usize) -> f64 {
    f64::from_le_bytes(data[at..at + 8].try_into().unwrap())
}

/// A trivial controller protocol: one feedback frame per joint, then a status frame that
/// closes the cycle; one command frame per joint; 16-bit counters.
struct FakeAdapter {
    n: usize,
    clock_period_s: Option<f64>,
    stats: AdapterStats,
    got: [Option<(u32, f64, f64, f64)>; MAX_JOINTS],
    corrupt: bool,
}

impl FakeAdapter {
    fn new(n: usize, clock_period_s: Option<f64>) -> FakeAdapter {
        FakeAdapter {
            n,
            clock_period_s,
            stats: AdapterStats::default(),
            got: [None; MAX_JOINTS],
            corrupt: false,
        }
    }

    fn drop_cycle(&mut self, why: &str, corrupt: bool) {
        if corrupt {
            self.stats.corrupt_cycles += 1;
        } else {
            self.stats.incomplete_cycles += 1;
        }
        self.stats.last_error = why.to_string();
        self.got = [None; MAX_JOINTS];
        self.corrupt = false;
    }
}

impl Adapter for FakeAdapter {
    fn name(&self) -> &'static str {
        "fake"
    }

    fn counter_modulus(&self) -> u32 {
        65536
    }

    fn host_heartbeat_timeout_s(&self) -> f64 {
        0.5
    }

    fn clock_period_s(&self) -> Option<f64> {
        self.clock_period_s
    }

    fn n_joints(&self) -> usize {
        self.n
    }

    fn clock_frames(&mut self, out: &mut Vec<Frame>) {
        out.push(Frame::empty(SYNC_ID));
    }

    fn feed(&mut self, frame: &Frame, _now: f64) -> Option<Feedback> {
        self.stats.frames += 1;
        if frame.error {
            self.stats.bad_frames += 1;
            self.stats.last_error = "error frame".into();
            self.corrupt = true;
            return None;
        }
        let data = frame.payload();
        if (FB_ID..FB_ID + self.n as u32).contains(&frame.id) {
            if data.len() < 26 {
                self.stats.bad_frames += 1;
                self.stats.last_error = format!("feedback of {} bytes", data.len());
                self.corrupt = true;
                return None;
            }
            let counter = u16::from_le_bytes([data[0], data[1]]) as u32;
            self.got[(frame.id - FB_ID) as usize] =
                Some((counter, f64_at(data, 2), f64_at(data, 10), f64_at(data, 18)));
            return None;
        }
        if frame.id != STATUS_ID {
            self.stats.unknown_frames += 1;
            return None;
        }
        if data.len() < 9 {
            self.stats.bad_frames += 1;
            self.stats.last_error = "short status".into();
            self.drop_cycle("short status", true);
            return None;
        }
        let counter = u16::from_le_bytes([data[0], data[1]]) as u32;
        if self.corrupt {
            self.drop_cycle("a bad frame in the cycle", true);
            return None;
        }
        let Some(state) = ControllerState::from_u8(data[2]) else {
            self.drop_cycle("bad controller state", true);
            return None;
        };
        let mut fb = Feedback::new(self.n);
        for k in 0..self.n {
            match self.got[k] {
                Some((c, q, dq, i)) if c == counter => {
                    fb.q[k] = q;
                    fb.dq[k] = dq;
                    fb.current[k] = i;
                }
                _ => {
                    self.drop_cycle("a joint's feedback is missing", false);
                    return None;
                }
            }
        }
        self.got = [None; MAX_JOINTS];
        fb.counter = counter;
        fb.controller_state = state;
        fb.servo_power = data[3] != 0;
        fb.estop = data[4] != 0;
        fb.period_s = u32::from_le_bytes([data[5], data[6], data[7], data[8]]) as f64 * 1e-6;
        fb.fault = if state == ControllerState::Fault {
            "FOLLOWING_ERROR"
        } else {
            "NONE"
        };
        self.stats.cycles += 1;
        Some(fb)
    }

    fn command_frames(
        &mut self,
        counter: u32,
        q: &[f64],
        dq: &[f64],
        hold: bool,
        out: &mut Vec<Frame>,
    ) -> Result<(), FrameError> {
        if let Some(k) = (0..self.n).find(|&k| !(q[k].abs() <= Q_RANGE && dq[k].is_finite())) {
            return Err(FrameError(format!(
                "J{}: command {} rad outside ±{Q_RANGE}",
                k + 1,
                q[k]
            )));
        }
        for k in 0..self.n {
            let mut data = [0u8; 19];
            data[..2].copy_from_slice(&(counter as u16).to_le_bytes());
            data[2] = hold as u8;
            data[3..11].copy_from_slice(&q[k].to_le_bytes());
            data[11..19].copy_from_slice(&dq[k].to_le_bytes());
            out.push(Frame::fd(CMD_ID + k as u32, &data, false));
        }
        Ok(())
    }

    fn request_frames(&mut self, request: HostRequest, out: &mut Vec<Frame>) {
        out.push(Frame::classic(REQUEST_ID, &[request as u8]));
    }

    fn heartbeat_frame(&mut self) -> Frame {
        Frame::classic(HEARTBEAT_ID, &[5])
    }

    fn stats(&self) -> &AdapterStats {
        &self.stats
    }

    fn health(&self, _now: f64) -> serde_json::Map<String, serde_json::Value> {
        let mut h = serde_json::Map::new();
        h.insert("fake_frames".into(), json!(self.stats.frames));
        h.insert("cycles".into(), json!("the adapter's, never the core's"));
        h
    }
}

/// A frame the core sent, decoded.
#[derive(Clone, Copy, Debug, PartialEq)]
enum Sent {
    Cmd {
        joint: usize,
        counter: u32,
        hold: bool,
        q: f64,
        dq: f64,
    },
    Request(u8),
    Heartbeat,
    Sync,
}

fn decode(frame: &Frame) -> Sent {
    let d = frame.payload();
    match frame.id {
        REQUEST_ID => Sent::Request(d[0]),
        HEARTBEAT_ID => Sent::Heartbeat,
        SYNC_ID => Sent::Sync,
        id if (CMD_ID..CMD_ID + MAX_JOINTS as u32).contains(&id) => Sent::Cmd {
            joint: (id - CMD_ID) as usize,
            counter: u16::from_le_bytes([d[0], d[1]]) as u32,
            hold: d[2] != 0,
            q: f64_at(d, 3),
            dq: f64_at(d, 11),
        },
        id => panic!("the core sent an unknown frame 0x{id:X}"),
    }
}

/// One command set: (counter, hold, q, dq) per joint.
#[derive(Clone, Debug, PartialEq)]
struct Set {
    counters: Vec<u32>,
    hold: Vec<bool>,
    q: Vec<f64>,
    dq: Vec<f64>,
}

impl Set {
    fn all_hold(&self) -> bool {
        self.hold.iter().all(|&h| h)
    }

    fn none_hold(&self) -> bool {
        self.hold.iter().all(|&h| !h)
    }
}

/// The command frames among `sent`, as sets of N.
fn commands(sent: &[Sent]) -> Vec<Set> {
    let cmds: Vec<_> = sent
        .iter()
        .filter_map(|s| match *s {
            Sent::Cmd {
                joint,
                counter,
                hold,
                q,
                dq,
            } => Some((joint, counter, hold, q, dq)),
            _ => None,
        })
        .collect();
    assert_eq!(cmds.len() % N, 0, "whole command sets");
    cmds.chunks(N)
        .map(|c| {
            assert!(
                c.iter().enumerate().all(|(k, f)| f.0 == k),
                "joints in order"
            );
            Set {
                counters: c.iter().map(|f| f.1).collect(),
                hold: c.iter().map(|f| f.2).collect(),
                q: c.iter().map(|f| f.3).collect(),
                dq: c.iter().map(|f| f.4).collect(),
            }
        })
        .collect()
}

fn requests(sent: &[Sent]) -> Vec<HostRequest> {
    sent.iter()
        .filter_map(|s| match *s {
            Sent::Request(0) => Some(HostRequest::Brake),
            Sent::Request(1) => Some(HostRequest::ServoOn),
            Sent::Request(2) => Some(HostRequest::ResetFault),
            _ => None,
        })
        .collect()
}

// --- payloads --------------------------------------------------------------------------------

/// A JointState payload, decoded (gateway/messages.py layout).
#[derive(Clone, Debug)]
struct Js {
    cycle: u32,
    stamp_s: f64,
    controller_state: u8,
    flags: u8,
    period_s: f64,
    q: Vec<f64>,
    dq: Vec<f64>,
    current: Vec<f64>,
    q_cmd: Vec<f64>,
    dq_cmd: Vec<f64>,
}

fn decode_state(b: &[u8]) -> Js {
    assert_eq!(&b[..4], b"LTJS");
    assert_eq!(b[4], 1);
    let n = b[5] as usize;
    assert_eq!(b.len(), 28 + 5 * n * 8);
    let block = |i: usize| {
        (0..n)
            .map(|k| f64_at(b, 28 + 8 * (i * n + k)))
            .collect::<Vec<_>>()
    };
    Js {
        cycle: u32::from_le_bytes(b[6..10].try_into().unwrap()),
        stamp_s: f64_at(b, 10),
        controller_state: b[18],
        flags: b[19],
        period_s: f64_at(b, 20),
        q: block(0),
        dq: block(1),
        current: block(2),
        q_cmd: block(3),
        dq_cmd: block(4),
    }
}

fn command_payload(cycle: u32, state_stamp_s: f64, sent_s: f64, q: &[f64], dq: &[f64]) -> Vec<u8> {
    let mut b = b"LTJC".to_vec();
    b.push(2);
    b.push(q.len() as u8);
    b.extend_from_slice(&cycle.to_le_bytes());
    for v in [state_stamp_s, sent_s, 0.0].iter().chain(q).chain(dq) {
        b.extend_from_slice(&v.to_le_bytes());
    }
    b
}

fn lifecycle_payload(state: &str, seq: i64, stamp_s: f64) -> Vec<u8> {
    json!({"state": state, "seq": seq, "stamp_s": stamp_s, "reason": ""})
        .to_string()
        .into_bytes()
}

fn io_payload(stamp_s: f64, enabling: bool, estop_ok: bool) -> Vec<u8> {
    let mut b = b"LTIO".to_vec();
    b.push(1);
    for v in [stamp_s, 6.0, 4.0, 6.0, 4.0] {
        b.extend_from_slice(&v.to_le_bytes());
    }
    b.extend_from_slice(&[enabling as u8, estop_ok as u8, 0]);
    b
}

fn error_frame(class: u32, data: &[u8]) -> Frame {
    let mut f = Frame::classic(class, data);
    f.error = true;
    f
}

// --- the cell ---------------------------------------------------------------------------------

const N: usize = 6;
const Q0: [f64; N] = [0.1, -0.2, 0.3, -0.4, 0.5, -0.6];
const PERIOD_US: u32 = 4000;
const PERIOD_S: f64 = 0.004;
const T0: f64 = 500.0;
const DEG: f64 = std::f64::consts::PI / 180.0;
/// The GR630ST datasheet's joint limits [deg] (gateway/robot/gr630st.toml).
const LOWER_DEG: [f64; N] = [-120.0, -70.0, -45.0, -360.0, -360.0, -360.0];
const UPPER_DEG: [f64; N] = [120.0, 70.0, 60.0, 360.0, 360.0, 360.0];

const ESTOP: u8 = 1;
const SERVO_POWER: u8 = 2;
const PREV_HOLD: u8 = 4;
const PREV_COAST: u8 = 8;
const ERR_CRTL: u32 = 0x004;
const ERR_PROT: u32 = 0x008;
const ERR_BUSOFF: u32 = 0x040;
const ERR_RESTARTED: u32 = 0x100;

/// The GR630ST datasheet's kinematics, as drivers/can/rt_kinematics.py `chain_table()` gives
/// them (what the Python tests' speed monitor evaluates).
const DATASHEET_CHAIN: &str = r#"{"format":"leadthrough-kinematic-chain","version":1,"joints":[{"name":"j1","parent_T_joint":[[1.0,-0.0,0.0,0.0],[0.0,1.0,0.0,0.0],[0.0,0.0,1.0,0.0],[0.0,0.0,0.0,1.0]],"axis":[0.0,0.0,1.0]},{"name":"j2","parent_T_joint":[[-0.0066671083490985675,-0.9999777745861462,0.0,0.002402],[6.123097904327087e-17,-4.0824264496460774e-19,-1.0,0.0],[0.9999777745861462,-0.0066671083490985675,6.123233995736766e-17,0.769],[0.0,0.0,0.0,1.0]],"axis":[0.0,0.0,1.0]},{"name":"j3","parent_T_joint":[[0.033277284019626784,0.9994461578135548,0.0,0.900073],[-0.9994461578135548,0.033277284019626784,0.0,0.0],[0.0,0.0,1.0,0.001177],[0.0,0.0,0.0,1.0]],"axis":[0.0,0.0,1.0]},{"name":"j4","parent_T_joint":[[0.9999944436310999,-0.0033335726971088935,0.0,1.1008],[0.0033335726971088935,0.9999944436310999,0.0,0.0],[0.0,0.0,1.0,0.0],[0.0,0.0,0.0,1.0]],"axis":[0.0,0.0,1.0]},{"name":"j5","parent_T_joint":[[0.015986534925356042,-0.9998722071850384,0.0,0.0],[6.122451490427783e-17,9.788929412897324e-19,-1.0,0.0],[0.9998722071850384,0.015986534925356042,6.123233995736766e-17,0.0],[0.0,0.0,0.0,1.0]],"axis":[0.0,0.0,1.0]},{"name":"j6","parent_T_joint":[[1.0,0.0,0.0,0.0],[0.0,6.123233995736766e-17,-1.0,0.0],[0.0,1.0,6.123233995736766e-17,0.112981],[0.0,0.0,0.0,1.0]],"axis":[0.0,0.0,1.0]}],"tool_m":[0.0,0.0,0.2268],"flange_m":[0.0,0.0,0.07680000000000001]}"#;

fn datasheet_chain() -> KinematicChain {
    KinematicChain::from_json(&serde_json::from_str(DATASHEET_CHAIN).unwrap()).unwrap()
}

fn limits() -> (Vec<f64>, Vec<f64>) {
    (
        LOWER_DEG.iter().map(|d| d * DEG).collect(),
        UPPER_DEG.iter().map(|d| d * DEG).collect(),
    )
}

fn config(edit: impl FnOnce(&mut CoreConfig)) -> CoreConfig {
    let mut cfg = CoreConfig::default(); // current_zero_cycles 0: the servo at once
    edit(&mut cfg);
    cfg
}

/// One controller cycle as the scripted controller sends it.
#[derive(Clone, Copy)]
struct Spec {
    q: [f64; N],
    state: ControllerState,
    current: [f64; N],
    power: bool,
    period_us: u32,
    counter: Option<u32>,
}

impl Default for Spec {
    fn default() -> Spec {
        Spec {
            q: Q0,
            state: ControllerState::External,
            current: [1.5; N],
            power: true,
            period_us: PERIOD_US,
            counter: None,
        }
    }
}

fn at(q: [f64; N]) -> Spec {
    Spec {
        q,
        ..Spec::default()
    }
}

/// The core and a scripted controller; `t` is the injected clock [s].
struct Cell {
    core: HostCore,
    t: f64,
    counter: u32,
    seq: i64,
    out: Vec<Frame>,
    state: Vec<u8>,
    window: Vec<u8>,
}

impl Cell {
    fn new(edit: impl FnOnce(&mut CoreConfig)) -> Cell {
        Cell::with(config(edit), None)
    }

    fn with(cfg: CoreConfig, clock_period_s: Option<f64>) -> Cell {
        let chain = (cfg.hand_guiding_max_speed_m_s > 0.0).then(datasheet_chain);
        let adapter = Box::new(FakeAdapter::new(cfg.joints, clock_period_s));
        let core = HostCore::new(cfg, adapter, 0.1, None, chain, limits()).expect("a core");
        Cell {
            core,
            t: T0,
            counter: 0,
            seq: 0,
            out: Vec::with_capacity(64),
            state: Vec::with_capacity(512),
            window: Vec::with_capacity(1024),
        }
    }

    fn gateway(&mut self, state: &str) {
        self.gateway_io(state, true, true);
    }

    fn gateway_io(&mut self, state: &str, enabling: bool, estop_ok: bool) {
        self.seq += 1; // the gateway numbers every announcement it changes
        let t = self.t;
        self.core
            .on_lifecycle(&lifecycle_payload(state, self.seq, t), t);
        self.core.on_io(&io_payload(t, enabling, estop_ok), t);
    }

    /// The frames of one controller cycle.
    fn frames(&mut self, spec: Spec) -> Vec<Frame> {
        self.counter = match spec.counter {
            Some(c) => c,
            None => (self.counter + 1) & 0xFFFF,
        };
        let mut frames = Vec::new();
        for k in 0..N {
            let mut d = [0u8; 26];
            d[..2].copy_from_slice(&(self.counter as u16).to_le_bytes());
            d[2..10].copy_from_slice(&spec.q[k].to_le_bytes());
            d[10..18].copy_from_slice(&(0.01 * k as f64).to_le_bytes());
            d[18..26].copy_from_slice(&spec.current[k].to_le_bytes());
            frames.push(Frame::fd(FB_ID + k as u32, &d, false));
        }
        let mut s = [0u8; 9];
        s[..2].copy_from_slice(&(self.counter as u16).to_le_bytes());
        s[2] = spec.state as u8;
        s[3] = spec.power as u8;
        s[4] = 0;
        s[5..9].copy_from_slice(&spec.period_us.to_le_bytes());
        frames.push(Frame::fd(STATUS_ID, &s, false));
        frames
    }

    /// Feed one controller cycle; its JointState (None if the core published none) and the
    /// frames sent at once.
    fn try_cycle(&mut self, spec: Spec) -> (Option<Js>, Vec<Sent>) {
        let mut published = None;
        let mut sent = Vec::new();
        for frame in self.frames(spec) {
            self.out.clear();
            let t = self.t;
            let result =
                self.core
                    .on_frame(&frame, t, &mut self.out, &mut self.state, &mut self.window);
            sent.extend(self.out.iter().map(decode));
            if result.state {
                assert!(published.is_none(), "one JointState per cycle");
                published = Some(decode_state(&self.state));
            }
        }
        (published, sent)
    }

    fn cycle(&mut self, spec: Spec) -> (Js, Vec<Sent>) {
        let (js, sent) = self.try_cycle(spec);
        (js.expect("the cycle's last frame completes it"), sent)
    }

    fn tick(&mut self) -> Vec<Sent> {
        self.out.clear();
        let t = self.t;
        self.core.on_tick(t, &mut self.out);
        self.out.iter().map(decode).collect()
    }

    fn command(&mut self, js: &Js, q: &[f64], dq: f64) -> (Answer, Vec<Set>) {
        self.command_stamped(js.cycle, js.stamp_s, q, dq)
    }

    fn command_stamped(
        &mut self,
        cycle: u32,
        state_stamp_s: f64,
        q: &[f64],
        dq: f64,
    ) -> (Answer, Vec<Set>) {
        let payload = command_payload(cycle, state_stamp_s, self.t, q, &[dq; N]);
        self.out.clear();
        let t = self.t;
        let result = self.core.on_command(&payload, t, &mut self.out);
        let sent: Vec<Sent> = self.out.iter().map(decode).collect();
        (result.answer, commands(&sent))
    }

    fn answer(&self) -> Answer {
        self.core.pending_answer()
    }

    fn health(&mut self) -> serde_json::Map<String, serde_json::Value> {
        let t = self.t;
        self.core.health(t)
    }
}

fn plus(q: [f64; N], d: f64) -> [f64; N] {
    q.map(|v| v + d)
}

fn assert_close(actual: &[f64], expected: &[f64], atol: f64) {
    assert_eq!(actual.len(), expected.len(), "{actual:?} vs {expected:?}");
    for (k, (a, e)) in actual.iter().zip(expected).enumerate() {
        assert!(
            (a - e).abs() <= atol,
            "[{k}]: {a} != {e} within {atol} ({actual:?} vs {expected:?})"
        );
    }
}

// --- test_can_core.py ----------------------------------------------------------------------

#[test]
fn core_a_cycle_becomes_one_joint_state_with_the_feedback_and_the_echo() {
    let mut cell = Cell::new(|_| {});
    let (js, _) = cell.cycle(Spec::default());
    assert_eq!(js.cycle, cell.counter);
    assert_eq!(js.stamp_s, T0);
    assert_eq!(js.period_s, 0.004);
    assert_eq!(js.controller_state, ControllerState::External as u8);
    assert_close(&js.q, &Q0, 1e-6);
    assert_close(&js.dq, &[0.0, 0.01, 0.02, 0.03, 0.04, 0.05], 1e-4);
    assert_close(&js.current, &[1.5; N], 1e-9);
    assert_close(&js.q_cmd, &js.q, 0.0); // nothing sent yet: the measurement
    assert_close(&js.dq_cmd, &[0.0; N], 0.0);
    assert!(js.flags & SERVO_POWER != 0 && js.flags & ESTOP == 0);
    assert_eq!(cell.core.cycles, 1);
    assert_eq!(cell.core.pending_cycle(), Some(1));
}

#[test]
fn core_the_first_state_closes_a_window_and_then_one_per_period_or_on_a_change() {
    let mut cell = Cell::new(|c| c.state_window_s = 0.02);
    let mut closed = Vec::new();
    for k in 0..12 {
        let spec = if k == 8 {
            Spec {
                state: ControllerState::Hold,
                ..Spec::default()
            }
        } else {
            Spec::default()
        };
        let frames = cell.frames(spec);
        let mut window = false;
        for f in &frames {
            cell.out.clear();
            let r = cell
                .core
                .on_frame(f, cell.t, &mut cell.out, &mut cell.state, &mut cell.window);
            window |= r.window;
            if r.window {
                assert_eq!(&cell.window[..4], b"LTSW");
                assert_eq!(
                    &cell.window[cell.window.len() - cell.state.len()..],
                    &cell.state[..],
                    "the newest state whole"
                );
            }
        }
        closed.push(window);
        cell.t += PERIOD_S;
    }
    // the first state; then on the 20 ms grid (5 cycles of 4 ms), and at once when the
    // controller's state changes (to HOLD and back), the grid going on
    assert_eq!(
        closed
            .iter()
            .enumerate()
            .filter(|(_, &c)| c)
            .map(|(k, _)| k)
            .collect::<Vec<_>>(),
        vec![0, 5, 8, 9]
    );
}

#[test]
fn core_currents_are_published_less_the_zero_measured_with_the_servo_power_off() {
    let mut cell = Cell::new(|c| {
        c.current_zero_cycles = 4;
        c.current_zero_settle_cycles = 2;
    });
    let zero = [0.07, -0.21, 0.15, 0.02, -0.01, 0.0];
    let (js, _) = cell.cycle(Spec {
        current: plus(zero, 2.0),
        ..Spec::default()
    }); // powered: nothing measured yet
    assert_close(&js.current, &plus(zero, 2.0), 6e-3);
    let mut js = js;
    for k in 0..8 {
        // the power goes off; the first 2 cycles still hold powered ticks
        let current = plus(zero, if k < 2 { 1.0 } else { 0.0 });
        js = cell
            .cycle(Spec {
                state: ControllerState::Braked,
                current,
                power: false,
                ..Spec::default()
            })
            .0;
    }
    assert_close(&js.current, &[0.0; N], 6e-3);
    let health = cell.health();
    let measured: Vec<f64> = health["current_zero_a"]
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v.as_f64().unwrap())
        .collect();
    assert_close(&measured, &zero, 6e-3);
    assert_eq!(health["current_zero_samples"], json!(4));
    assert_eq!(health["current_zero_source"], json!("measured"));
    let (js, _) = cell.cycle(Spec {
        current: plus(zero, 3.0),
        ..Spec::default()
    }); // powered again: the zero stays
    assert_close(&js.current, &[3.0; N], 6e-3);
}

#[test]
fn core_the_first_servo_on_waits_until_the_current_zero_is_measured() {
    let mut cell = Cell::new(|c| {
        c.current_zero_cycles = 3;
        c.current_zero_settle_cycles = 0;
    });
    let off = Spec {
        state: ControllerState::Braked,
        current: [0.1; N],
        power: false,
        ..Spec::default()
    };
    cell.gateway("ready");
    assert_eq!(cell.core.desired_request(cell.t), HostRequest::Brake); // nothing measured yet
    assert_eq!(requests(&cell.tick()), vec![HostRequest::Brake]);
    let notes = cell.core.take_notes();
    assert!(
        notes
            .iter()
            .any(|(level, key, m)| *level == 20 && key == "zero" && m.contains("0 of 3 cycles")),
        "{notes:?}"
    );
    for _ in 0..2 {
        cell.cycle(off);
    }
    assert_eq!(cell.core.desired_request(cell.t), HostRequest::Brake);
    cell.cycle(off);
    assert_eq!(cell.core.desired_request(cell.t), HostRequest::ServoOn);
    cell.cycle(Spec {
        current: [2.0; N],
        ..Spec::default()
    }); // powered, then off again: no new wait
    cell.cycle(off);
    assert_eq!(cell.core.desired_request(cell.t), HostRequest::ServoOn);
}

#[test]
fn core_a_blocked_cycle_is_held_at_once_and_flagged_in_the_next_state() {
    let mut cell = Cell::new(|_| {}); // no lifecycle: blocked
    let (_, sent) = cell.cycle(Spec::default());
    let hold = commands(&sent);
    assert_eq!(hold.len(), 1);
    assert!(hold[0].all_hold() && hold[0].counters.iter().all(|&c| c == cell.counter));
    assert_eq!(cell.answer(), Answer::Hold);
    let (js, _) = cell.cycle(Spec::default());
    assert!(js.flags & PREV_HOLD != 0);
}

#[test]
fn core_a_fresh_command_is_forwarded_once_and_echoed() {
    let mut cell = Cell::new(|_| {});
    cell.gateway("teaching");
    let (js, sent) = cell.cycle(Spec::default());
    assert!(commands(&sent).is_empty());
    cell.t += 0.001;
    let (answer, sets) = cell.command(&js, &plus(Q0, 0.01), 0.2);
    assert_eq!(answer, Answer::Command);
    assert_eq!(sets.len(), 1);
    assert!(sets[0].counters.iter().all(|&c| c == cell.counter) && sets[0].none_hold());
    assert_close(&sets[0].q, &plus(Q0, 0.01), 1e-6);
    let (again, frames) = cell.command(&js, &Q0, 0.0);
    assert_eq!((again, frames.len()), (Answer::None, 0));
    assert_eq!(cell.core.rejected_for("late_cycle"), 1);
    let (nxt, _) = cell.cycle(Spec::default());
    assert_close(&nxt.q_cmd, &plus(Q0, 0.01), 0.0);
    assert!(nxt.flags & (PREV_HOLD | PREV_COAST) == 0);
    assert_eq!(cell.core.forwarded, 1);
}

#[test]
fn core_the_next_deadline_is_the_answer_time_of_an_unanswered_cycle() {
    let mut cell = Cell::new(|c| {
        c.deadline_s = 0.010;
        c.answer_by_period_fraction = 0.5;
    });
    cell.gateway("teaching");
    cell.tick(); // first heartbeat and request go out
    cell.cycle(Spec::default());
    assert!((cell.core.next_tick_s() - (T0 + 0.002)).abs() < 1e-9); // 0.5 × 4 ms < 10 ms
    cell.t += 0.0019;
    assert!(commands(&cell.tick()).is_empty());
    cell.t += 0.0002;
    let hold = commands(&cell.tick());
    assert!(hold.len() == 1 && hold[0].all_hold());
    assert!((cell.core.next_tick_s() - (T0 + 0.1)).abs() < 1e-9); // next heartbeat
}

#[test]
fn core_at_ltc1s_8_ms_one_late_command_coasts_and_a_second_in_a_row_holds() {
    // The coast's bound is one cycle, whatever the period: at 8 ms the command of the cycle
    // before is 12 ms old when the late cycle is answered (past deadline_s, 10 ms), and still
    // coasts; the next late cycle holds.
    let mut cell = Cell::new(|c| c.deadline_s = 0.010);
    let slow = Spec {
        period_us: 8000,
        ..Spec::default()
    };
    cell.gateway("teaching");
    cell.tick();
    let (js, _) = cell.cycle(slow);
    assert_eq!(cell.command(&js, &plus(Q0, 0.001), 0.2).0, Answer::Command);
    let coasted = plus(Q0, 0.001 + 0.2 * 0.008);
    for answer in [Answer::Coast, Answer::Hold] {
        // the hold keeps the coast's place
        cell.t += 0.008;
        cell.gateway("teaching");
        cell.cycle(slow);
        cell.t += 0.0041; // past the answer deadline, half the period
        let sent = commands(&cell.tick());
        assert_eq!(cell.answer(), answer);
        assert_eq!(sent.len(), 1);
        assert!(sent[0].hold.iter().all(|&h| h == (answer == Answer::Hold)));
        assert_close(&sent[0].q, &coasted, 2e-6);
        cell.t -= 0.0041;
    }
}

#[test]
fn core_against_a_lock_step_controller_waits_for_a_late_command_then_holds() {
    // A lock-step virtual controller starts its next cycle only once this one is answered:
    // a command 150 ms late at an 8 ms period is forwarded, not held, and the link stays up;
    // past the wait the cycle is held as at any controller.
    let mut cell = Cell::new(|c| c.lockstep_answer_wait_s = 0.2);
    let slow = Spec {
        period_us: 8000,
        ..Spec::default()
    };
    cell.gateway("teaching");
    cell.tick();
    let (js, _) = cell.cycle(slow);
    cell.t += 0.15;
    cell.gateway("teaching");
    assert!(commands(&cell.tick()).is_empty());
    assert!(cell.core.link_ok(cell.t));
    assert_eq!(cell.command(&js, &plus(Q0, 0.001), 0.2).0, Answer::Command);
    cell.gateway("teaching");
    cell.cycle(slow);
    cell.t += 0.19;
    assert!(commands(&cell.tick()).is_empty());
    cell.t += 0.011;
    let late = commands(&cell.tick());
    assert!(late.len() == 1 && cell.answer() != Answer::Command);
    assert!(!cell.core.link_ok(cell.t + 0.1)); // 0.1 s controller timeout + the 0.2 s wait
}

#[test]
fn core_a_late_command_coasts_then_the_next_late_one_holds_where_the_coast_went() {
    let mut cell = Cell::new(|c| c.deadline_s = 0.010);
    cell.gateway("teaching");
    cell.tick(); // servo on requested: a new servo-on period begins
    let (js, _) = cell.cycle(Spec::default());
    assert_eq!(cell.command(&js, &plus(Q0, 0.001), 0.2).0, Answer::Command);
    cell.t += 0.004;
    cell.gateway("teaching");
    cell.cycle(Spec::default());
    cell.t += 0.0021;
    let coast = commands(&cell.tick());
    assert!(cell.answer() == Answer::Coast && coast[0].none_hold());
    assert_close(&coast[0].q, &plus(Q0, 0.001 + 0.2 * 0.004), 2e-6);
    cell.t += 0.010; // the next cycle is late too: two cycles after the forwarded command
    cell.gateway("teaching");
    let (js, _) = cell.cycle(Spec::default());
    assert!(js.flags & PREV_COAST != 0);
    cell.t += 0.0021;
    let hold = commands(&cell.tick());
    assert!(hold[0].all_hold() && cell.answer() == Answer::Hold);
    // where the controller was sent last: a hold at the forwarded command would pull it back
    assert_close(&hold[0].q, &plus(Q0, 0.001 + 0.2 * 0.004), 2e-6);
}

#[test]
fn core_coast_max_cycles_lets_that_many_late_cycles_in_a_row_coast() {
    let mut cell = Cell::new(|c| c.coast_max_cycles = 2);
    cell.gateway("teaching");
    cell.tick();
    let (js, _) = cell.cycle(Spec::default());
    assert_eq!(cell.command(&js, &Q0, 0.2).0, Answer::Command);
    let mut answers = Vec::new();
    let mut last_q = Vec::new();
    for _ in 0..3 {
        cell.t += PERIOD_S;
        cell.gateway("teaching");
        cell.cycle(Spec::default());
        cell.t += 0.0021;
        let sets = commands(&cell.tick());
        cell.t -= 0.0021;
        answers.push(cell.answer());
        last_q = sets[0].q.clone();
    }
    assert_eq!(answers, vec![Answer::Coast, Answer::Coast, Answer::Hold]);
    assert_close(&last_q, &plus(Q0, 0.2 * 2.0 * PERIOD_S), 2e-6); // held where the second coast went
    assert_eq!(cell.core.coasted, 2);
}

#[test]
fn core_an_implausible_command_is_refused_and_its_cycle_held() {
    for (q_offset, dq) in [(0.06, 0.0), (0.0, 1.01)] {
        let mut cell = Cell::new(|c| {
            c.max_following_error_rad = vec![0.05; N];
            c.max_velocity_rad_s = vec![1.0; N];
        });
        cell.gateway("teaching");
        let (js, _) = cell.cycle(Spec::default());
        let (answer, sets) = cell.command(&js, &plus(Q0, q_offset), dq);
        assert!(answer == Answer::Hold && sets.len() == 1 && sets[0].all_hold());
        assert_eq!(cell.core.rejected_for("out_of_range"), 1);
        let notes = cell.core.take_notes();
        let want = if dq > 0.0 {
            "|dq_cmd| = 1.0100 rad/s > 1 rad/s"
        } else {
            "|q_cmd - q| = 0.0600 rad > 0.05 rad"
        };
        assert!(
            notes
                .iter()
                .any(|(l, k, m)| *l == 30 && k == "out_of_range" && m.contains(want)),
            "{notes:?}"
        );
    }
}

#[test]
fn core_a_command_the_protocol_cannot_carry_is_out_of_range_and_held() {
    let mut cell = Cell::new(|c| {
        c.max_following_error_rad = vec![1000.0; N];
        c.joint_limit_margin_rad = 0.0;
    });
    // a joint without limits to speak of, so only the protocol refuses
    cell.core = HostCore::new(
        cell.core.config().clone(),
        Box::new(FakeAdapter::new(N, None)),
        0.1,
        None,
        Some(datasheet_chain()),
        (vec![-1e6; N], vec![1e6; N]),
    )
    .unwrap();
    cell.gateway("teaching");
    let (js, _) = cell.cycle(Spec::default());
    let (answer, sets) = cell.command(&js, &plus(Q0, 200.0), 0.0);
    assert!(
        answer == Answer::Hold && sets.len() == 1 && sets[0].all_hold(),
        "nothing of the refused set went out"
    );
    assert_close(&sets[0].q, &Q0, 0.0);
    assert_eq!(cell.core.rejected_for("out_of_range"), 1);
}

#[test]
fn core_a_garbled_command_is_counted_and_answers_nothing() {
    let mut cell = Cell::new(|_| {});
    cell.gateway("teaching");
    cell.cycle(Spec::default());
    let mut out = Vec::new();
    let result = cell.core.on_command(b"LTJC\x02garbage", cell.t, &mut out);
    assert!(out.is_empty() && result.command.is_none() && result.answer == Answer::None);
    assert_eq!(cell.core.rejected_for("bad_message"), 1);
    // a command for another joint count is a bad message too, decoded
    let js = decode_state(&cell.state);
    let payload = command_payload(js.cycle, js.stamp_s, cell.t, &Q0[..5], &[0.0; 5]);
    let result = cell.core.on_command(&payload, cell.t, &mut out);
    assert!(out.is_empty() && result.command.is_some() && result.answer == Answer::None);
    assert_eq!(cell.core.rejected_for("bad_message"), 2);
}

#[test]
fn core_closing_frames_brake_first_then_hold_the_waiting_cycle() {
    let mut cell = Cell::new(|_| {});
    cell.gateway("teaching");
    cell.cycle(Spec::default());
    let mut out = Vec::new();
    cell.core.closing_frames(&mut out);
    let sent: Vec<Sent> = out.iter().map(decode).collect();
    assert_eq!(sent[0], Sent::Request(HostRequest::Brake as u8));
    let sets = commands(&sent[1..]);
    assert!(sets.len() == 1 && sets[0].all_hold() && sent.len() == 1 + N);
    assert_eq!(cell.core.request_sent, Some(HostRequest::Brake));
}

/// Teach: one command moving every joint at `dq` from Q0; the position it sent.
fn moving(cell: &mut Cell, dq: f64) -> [f64; N] {
    cell.gateway("teaching");
    cell.tick();
    let (js, _) = cell.cycle(Spec::default());
    assert_eq!(cell.command(&js, &Q0, dq).0, Answer::Command);
    Q0
}

/// `cycles` cycles, the gateway announcing `state` each, the measured position the last
/// command sent (a drive following it); the command sets answered at once.
fn follow(
    cell: &mut Cell,
    state: &str,
    cycles: usize,
    q: [f64; N],
    enabling: bool,
    estop_ok: bool,
) -> Vec<Set> {
    let mut q = q;
    let mut sets = Vec::new();
    for _ in 0..cycles {
        cell.t += PERIOD_S;
        cell.gateway_io(state, enabling, estop_ok);
        let (_, frames) = cell.cycle(at(q));
        if let Some(set) = commands(&frames).pop() {
            q.copy_from_slice(&set.q);
            sets.push(set);
        }
    }
    sets
}

#[test]
fn core_releasing_the_enabling_device_ramps_the_command_to_standstill_then_holds() {
    // Stop category 2: the velocity falls linearly to zero in |dq| / deceleration (0.2 rad/s
    // at 1 rad/s²: 0.2 s, 50 cycles of 4 ms) along the last command's path, then a hold at
    // the ramp's end, dq·T/2 = 20 mrad further on.
    let mut cell = Cell::new(|c| {
        c.stop_deceleration_rad_s2 = vec![1.0; N];
        c.hand_guiding_max_speed_m_s = 0.0;
    });
    let q = moving(&mut cell, 0.2);
    let sets = follow(&mut cell, "teaching", 60, q, false, true);
    assert_eq!(sets.len(), 60, "every cycle of the stop answered at once");
    let ramp: Vec<&Set> = sets.iter().filter(|s| s.none_hold()).collect();
    let held: Vec<&Set> = sets.iter().filter(|s| s.all_hold()).collect();
    assert!(ramp.len() == 50 && held.len() == 10 && sets[..50].iter().all(|s| s.none_hold()));
    for (k, s) in ramp.iter().enumerate() {
        assert!((s.dq[0] - 0.2 * (1.0 - k as f64 / 50.0)).abs() < 1e-4);
    }
    let steps: Vec<f64> = ramp
        .windows(2)
        .map(|w| (w[1].q[0] - w[0].q[0]) / 0.004)
        .collect();
    assert!(steps.iter().all(|&s| s > -1e-3), "never reverses");
    assert!(steps.windows(2).all(|w| w[1] - w[0] < 1e-2), "slows down");
    let end = plus(Q0, 0.2 * 0.004 + 0.5 * 0.2 * 0.2);
    assert_close(&held[held.len() - 1].q, &end, 2e-6);
    assert_eq!(cell.health()["ramped"], json!(50));
    assert_eq!(cell.core.desired_request(cell.t), HostRequest::ServoOn);
    assert!(cell
        .core
        .take_notes()
        .iter()
        .any(|(_, k, m)| k == "ramp" && m.contains("ramping to standstill in 200 ms")));
}

#[test]
fn core_a_fault_during_the_ramp_holds_at_once_where_the_ramp_had_got_to() {
    let mut cell = Cell::new(|c| {
        c.stop_deceleration_rad_s2 = vec![1.0; N];
        c.hand_guiding_max_speed_m_s = 0.0;
    });
    let q = moving(&mut cell, 0.2);
    let sets = follow(&mut cell, "teaching", 10, q, false, true);
    assert_eq!(cell.answer(), Answer::Ramp);
    let mut reached = [0.0; N];
    reached.copy_from_slice(&sets[sets.len() - 1].q);
    let after = follow(&mut cell, "teaching", 3, reached, false, false);
    assert!(
        after.iter().all(|s| s.all_hold()),
        "the e-stop chain opened: no more ramp"
    );
    // held where the ramp was on the cycle the fault was seen
    assert_close(&after[0].q, &plus(reached, 0.004 * 0.2 * 0.8), 2e-5);
}

#[test]
fn core_the_operators_stop_keeps_the_servo_on_through_the_ramp_then_brakes() {
    // Stop category 1: STOPPED while the arm moves ramps it to standstill under power.
    let mut cell = Cell::new(|c| {
        c.stop_deceleration_rad_s2 = vec![2.0; N];
        c.hand_guiding_max_speed_m_s = 0.0;
    });
    let q = moving(&mut cell, 0.2);
    follow(&mut cell, "stopped", 5, q, true, true);
    assert_eq!(cell.answer(), Answer::Ramp);
    assert_eq!(cell.core.desired_request(cell.t), HostRequest::ServoOn);
    follow(&mut cell, "stopped", 25, q, true, true); // 0.1 s: the ramp has ended
    assert_eq!(cell.answer(), Answer::Hold);
    assert_eq!(cell.core.desired_request(cell.t), HostRequest::Brake);
}

#[test]
fn core_the_operators_stop_between_two_cycles_waits_for_the_ramp_not_the_brakes() {
    // The stop arrives, and the driver decides its servo request, before the next cycle
    // starts the ramp: the servo stays on.
    let mut cell = Cell::new(|c| {
        c.stop_deceleration_rad_s2 = vec![2.0; N];
        c.hand_guiding_max_speed_m_s = 0.0;
    });
    let q = moving(&mut cell, 0.2);
    cell.t += 0.001;
    cell.gateway("stopped");
    let sent = cell.tick();
    assert!(
        requests(&sent).iter().all(|&r| r == HostRequest::ServoOn),
        "{sent:?}"
    );
    assert_eq!(cell.core.desired_request(cell.t), HostRequest::ServoOn);
    follow(&mut cell, "stopped", 1, q, true, true);
    assert_eq!(cell.answer(), Answer::Ramp);
    cell.t += 1.0; // long after: a stop that never ramped would not keep the servo on
    cell.gateway("stopped");
    follow(&mut cell, "stopped", 40, q, true, true);
    assert_eq!(cell.core.desired_request(cell.t), HostRequest::Brake);
}

#[test]
fn core_a_hold_the_drives_do_not_keep_trips_the_standstill_monitor_and_the_brakes() {
    let mut cell = Cell::new(|c| {
        c.standstill_settle_s = 0.1;
        c.standstill_band_rad = 0.02;
        c.standstill_confirm_cycles = 3;
    });
    cell.gateway("ready");
    cell.tick();
    follow(&mut cell, "ready", 40, Q0, true, true); // held where it was: within the band
    assert!(cell.core.standstill.trip.is_none());
    let mut q = Q0;
    for _ in 0..10 {
        // the arm sags 5 mrad per cycle under a hold set
        q[1] -= 0.005;
        cell.t += 0.004;
        cell.gateway("ready");
        cell.cycle(at(q));
    }
    let trip = cell.health()["standstill_trip"]
        .as_str()
        .unwrap_or_default()
        .to_string();
    assert!(trip.contains("joint 2"), "{trip}");
    assert_eq!(cell.core.desired_request(cell.t), HostRequest::Brake);
    for _ in 0..2 {
        // the gateway has stopped the cell, the arm on its brakes: cleared
        cell.t += 0.004;
        cell.gateway("fault");
        cell.cycle(at(q));
    }
    assert_eq!(cell.health()["standstill_trip"], json!(null));
}

#[test]
fn core_a_command_past_the_drivers_joint_limits_is_refused_and_the_cycle_held() {
    // The driver's own joint limits (the description's less joint_limit_margin_rad), behind
    // the control law's soft walls.
    let upper = 60.0 * DEG;
    let mut cell = Cell::new(|_| {});
    let mut q = Q0;
    q[2] = upper - 0.02; // inside the driver's range, near the top of joint 3
    cell.gateway("teaching");
    let (js, _) = cell.cycle(at(q));
    assert_eq!(cell.command(&js, &q, 0.0).0, Answer::Command);
    let mut beyond = q;
    beyond[2] = upper - 0.005; // within 0.01 rad of the limit (and 0.015 from q)
    cell.t += 0.004;
    cell.gateway("teaching");
    let (js, _) = cell.cycle(at(q));
    let (answer, held) = cell.command(&js, &beyond, 0.0);
    assert!(answer == Answer::Hold && cell.core.rejected_for("out_of_range") == 1);
    assert!(held.len() == 1 && held[0].all_hold());
    assert!((held[0].q[2] - q[2]).abs() < 1e-5);
    let notes = cell.core.take_notes();
    assert!(
        notes.iter().any(|(_, _, m)| m.contains(
            "joint 3: q_cmd = 1.0422 rad outside the driver's limits [-0.7754, 1.0372] rad"
        )),
        "{notes:?}"
    );
}

#[test]
fn core_an_older_or_conflicting_lifecycle_message_is_dropped_and_counted() {
    // A late "teaching" (lower seq, or the same seq with an older stamp) must not undo a
    // "stopped"; the same seq naming another state is not what the gateway sends.
    let mut cell = Cell::new(|_| {});
    cell.gateway("teaching");
    let (js, _) = cell.cycle(Spec::default());
    assert_eq!(cell.command(&js, &Q0, 0.0).0, Answer::Command);
    cell.t += 0.004;
    let t = cell.t;
    cell.core
        .on_lifecycle(&lifecycle_payload("stopped", 7, t), t);
    cell.core
        .on_lifecycle(&lifecycle_payload("teaching", 6, t), t); // sent before the stop
    cell.core
        .on_lifecycle(&lifecycle_payload("stopped", 7, t - 0.01), t);
    cell.core
        .on_lifecycle(&lifecycle_payload("teaching", 7, t), t);
    cell.core
        .on_lifecycle(&lifecycle_payload("stopped", 7, t + 0.05), t);
    let (js, sent) = cell.cycle(Spec::default());
    assert!(commands(&sent).iter().all(|s| s.all_hold()) && !sent.is_empty()); // still stopped: held at once
    assert_ne!(cell.command(&js, &Q0, 0.0).0, Answer::Command);
    assert_eq!(
        cell.health()["lifecycle_dropped"],
        json!({"out_of_order": 2, "conflicting": 1})
    );
    let notes = cell.core.take_notes();
    assert!(
        notes.iter().any(|(_, k, m)| k == "lifecycle_out_of_order"
            && m.contains("seq 6 TEACHING after seq 7 STOPPED")),
        "{notes:?}"
    );
}

#[test]
fn core_a_bus_off_latches_a_bus_fault_until_the_bus_works_and_the_cell_is_stopped() {
    let mut cell = Cell::new(|c| c.bus_error_window_s = 0.5);
    cell.gateway("teaching");
    cell.tick();
    let (js, _) = cell.cycle(Spec::default());
    assert_eq!(cell.command(&js, &Q0, 0.0).0, Answer::Command);
    let (mut out, mut s, mut w) = (Vec::new(), Vec::new(), Vec::new());
    cell.core.on_frame(
        &error_frame(ERR_CRTL, &[0, 0x20, 0, 0, 0, 0, 0, 0]),
        cell.t,
        &mut out,
        &mut s,
        &mut w,
    );
    assert!(cell.core.bus.fault.is_none() && cell.core.bus.error_passive == 1);
    cell.core.on_frame(
        &error_frame(ERR_BUSOFF, &[0; 8]),
        cell.t,
        &mut out,
        &mut s,
        &mut w,
    );
    let health = cell.health();
    assert!(
        health["bus_fault"].as_str().unwrap().contains("bus-off") && health["bus_off"] == json!(1)
    );
    assert_eq!(cell.core.desired_request(cell.t), HostRequest::Brake);
    cell.t += 0.1; // the kernel restarts the interface (restart-ms) and frames flow again
    cell.core.on_frame(
        &error_frame(ERR_RESTARTED, &[0; 8]),
        cell.t,
        &mut out,
        &mut s,
        &mut w,
    );
    let (js, _) = cell.try_cycle(Spec::default());
    assert!(
        js.is_none(),
        "the cycle an error frame came in is dropped (the adapter's rule)"
    );
    let sets = follow(&mut cell, "teaching", 200, Q0, true, true); // 0.8 s of cycles, still teaching
    let (js, _) = cell.cycle(Spec::default());
    let (answer, _) = cell.command(&js, &Q0, 0.0);
    assert!(answer == Answer::None && cell.core.rejected_for("blocked_bus") == 1);
    assert!(
        sets.len() == 200 && sets.iter().all(|s| s.all_hold()),
        "held while the fault is latched"
    );
    assert!(
        cell.core.bus.fault.is_some(),
        "the bus alone never re-arms the cell"
    );
    follow(&mut cell, "fault", 2, Q0, true, true); // the gateway has stopped the cell: cleared
    let health = cell.health();
    assert_eq!(health["bus_fault"], json!(null));
    assert_eq!(health["bus_restarts"], json!(1));
}

#[test]
fn core_a_burst_of_bus_errors_latches_a_fault_and_scattered_ones_do_not() {
    let mut cell = Cell::new(|c| {
        c.bus_error_limit = 5;
        c.bus_error_window_s = 1.0;
    });
    cell.gateway("ready");
    let (mut out, mut s, mut w) = (Vec::new(), Vec::new(), Vec::new());
    for _ in 0..8 {
        // one every 0.3 s: never 5 within a second
        cell.t += 0.3;
        cell.core.on_frame(
            &error_frame(ERR_PROT, &[0; 8]),
            cell.t,
            &mut out,
            &mut s,
            &mut w,
        );
    }
    assert!(cell.core.bus.fault.is_none() && cell.core.bus.error_frames == 8);
    for _ in 0..5 {
        cell.t += 0.01;
        cell.core.on_frame(
            &error_frame(ERR_PROT, &[0; 8]),
            cell.t,
            &mut out,
            &mut s,
            &mut w,
        );
    }
    let fault = cell.core.bus.fault.clone().unwrap();
    assert!(
        fault.contains("5 CAN error frames within 1 s") && fault.contains("protocol violation"),
        "{fault}"
    );
    assert!(matches!(
        cell.core.blocked(cell.t),
        Some("blocked_bus" | "blocked_lifecycle")
    ));
}

// --- test_lost_cycles.py ---------------------------------------------------------------------

fn teach(cell: &mut Cell, dq: f64) -> [f64; N] {
    cell.gateway("teaching");
    cell.tick();
    let (js, _) = cell.cycle(Spec::default());
    assert_eq!(cell.command(&js, &Q0, dq).0, Answer::Command);
    Q0
}

/// One cycle whose command never comes: the driver answers at the deadline; its answer.
fn miss(cell: &mut Cell, q: [f64; N], enabling: bool) -> Answer {
    cell.t += PERIOD_S;
    cell.gateway_io("teaching", enabling, true);
    cell.cycle(at(q));
    cell.t += 0.0021; // past the answer deadline, half the period
    cell.tick();
    cell.t -= 0.0021;
    cell.answer()
}

#[test]
fn core_the_driver_holds_and_latches_after_n_lost_cycles_until_the_cell_is_stopped() {
    let mut cell = Cell::new(|c| {
        c.lost_cycles_max_consecutive = 5;
        c.hand_guiding_max_speed_m_s = 0.0;
    });
    let q = teach(&mut cell, 0.0);
    let answers: Vec<Answer> = (0..5).map(|_| miss(&mut cell, q, true)).collect();
    assert!(answers[0] == Answer::Coast && answers[4] == Answer::Hold);
    let health = cell.health();
    assert_eq!(health["lost_cycles"], json!(5));
    assert_eq!(
        health["lost_cycles_trip"],
        json!("5 command cycles lost in a row")
    );
    assert!(cell.core.take_notes().iter().any(|(l, k, m)| *l == 40
        && k == "lost"
        && m.contains("5 command cycles lost in a row; stopping the arm")));
    cell.t += PERIOD_S;
    cell.gateway("teaching");
    let (js, frames) = cell.cycle(at(q));
    assert!(
        commands(&frames).len() == 1 && commands(&frames)[0].all_hold(),
        "held at once, no longer waiting"
    );
    assert!(
        cell.command(&js, &Q0, 0.0).0 == Answer::None
            && cell.core.rejected_for("blocked_lost") == 1
    );
    cell.t += PERIOD_S;
    cell.gateway("fault"); // the gateway faults on the trip: the cell is stopped
    cell.cycle(at(q));
    assert_eq!(cell.health()["lost_cycles_trip"], json!(null));
}

#[test]
fn core_a_link_losing_every_other_cycle_trips_the_window_rule_and_the_arm_ramps_to_rest() {
    let mut cell = Cell::new(|c| {
        c.lost_cycles_max_consecutive = 5;
        c.lost_cycles_max_per_window = 4;
        c.lost_cycles_window_s = 1.0;
        c.hand_guiding_max_speed_m_s = 0.0;
        c.stop_deceleration_rad_s2 = vec![1.0; N];
    });
    let q = teach(&mut cell, 0.2);
    for _ in 0..4 {
        assert_eq!(miss(&mut cell, q, true), Answer::Coast);
        cell.t += PERIOD_S;
        cell.gateway("teaching");
        let (js, _) = cell.cycle(at(q));
        if cell.core.lost.trip.is_none() {
            assert_eq!(cell.command(&js, &q, 0.2).0, Answer::Command);
        }
    }
    let trip = cell.health()["lost_cycles_trip"]
        .as_str()
        .unwrap()
        .to_string();
    assert!(trip.contains("4 command cycles lost within 1 s"), "{trip}");
    assert_eq!(
        cell.answer(),
        Answer::Ramp,
        "stopped as for a released enabling device"
    );
}

#[test]
fn core_blocked_cycles_are_not_lost_and_hold_answers_never_coast() {
    let mut cell = Cell::new(|c| {
        c.lost_cycles_max_consecutive = 3;
        c.lost_cycle_answer = LostCycleAnswer::Hold;
    });
    let q = teach(&mut cell, 0.2);
    assert_eq!(
        miss(&mut cell, q, true),
        Answer::Hold,
        "no extrapolation asked for"
    );
    for _ in 0..10 {
        // the enabling device released: the driver stops the arm, not lost
        miss(&mut cell, q, false);
    }
    assert!(cell.core.lost.lost == 1 && cell.core.lost.trip.is_none());
}

// --- test_speed_monitor.py (the core's part) -------------------------------------------------

fn teach_and_turn_j1(cell: &mut Cell, state: &str, speed_rad_s: f64, cycles: usize) -> Vec<Answer> {
    let mut q = Q0;
    let mut answers = Vec::new();
    for _ in 0..cycles {
        cell.gateway(state);
        cell.t += PERIOD_S;
        let (js, _) = cell.cycle(at(q));
        answers.push(cell.command(&js, &q, 0.0).0);
        q[0] += speed_rad_s * PERIOD_S;
    }
    answers
}

#[test]
fn core_the_driver_brakes_once_the_arm_outruns_hand_guiding_and_clears_when_teaching_ends() {
    let mut cell = Cell::new(|_| {});
    assert!(cell.core.speed.is_some());
    let answers = teach_and_turn_j1(&mut cell, "teaching", 0.05, 20); // a slow turn
    assert!(answers.iter().all(|&a| a == Answer::Command));
    let health = cell.health();
    let peak = health["speed_peak_m_s"].as_f64().unwrap();
    assert!(
        health["speed_trip"].is_null() && 0.0 < peak && peak < 0.25,
        "{peak}"
    );
    let answers = teach_and_turn_j1(&mut cell, "teaching", 1.0, 20); // the tool at 1 m/s
    assert!(
        answers[..3].iter().all(|&a| a == Answer::Command)
            && answers[6..].iter().all(|&a| a == Answer::None),
        "{answers:?}"
    );
    assert!(cell.core.rejected_for("blocked_speed") >= 14);
    let mut here = [0.0; N];
    here.copy_from_slice(cell.core.feedback.unwrap().q()); // where the turn has got the arm
    let (_, frames) = cell.cycle(at(here)); // a tripped driver holds every cycle at once
    let held = commands(&frames);
    assert!(held.len() == 1 && held[0].all_hold() && held[0].dq.iter().all(|&v| v == 0.0));
    assert_eq!(cell.answer(), Answer::Hold);
    assert!(cell.health()["speed_trip"]
        .as_str()
        .unwrap()
        .contains("mm/s"));
    // the brakes, not a rigid hold the hand outrunning it would fight into a power cut
    assert_eq!(cell.core.desired_request(cell.t), HostRequest::Brake);
    cell.gateway("fault"); // the gateway faults on the trip...
    cell.cycle(at(here));
    assert_eq!(cell.health()["speed_trip"], json!(null)); // ...which clears it for a reset
}

#[test]
fn core_identification_runs_faster_than_hand_guiding_unmonitored() {
    let mut cell = Cell::new(|_| {});
    let answers = teach_and_turn_j1(&mut cell, "identifying", 1.0, 20);
    assert!(answers.iter().all(|&a| a == Answer::Command));
    assert_eq!(cell.health()["speed_trip"], json!(null));
}

#[test]
fn core_no_monitor_when_the_limit_is_zero_and_a_limit_needs_the_kinematics() {
    assert!(Cell::new(|c| c.hand_guiding_max_speed_m_s = 0.0)
        .core
        .speed
        .is_none());
    let err = HostCore::new(
        CoreConfig::default(),
        Box::new(FakeAdapter::new(N, None)),
        0.1,
        None,
        None,
        limits(),
    )
    .err()
    .unwrap();
    assert!(err.contains("hand_guiding_max_speed_m_s"), "{err}");
}

// --- test_cia402_cycle.py (the core's part) --------------------------------------------------

#[test]
fn core_clocks_a_host_clocked_link_and_its_exit_brake_ends_with_the_clock_frame() {
    // The core sends the adapter's clock frames (CANopen: SYNC) on its period and, on exit,
    // the BRAKE then one clock frame: a host-clocked cycle's frames take effect at the next.
    let period = 0.002;
    let mut cell = Cell::with(config(|c| c.heartbeat_period_s = 0.02), Some(period));
    let mut syncs = 0;
    for k in 0..5 {
        let now = 100.0 + k as f64 * period;
        assert!(cell.core.next_tick_s() <= now + 1e-9);
        cell.t = now;
        syncs += cell.tick().iter().filter(|s| **s == Sent::Sync).count();
    }
    assert_eq!(syncs, 5);
    assert!((cell.core.next_tick_s() - (100.0 + 5.0 * period)).abs() < 1e-9);
    cell.cycle(Spec::default());
    let mut out = Vec::new();
    cell.core.closing_frames(&mut out);
    let sent: Vec<Sent> = out.iter().map(decode).collect();
    assert_eq!(sent[0], Sent::Request(HostRequest::Brake as u8));
    assert_eq!(sent.last(), Some(&Sent::Sync));
    assert_eq!(sent.iter().filter(|s| **s == Sent::Sync).count(), 1);
    assert!(commands(&sent[1..sent.len() - 1])[0].all_hold());
}

// --- test_can_driver_logic.py (the core's part) ----------------------------------------------

const T_RIG: f64 = 1000.0;

/// The driver tests' settings: cycles of 20 ms, the clock at 1000 s.
fn rig(edit: impl FnOnce(&mut CoreConfig)) -> Cell {
    let mut cell = Cell::new(|c| {
        c.deadline_s = 0.010;
        c.heartbeat_period_s = 0.1;
        c.max_following_error_rad = vec![0.05; N];
        c.max_velocity_rad_s = vec![1.0; N];
        edit(c);
    });
    cell.t = T_RIG;
    cell
}

fn teaching(edit: impl FnOnce(&mut CoreConfig)) -> Cell {
    let mut cell = rig(edit);
    cell.gateway("teaching");
    cell.tick();
    cell
}

fn slow(q: [f64; N]) -> Spec {
    Spec {
        q,
        period_us: 20000,
        ..Spec::default()
    }
}

#[test]
fn core_an_unanswered_cycle_is_held_at_the_deadline_or_before_the_next_cycle() {
    for (period_us, answer_by_s) in [(20000, 0.010), (4000, 0.002)] {
        let mut cell = teaching(|_| {});
        cell.cycle(Spec {
            period_us,
            ..Spec::default()
        });
        cell.t += answer_by_s - 1e-4;
        assert!(commands(&cell.tick()).is_empty());
        cell.t += 2e-4;
        let hold = commands(&cell.tick());
        assert_eq!(hold.len(), 1);
        assert!(hold[0].all_hold() && hold[0].dq.iter().all(|&v| v == 0.0));
        assert!(hold[0].counters.iter().all(|&c| c == cell.counter));
        assert_close(&hold[0].q, &Q0, 1e-6);
        cell.t += 0.05;
        assert!(
            commands(&cell.tick()).is_empty(),
            "a cycle is answered once"
        );
    }
}

#[test]
fn core_forwarded_command_and_the_joint_state_echo() {
    let mut cell = teaching(|_| {});
    let (js, _) = cell.cycle(slow(Q0));
    assert_close(&js.q_cmd, &Q0, 1e-6); // measured q before any command
    cell.t += 0.002;
    let (answer, sets) = cell.command(&js, &plus(Q0, 0.01), 0.2);
    assert!(answer == Answer::Command && sets.len() == 1);
    assert!(sets[0].none_hold() && sets[0].counters.iter().all(|&c| c == cell.counter));
    assert_close(&sets[0].q, &plus(Q0, 0.01), 1e-6);
    assert_close(&sets[0].dq, &[0.2; N], 1e-4);
    let (nxt, _) = cell.cycle(slow(Q0));
    assert_close(&nxt.q_cmd, &plus(Q0, 0.01), 1e-12);
    assert_close(&nxt.dq_cmd, &[0.2; N], 1e-12);
    cell.command(&js, &Q0, 0.0); // a second command for an answered cycle is late
    assert_eq!(cell.core.rejected_for("late_cycle"), 1);
}

#[test]
fn core_age_counts_from_the_driver_stamp_even_if_the_command_claims_fresh() {
    let mut cell = teaching(|_| {});
    let (js, _) = cell.cycle(slow(Q0));
    cell.t += 0.011;
    let t = cell.t;
    let (answer, sets) = cell.command_stamped(js.cycle, t, &Q0, 0.0); // lies about its age
    assert_eq!(cell.core.rejected_for("stale"), 1);
    assert!(answer == Answer::Hold && sets[0].all_hold());
}

#[test]
fn core_following_error_and_velocity_limits_are_per_joint() {
    let mut cell = teaching(|c| c.max_following_error_rad = vec![0.05, 0.05, 0.05, 0.2, 0.2, 0.2]);
    let (js, _) = cell.cycle(slow(Q0));
    let mut q = Q0;
    q[4] += 0.15; // within joint 5's 0.2 rad
    assert_eq!(cell.command(&js, &q, 0.0).1.len(), 1);
    let (js, _) = cell.cycle(slow(Q0));
    let mut q = Q0;
    q[1] += 0.06; // beyond joint 2's 0.05 rad
    let (_, sets) = cell.command(&js, &q, 0.0);
    assert_eq!(cell.core.rejected_for("out_of_range"), 1);
    assert!(sets[0].all_hold(), "rejected: held at once");
    let (js, _) = cell.cycle(slow(Q0));
    cell.command(&js, &Q0, 1.01);
    assert_eq!(cell.core.rejected_for("out_of_range"), 2);
}

#[test]
fn core_hold_latches_the_last_forwarded_command_and_ignores_sag() {
    let mut cell = teaching(|_| {});
    let (js, _) = cell.cycle(slow(Q0));
    cell.command(&js, &plus(Q0, 0.02), 0.0);
    let mut q = Q0;
    for _ in 0..5 {
        // commands stop; the arm sags 5 mrad per cycle (fast enough for the speed monitor:
        // once it trips, the cycle is held at once, not at its deadline; as in Python's test,
        // the frames of both count)
        q = plus(q, -0.005);
        let (_, mut sent) = cell.cycle(slow(q));
        cell.t += 0.011;
        sent.extend(cell.tick());
        let sets = commands(&sent);
        assert_eq!(sets.len(), 1);
        assert_close(&sets[0].q, &plus(Q0, 0.02), 1e-6);
    }
}

#[test]
fn core_hold_latches_the_measured_position_if_the_last_command_is_too_far() {
    let mut cell = teaching(|_| {});
    let (js, _) = cell.cycle(slow(Q0));
    cell.command(&js, &plus(Q0, 0.04), 0.0);
    let q_then = plus(Q0, -0.02); // 0.06 rad from the last command: beyond the 0.05 rad limit
    let (_, mut sent) = cell.cycle(slow(q_then));
    cell.t += 0.011;
    sent.extend(cell.tick());
    let hold = commands(&sent);
    assert!(hold.len() == 1 && hold[0].all_hold());
    assert_close(&hold[0].q, &q_then, 1e-6);
    let (_, mut sent) = cell.cycle(slow(plus(q_then, -0.01))); // not re-sampled while holding
    cell.t += 0.011;
    sent.extend(cell.tick());
    let hold = commands(&sent);
    assert_eq!(hold.len(), 1);
    assert_close(&hold[0].q, &q_then, 1e-6);
}

#[test]
fn core_on_brakes_the_hold_follows_the_measured_position() {
    let mut cell = rig(|_| {}); // STOPPED: only holds, controller BRAKED
    for k in 0..3 {
        let q = plus(Q0, 0.01 * k as f64);
        let (_, sent) = cell.cycle(Spec {
            state: ControllerState::Braked,
            ..slow(q)
        });
        let holds = commands(&sent);
        assert_eq!(holds.len(), 1, "blocked cycles are held at once");
        assert_close(&holds[0].q, &q, 1e-6);
    }
}

#[test]
fn core_blocked_reasons() {
    let mut cell = rig(|_| {});
    let mut sets = Vec::new();
    cell.gateway_io("teaching", false, true);
    let (js, sent) = cell.cycle(slow(Q0));
    sets.extend(commands(&sent));
    cell.command(&js, &Q0, 0.0);
    cell.gateway("ready");
    let (js, sent) = cell.cycle(slow(Q0));
    sets.extend(commands(&sent));
    cell.command(&js, &Q0, 0.0);
    cell.gateway("teaching");
    let (js, sent) = cell.cycle(Spec {
        state: ControllerState::Braked,
        ..slow(Q0)
    });
    sets.extend(commands(&sent));
    cell.command(&js, &Q0, 0.0);
    let c = &cell.core;
    assert_eq!(
        (
            c.rejected_for("blocked_enabling"),
            c.rejected_for("blocked_lifecycle"),
            c.rejected_for("blocked_controller")
        ),
        (1, 1, 1)
    );
    assert!(sets.len() == 3 && sets.iter().all(|s| s.all_hold()));
}

#[test]
fn core_the_servo_request_follows_a_fresh_lifecycle() {
    let mut cell = rig(|_| {});
    let first = cell.tick();
    assert!(first.contains(&Sent::Heartbeat) && requests(&first) == vec![HostRequest::Brake]);
    cell.gateway("ready");
    assert_eq!(requests(&cell.tick()), vec![HostRequest::ServoOn]);
    cell.t += 0.05;
    cell.gateway("ready");
    assert!(cell.tick().is_empty(), "no repeat between heartbeats");
    cell.t += 0.051;
    cell.gateway("ready");
    let repeat = cell.tick();
    assert!(repeat.contains(&Sent::Heartbeat) && requests(&repeat) == vec![HostRequest::ServoOn]);
    cell.t += 0.25; // the gateway fell silent
    assert_eq!(requests(&cell.tick()), vec![HostRequest::Brake]);
    let notes = cell.core.take_notes();
    let said: Vec<&str> = notes
        .iter()
        .filter(|n| n.1 == "request")
        .map(|n| n.2.as_str())
        .collect();
    assert_eq!(
        said,
        vec![
            "requesting BRAKE from the controller",
            "requesting SERVO_ON from the controller",
            "requesting BRAKE from the controller"
        ]
    );
}

#[test]
fn core_a_future_stamp_does_not_keep_the_lifecycle_fresh() {
    let mut cell = rig(|_| {});
    let t = cell.t;
    cell.core
        .on_lifecycle(&lifecycle_payload("teaching", 1, t + 3600.0), t);
    cell.core.on_io(&io_payload(t, true, true), t);
    assert_eq!(requests(&cell.tick()), vec![HostRequest::Brake]);
    assert_eq!(cell.core.blocked(t), Some("blocked_lifecycle"));
}

#[test]
fn core_the_operators_reset_is_sent_once_and_only_to_a_faulted_controller() {
    let mut cell = rig(|_| {});
    let mut sent = Vec::new();
    cell.gateway("fault");
    cell.cycle(Spec {
        state: ControllerState::Fault,
        ..slow(Q0)
    });
    sent.extend(cell.tick());
    cell.gateway("stopped");
    assert_eq!(
        cell.core.next_tick_s(),
        f64::NEG_INFINITY,
        "a reset is due at once"
    );
    sent.extend(cell.tick());
    sent.extend(cell.tick());
    assert_eq!(
        requests(&sent),
        vec![
            HostRequest::Brake,
            HostRequest::ResetFault,
            HostRequest::Brake
        ]
    );
    cell.gateway("stopped");
    assert!(!requests(&cell.tick()).contains(&HostRequest::ResetFault));
    cell.gateway("fault");
    cell.cycle(Spec {
        state: ControllerState::Braked,
        ..slow(Q0)
    }); // the controller is not faulted
    cell.gateway("stopped");
    assert!(!requests(&cell.tick()).contains(&HostRequest::ResetFault));
}

#[test]
fn core_a_faulted_controller_is_named_in_the_health_in_the_adapters_words() {
    let mut cell = rig(|_| {});
    cell.gateway("fault");
    cell.cycle(Spec {
        state: ControllerState::Fault,
        ..slow(Q0)
    });
    let health = cell.health();
    // the fake adapter has no words of its own: the fault's kind
    assert_eq!(health["controller_fault_text"], json!("FOLLOWING_ERROR"));
    cell.cycle(Spec {
        state: ControllerState::Braked,
        ..slow(Q0)
    });
    assert_eq!(cell.health()["controller_fault_text"], json!(null));
}

#[test]
fn core_the_cycle_counter_is_widened_across_the_wrap_and_repeats_are_dropped() {
    let mut cell = rig(|_| {});
    for (counter, cycle) in [(65534, 65534), (65535, 65535), (0, 65536), (2, 65538)] {
        // a lost cycle leaves a gap
        assert_eq!(
            cell.cycle(Spec {
                counter: Some(counter),
                ..slow(Q0)
            })
            .0
            .cycle,
            cycle
        );
    }
    let (js, _) = cell.try_cycle(Spec {
        counter: Some(2),
        state: ControllerState::Hold,
        ..Spec::default()
    });
    assert!(js.is_none(), "a repeated cycle is not published twice");
    assert_eq!(cell.core.cycles, 4);
    assert!(cell
        .core
        .take_notes()
        .iter()
        .any(|(l, k, m)| *l == 30 && k == "dup" && m == "controller repeated cycle 2"));
}

#[test]
fn core_the_health_message() {
    let mut cell = teaching(|_| {});
    cell.cycle(slow(Q0));
    cell.t += 0.2;
    cell.tick();
    assert!(
        cell.core.health_due(cell.t)
            && !cell.core.health_due(cell.t + 0.05)
            && cell.core.health_due(cell.t + 0.1)
    );
    let health = cell.health();
    assert_eq!(health["link_ok"], json!(false)); // 0.2 s since the last cycle > controller_timeout_s
    assert_eq!(health["controller_state"], json!("EXTERNAL"));
    assert_eq!(health["controller_fault"], json!("NONE"));
    assert_eq!(health["controller_fault_text"], json!(null));
    assert_eq!(health["held"], json!(1));
    assert_eq!(health["servo_request"], json!("SERVO_ON"));
    // Python's keys and value types, then the adapter's own entries
    let python = [
        "controller_state",
        "controller_fault",
        "controller_fault_text", // added by the compiled core: the operator's reason
        "link_ok",
        "servo_request",
        "cycles",
        "forwarded",
        "held",
        "ramped",
        "standstill_trip",
        "lost_cycles",
        "lost_cycles_trip",
        "coasted",
        "unanswered",
        "rejected",
        "bad_frames",
        "unknown_frames", // added by the compiled core: the fuzz tests count ignored ids
        "implausible_cycles",
        "incomplete_cycles",
        "corrupt_cycles",
        "bad_inputs",
        "lifecycle_dropped",
        "speed_trip",
        "speed_peak_m_s",
        "bus_fault",
        "bus_error_frames",
        "bus_off",
        "bus_restarts",
        "bus_error_passive",
        "current_zero_a",
        "current_zero_source",
        "current_zero_samples",
        "current_zero_ready",
        "current_zero_measured_a",
        "current_zero_noise_a",
        "current_zero_drift_a",
    ];
    let mut keys: Vec<&str> = health.keys().map(String::as_str).collect();
    keys.sort();
    let mut want: Vec<&str> = python.iter().copied().chain(["fake_frames"]).collect();
    want.sort();
    assert_eq!(keys, want);
    assert_eq!(
        health["cycles"],
        json!(1),
        "the core's key wins over the adapter's"
    );
    let rejected = health["rejected"].as_object().unwrap();
    assert_eq!(rejected.keys().len(), REJECT_REASONS.len());
    assert!(rejected.values().all(|v| v.is_u64()));
    for key in [
        "cycles",
        "forwarded",
        "held",
        "ramped",
        "lost_cycles",
        "coasted",
        "unanswered",
        "bad_frames",
        "bus_off",
    ] {
        assert!(health[key].is_u64(), "{key}");
    }
    assert!(health["current_zero_ready"].is_boolean() && health["current_zero_drift_a"].is_null());
    assert_eq!(
        health["current_zero_a"],
        json!([0.0, 0.0, 0.0, 0.0, 0.0, 0.0])
    );
    assert!(health["speed_peak_m_s"].is_f64());
}

#[test]
fn core_close_brakes_and_holds() {
    let mut cell = teaching(|_| {});
    cell.cycle(slow(Q0));
    let mut out = Vec::new();
    cell.core.closing_frames(&mut out);
    let sent: Vec<Sent> = out.iter().map(decode).collect();
    assert_eq!(requests(&sent), vec![HostRequest::Brake]);
    assert_eq!(sent[0], Sent::Request(0));
    assert!(commands(&sent[1..])[0].all_hold() && sent.len() == 1 + N);
}

#[test]
fn core_a_late_answer_coasts_on_the_last_command_then_holds_on_the_next() {
    // One late command costs nothing: the driver re-sends the last forwarded command moved on
    // by its velocity; a second late cycle in a row holds, where the coast went.
    let mut cell = teaching(|_| {});
    let (js, _) = cell.cycle(Spec::default());
    let (_, sent) = cell.command(&js, &plus(Q0, 0.001), 0.2);
    assert!(sent[0].none_hold());
    cell.t += PERIOD_S;
    let (late, _) = cell.cycle(Spec::default()); // control is late for this one
    assert_eq!(late.flags & (PREV_COAST | PREV_HOLD), 0); // the last was the command
    cell.t += 0.5 * PERIOD_S + 1e-4;
    let coast = commands(&cell.tick());
    assert!(coast[0].none_hold() && coast[0].counters.iter().all(|&c| c == cell.counter));
    assert_close(&coast[0].q, &plus(Q0, 0.001 + 0.2 * PERIOD_S), 2e-6);
    assert_close(&coast[0].dq, &[0.2; N], 1e-4);
    assert_eq!(cell.core.coasted, 1);
    cell.t += PERIOD_S;
    let (after_coast, _) = cell.cycle(Spec::default()); // late again: two cycles after the command
    assert!(after_coast.flags & PREV_COAST != 0); // the recorder leaves the next cycles out
    cell.t += 0.5 * PERIOD_S + 1e-4;
    let hold = commands(&cell.tick());
    assert!(hold[0].all_hold() && hold[0].dq.iter().all(|&v| v == 0.0));
    assert_close(&hold[0].q, &plus(Q0, 0.001 + 0.2 * PERIOD_S), 2e-6);
    cell.t += PERIOD_S;
    assert!(cell.cycle(Spec::default()).0.flags & PREV_HOLD != 0);
}

// --- what the port adds: notes, bad input, allocation, construction ---------------------------

#[test]
fn core_notes_are_rate_limited_per_key_and_count_what_they_held_back() {
    let mut cell = Cell::new(|_| {});
    cell.gateway("ready"); // READY: every command is blocked
    let mut notes = Vec::new();
    for k in 0..500 {
        // 2 s of cycles at 4 ms, a command each
        cell.t = T0 + k as f64 * PERIOD_S;
        if k % 25 == 0 {
            cell.gateway("ready");
        }
        let (js, _) = cell.cycle(Spec::default());
        cell.command(&js, &Q0, 0.0);
        notes.extend(cell.core.take_notes());
    }
    let blocked: Vec<&(u8, String, String)> = notes
        .iter()
        .filter(|n| n.1 == "blocked_lifecycle")
        .collect();
    assert_eq!(blocked.len(), 2, "{blocked:?}"); // at 0 s and at 1 s
    assert_eq!(blocked[0].0, 20);
    assert!(blocked[0]
        .2
        .starts_with("JointCommand not forwarded (blocked_lifecycle): cycle 1"));
    assert!(
        blocked[1].2.ends_with(" (+249 similar in the last 1 s)"),
        "{}",
        blocked[1].2
    );
    assert_eq!(cell.core.rejected_for("blocked_lifecycle"), 500);
}

#[test]
fn core_a_full_note_queue_drops_and_says_so() {
    let mut cell = Cell::new(|_| {});
    for k in 0..200 {
        // alternating requests: each change is a note of its own (not rate-limited)
        cell.t = T0 + k as f64 * 0.3;
        cell.gateway("ready");
        cell.tick();
    }
    let notes = cell.core.take_notes();
    assert!(notes.len() <= crate::core::NOTE_QUEUE + 1);
    let mut cell = Cell::new(|_| {});
    for k in 0..100 {
        cell.t = T0 + k as f64 * 0.3;
        cell.gateway(if k % 2 == 0 { "ready" } else { "stopped" });
        cell.tick();
    }
    let notes = cell.core.take_notes();
    assert_eq!(notes.len(), crate::core::NOTE_QUEUE + 1);
    let last = &notes[notes.len() - 1];
    assert!(
        last.1 == "notes" && last.2.contains("notes dropped"),
        "{last:?}"
    );
    assert!(cell.core.take_notes().is_empty());
}

#[test]
fn core_bad_input_is_counted_never_a_panic() {
    let mut cell = Cell::new(|_| {});
    cell.gateway("teaching");
    let (js, _) = cell.cycle(Spec::default());
    let t = cell.t;
    let mut out = Vec::new();
    let (mut s, mut w) = (Vec::new(), Vec::new());
    let mut seed = 0x2545_F491_4F6C_DD1Du64;
    let mut bytes = |len: usize| -> Vec<u8> {
        (0..len)
            .map(|_| {
                seed ^= seed << 13;
                seed ^= seed >> 7;
                seed ^= seed << 17;
                seed as u8
            })
            .collect()
    };
    let mut payloads: Vec<Vec<u8>> = vec![
        vec![],
        b"{".to_vec(),
        b"[]".to_vec(),
        b"{\"state\": \"teaching\"}".to_vec(),
        b"{\"state\": \"teaching\", \"seq\": 1, \"stamp_s\": 1e999}".to_vec(),
        b"LTJC".to_vec(),
        b"LTIO\x01".to_vec(),
        command_payload(js.cycle, js.stamp_s, t, &[f64::NAN; N], &[0.0; N]),
        command_payload(js.cycle, f64::INFINITY, t, &Q0, &[0.0; N]),
        command_payload(js.cycle, js.stamp_s, t, &[0.0; 17], &[0.0; 17]),
        io_payload(f64::NAN, true, true),
    ];
    for len in [1, 5, 12, 34, 48, 130, 200] {
        for _ in 0..20 {
            payloads.push(bytes(len));
        }
    }
    let bad_before = cell.core.bad_inputs;
    for p in &payloads {
        cell.core.on_lifecycle(p, t);
        cell.core.on_io(p, t);
        cell.core.on_command(p, t, &mut out);
    }
    assert!(cell.core.bad_inputs - bad_before >= 2 * payloads.len() as u64 - 2);
    assert!(cell.core.rejected_for("bad_message") >= payloads.len() as u64 - 2);
    for id in [0u32, 0x100, 0x105, 0x106, 0x180, 0x7FF] {
        for len in [0usize, 1, 8, 26, 64] {
            let data = bytes(len);
            let mut f = Frame::fd(id, &data, false);
            f.len = len as u8;
            cell.core.on_frame(&f, t, &mut out, &mut s, &mut w);
            cell.core.on_frame(
                &error_frame(id & 0x1FF, &data[..len.min(8)]),
                t,
                &mut out,
                &mut s,
                &mut w,
            );
        }
    }
    let mut oversized = Frame::empty(0x100);
    oversized.len = 200;
    cell.core.on_frame(&oversized, t, &mut out, &mut s, &mut w);
    cell.try_cycle(Spec {
        q: [f64::NAN; N],
        ..Spec::default()
    }); // implausible: dropped
    cell.core.on_tick(t + 1.0, &mut out);
    cell.core.health(t + 1.0);
    cell.core.closing_frames(&mut out);
    // an adapter that reports a NaN position with the plausibility check off: no panic
    let mut cell = Cell::new(|c| c.feedback_max_joint_speed_rad_s = 0.0);
    cell.gateway("teaching");
    let (js, _) = cell.cycle(Spec::default());
    cell.command(&js, &Q0, 0.1);
    let (js, _) = cell.cycle(Spec {
        q: [f64::NAN; N],
        ..Spec::default()
    });
    assert!(js.q.iter().all(|v| v.is_nan()));
    cell.command(&js, &Q0, 0.0);
    cell.t += 0.01;
    cell.tick();
    cell.health();
    cell.core.closing_frames(&mut out);
}

#[test]
fn core_construction_refuses_what_does_not_fit() {
    let new = |cfg: CoreConfig, joints: usize, limits: (Vec<f64>, Vec<f64>)| {
        HostCore::new(
            cfg,
            Box::new(FakeAdapter::new(joints, None)),
            0.1,
            None,
            Some(datasheet_chain()),
            limits,
        )
        .err()
        .unwrap_or_default()
    };
    assert!(new(CoreConfig::default(), 5, limits()).contains("adapter is built for 5"));
    assert!(new(config(|c| c.heartbeat_period_s = 0.3), N, limits()).contains("heartbeat_period_s"));
    assert!(new(CoreConfig::default(), N, (vec![0.0; 5], vec![1.0; 6])).contains("joint limits"));
    assert!(
        new(config(|c| c.max_velocity_rad_s = vec![1.0; 3]), N, limits())
            .contains("max_velocity_rad_s")
    );
    let stored = Some((vec![0.1; N], 250, vec![0.02; N]));
    let core = HostCore::new(
        CoreConfig::default(),
        Box::new(FakeAdapter::new(N, None)),
        0.1,
        stored,
        Some(datasheet_chain()),
        limits(),
    );
    assert!(
        core.unwrap().current_zero.ready,
        "the commissioning's zero is ready at once"
    );
}

#[test]
fn core_the_forwarding_path_does_not_allocate() {
    let mut cell = Cell::new(|_| {});
    cell.gateway("teaching");
    cell.tick();
    let mut commands_in: Vec<Vec<u8>> = Vec::new();
    let mut frames_in: Vec<Vec<Frame>> = Vec::new();
    for k in 0..300 {
        frames_in.push(cell.frames(Spec::default()));
        commands_in.push(command_payload(
            k + 1,
            T0 + (k + 1) as f64 * PERIOD_S,
            0.0,
            &Q0,
            &[0.0; N],
        ));
    }
    // warm up: one cycle through every path the loop below takes
    let mut t = T0;
    let before = cell.core.forwarded;
    let run = |cell: &mut Cell, frames: &[Frame], cmd: &[u8], t: f64| {
        for f in frames {
            cell.out.clear();
            cell.core
                .on_frame(f, t, &mut cell.out, &mut cell.state, &mut cell.window);
        }
        cell.out.clear();
        cell.core.on_command(cmd, t + 0.001, &mut cell.out);
        cell.out.clear();
        cell.core.on_tick(t + 0.0015, &mut cell.out);
    };
    let refresh = |cell: &mut Cell, t: f64| {
        cell.seq += 1;
        let lc = lifecycle_payload("teaching", cell.seq, t);
        let io = io_payload(t, true, true);
        (lc, io)
    };
    for k in 0..5 {
        t += PERIOD_S;
        run(&mut cell, &frames_in[k], &commands_in[k], t);
    }
    let mut counted = 0;
    for k in 5..300 {
        t += PERIOD_S;
        if k % 25 == 0 {
            // the gateway's 20 Hz (its JSON decode is not on the cycle)
            let (lc, io) = refresh(&mut cell, t);
            cell.core.on_lifecycle(&lc, t);
            cell.core.on_io(&io, t);
        }
        let start = allocations();
        run(&mut cell, &frames_in[k], &commands_in[k], t);
        counted += allocations() - start;
    }
    assert_eq!(cell.core.forwarded - before, 300, "every command forwarded");
    assert_eq!(counted, 0, "allocations on the forwarding path");
}

#[test]
fn core_a_blocked_cell_does_not_allocate_per_cycle() {
    // READY for minutes: every cycle held at once, every command rejected (blocked); after
    // the first notes, the rate limit keeps the rest unbuilt
    let mut cell = Cell::new(|_| {});
    cell.gateway("ready");
    cell.tick();
    let frames_in: Vec<Vec<Frame>> = (0..220).map(|_| cell.frames(Spec::default())).collect();
    let commands_in: Vec<Vec<u8>> = (0..220u32)
        .map(|k| command_payload(k + 1, T0, 0.0, &Q0, &[0.0; N]))
        .collect();
    let mut counted = 0;
    for k in 0..220 {
        let t = T0 + k as f64 * PERIOD_S;
        if k % 25 == 0 {
            // the gateway's 20 Hz (its JSON decode is not on the cycle)
            cell.seq += 1;
            let lc = lifecycle_payload("ready", cell.seq, t);
            cell.core.on_lifecycle(&lc, t);
            cell.core.on_io(&io_payload(t, true, true), t);
        }
        let start = allocations();
        for f in &frames_in[k] {
            cell.out.clear();
            cell.core
                .on_frame(f, t, &mut cell.out, &mut cell.state, &mut cell.window);
        }
        cell.out.clear();
        let outcome = cell
            .core
            .on_command(&commands_in[k], t + 0.001, &mut cell.out);
        assert_eq!(outcome.answer, Answer::None);
        cell.out.clear();
        cell.core.on_tick(t + 0.0015, &mut cell.out);
        if k >= 10 {
            counted += allocations() - start;
        }
    }
    assert_eq!(cell.core.rejected_for("blocked_lifecycle"), 220);
    assert_eq!(cell.core.held, 220);
    assert_eq!(counted, 0, "allocations while blocked");
    let notes = cell.core.take_notes();
    assert_eq!(
        notes.iter().filter(|n| n.1 == "blocked_lifecycle").count(),
        1
    );
}
