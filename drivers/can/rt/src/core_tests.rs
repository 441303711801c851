//! The host core cycle by cycle (the Rust port of tests/unit/test_can_core.py, the core's
//! scenarios of test_can_driver_logic.py, test_lost_cycles.py, test_speed_monitor.py and
//! test_cia402_cycle.py): frames and payloads in, frames and payloads out, an explicit clock,
//! and a fake adapter with a trivial protocol so the tests do not depend on a vendor's codec.
//!
//! Here: the cell (the core with the fake adapter of core_fake_adapter_tests.rs, an explicit
//! clock, its payloads); the tests, one module per topic: forwarding, stop, monitor,
//! driver_logic, port and allocation (core_<topic>_tests.rs).

use serde_json::json;

use crate::adapter::{ControllerState, HostRequest};
use crate::core::{Answer, HostCore, KinematicChain, REJECT_REASONS};
use crate::core_config::{CoreConfig, LostCycleAnswer};
use crate::frame::Frame;

use self::fake_adapter::*;

#[path = "core_allocation_tests.rs"]
mod allocation;
#[path = "core_driver_logic_tests.rs"]
mod driver_logic;
#[path = "core_fake_adapter_tests.rs"]
mod fake_adapter;
#[path = "core_forwarding_tests.rs"]
mod forwarding;
#[path = "core_monitor_tests.rs"]
mod monitor;
#[path = "core_port_tests.rs"]
mod port;
#[path = "core_stop_tests.rs"]
mod stop;

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

// --- the driver tests' rig (test_can_driver_logic.py) ----------------------------------------

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
