//! The CiA 402 adapter's tests (cia402.rs): the standard's state machine, the cycle's units,
//! counters, losses and faults, the commands it refuses, and the tables it does not take.

use super::*;
use crate::adapter::Adapter;
use crate::frame::Frame;
use serde_json::json;
use serde_json::Value;

const SW_NOT_READY: u16 = 0x0200;
const SW_SWITCH_ON_DISABLED: u16 = 0x0250;
const SW_READY: u16 = 0x0231;
const SW_SWITCHED_ON: u16 = 0x0233;
const SW_OPERATION_ENABLED: u16 = 0x0237;
const SW_QUICK_STOP: u16 = 0x0217;
const SW_FAULT: u16 = 0x0218;
const INC: f64 = 1048576.0;

fn gear(k: usize) -> f64 {
    100.0 - 50.0 * (k % 2) as f64
}

fn inc_per_rad(k: usize) -> f64 {
    INC * gear(k) / (2.0 * std::f64::consts::PI)
}

/// Tables as rt_cia402_tables.py makes them: drives 1..n, the EDS's layouts, 10 A / 2 A rated.
fn tables(n: usize) -> Value {
    let joints: Vec<Value> = (0..n)
        .map(|k| {
            let nid = k as u32 + 1;
            json!({
                "node_id": nid,
                "inc_per_rad": format!("{:?}", inc_per_rad(k)),
                "amps_per_mille": if k % 2 == 0 { "0.01" } else { "0.002" },
                "rpdo1": {"cob_id": 0x200 + nid, "format": "<Hl", "objects": [0x6040, 0x607A]},
                "rpdo2": {"cob_id": 0x300 + nid, "format": "<l", "objects": [0x60B1]},
                "tpdo1": {"cob_id": 0x180 + nid, "format": "<Hl", "objects": [0x6041, 0x6064]},
                "tpdo2": {"cob_id": 0x280 + nid, "format": "<lhh",
                          "objects": [0x606C, 0x6078, 0x6077]},
                "state": "not ready to switch on",
                "nmt_state": -1,
                "heartbeat_s": null,
                "emcy_code": 0,
                "last_target_inc": null,
                "position_inc": 0,
                "tpdo1_values": null,
                "tpdo2_values": null,
            })
        })
        .collect();
    json!({
        "format": TABLES_FORMAT,
        "adapter": "cia402",
        "n_joints": n,
        "mode": "csp",
        "host_node_id": 127,
        "sync_cob_id": 0x80,
        "nmt_operational": 5,
        "counter_modulus": 65536,
        "clock_period_s": "0.008",
        "host_heartbeat_timeout_s": "0.1",
        "producer_heartbeat_s": "0.05",
        "heartbeat_late_factor": "3.0",
        "request": "BRAKE",
        "dropped": "",
        "disabled_at_cycle": null,
        "host_disable_cycles": 3,
        "sync_count": 0,
        "corrupt": false,
        "joints": joints,
    })
}

fn adapter(n: usize) -> Cia402Adapter {
    Cia402Adapter::from_tables(&tables(n)).unwrap()
}

fn tpdo1(k: usize, statusword: u16, position: i32) -> Frame {
    let mut d = [0u8; 6];
    d[..2].copy_from_slice(&statusword.to_le_bytes());
    d[2..].copy_from_slice(&position.to_le_bytes());
    Frame::classic(0x181 + k as u32, &d)
}

fn tpdo2(k: usize, velocity: i32, current: i16) -> Frame {
    let mut d = [0u8; 8];
    d[..4].copy_from_slice(&velocity.to_le_bytes());
    d[4..6].copy_from_slice(&current.to_le_bytes());
    d[6..].copy_from_slice(&(!current).to_le_bytes());
    Frame::classic(0x281 + k as u32, &d)
}

/// SYNC, then every drive's TPDO1 and TPDO2 at `now`; the feedback of the last one.
fn cycle(a: &mut Cia402Adapter, statuswords: &[u16], q: &[f64], now: f64) -> Feedback {
    let mut out = Vec::new();
    a.clock_frames(&mut out);
    assert_eq!(out.len(), 1);
    assert_eq!((out[0].id, out[0].len), (0x080, 0));
    let n = statuswords.len();
    let mut last = None;
    for k in 0..n {
        let inc = (q[k] * inc_per_rad(k)).round() as i32;
        assert!(a.feed(&tpdo1(k, statuswords[k], inc), now).is_none());
        last = a.feed(&tpdo2(k, 2 * inc, 500 - 750 * k as i16), now);
        assert_eq!(last.is_some(), k == n - 1);
    }
    last.unwrap()
}

fn controlwords(frames: &[Frame]) -> Vec<u16> {
    frames
        .iter()
        .filter(|f| (0x200..0x280).contains(&f.id))
        .map(|f| u16::from_le_bytes([f.data[0], f.data[1]]))
        .collect()
}

fn i32_at(f: &Frame, at: usize) -> i32 {
    i32::from_le_bytes(f.data[at..at + 4].try_into().unwrap())
}

#[test]
fn every_statusword_codes_the_state_of_the_standards_table() {
    for (sw, want) in [
        (0x0000, DriveState::NotReadyToSwitchOn),
        (0x0250, DriveState::SwitchOnDisabled),
        (0x0231, DriveState::ReadyToSwitchOn),
        (0x0233, DriveState::SwitchedOn),
        (0x0237, DriveState::OperationEnabled),
        (0x0217, DriveState::QuickStopActive),
        (0x021F, DriveState::FaultReactionActive),
        (0x0218, DriveState::Fault),
        (0x002F, DriveState::FaultReactionActive),
        (0x0061, DriveState::NotReadyToSwitchOn), // bits 5 and 6 together: unusual
        (0xFFFF, DriveState::NotReadyToSwitchOn),
    ] {
        assert_eq!(decode_state(sw), want, "0x{sw:04X}");
    }
    for sw in 0..=u16::MAX {
        let s = decode_state(sw);
        let first = STATUSWORD_STATES.iter().find(|&&(m, v, _)| sw & m == v);
        assert_eq!(first.map_or(DriveState::NotReadyToSwitchOn, |t| t.2), s);
        assert_eq!(
            decode_state(sw & 0x6F),
            s,
            "only bits 0-3, 5, 6 code the state"
        );
    }
    for s in DriveState::ALL {
        assert_eq!(DriveState::from_text(s.text()), Some(s));
    }
}

#[test]
fn the_controlwords_walk_the_state_machine_by_the_standards_transitions() {
    use DriveState as S;
    let walk = |mut state: DriveState, request: HostRequest| {
        let mut steps = Vec::new();
        while let (cw, Some(step)) = controlword_for(state, request) {
            let t = TRANSITIONS.iter().find(|t| t.0 == step).unwrap();
            // 3 towards operation enabled: switch on + enable operation (3, then 4)
            let sent = if (step, request) == (3, HostRequest::ServoOn) {
                CW_ENABLE_OPERATION
            } else {
                t.3
            };
            assert_eq!((t.1, sent), (state, cw), "transition {step}");
            steps.push(step);
            state = t.2;
            if steps.len() > 5 {
                break;
            }
        }
        (steps, state)
    };
    let on = HostRequest::ServoOn;
    let brake = HostRequest::Brake;
    assert_eq!(
        walk(S::SwitchOnDisabled, on),
        (vec![2, 3, 4], S::OperationEnabled)
    );
    assert_eq!(walk(S::OperationEnabled, on).0, Vec::<u8>::new());
    assert_eq!(
        controlword_for(S::OperationEnabled, on),
        (CW_ENABLE_OPERATION, None)
    );
    assert_eq!(
        walk(S::OperationEnabled, brake),
        (vec![5, 6], S::ReadyToSwitchOn)
    );
    assert_eq!(
        walk(S::SwitchOnDisabled, brake),
        (vec![2], S::ReadyToSwitchOn)
    );
    assert_eq!(
        controlword_for(S::ReadyToSwitchOn, brake),
        (CW_SHUTDOWN, None)
    );
    assert_eq!(
        controlword_for(S::NotReadyToSwitchOn, on),
        (CW_SHUTDOWN, None)
    );
    let reset = HostRequest::ResetFault;
    assert_eq!(controlword_for(S::Fault, reset), (CW_FAULT_RESET, Some(15)));
    assert_eq!(controlword_for(S::Fault, on), (CW_SHUTDOWN, None));
    assert_eq!(
        controlword_for(S::FaultReactionActive, reset),
        (CW_SHUTDOWN, None)
    );
    for r in [on, brake, reset] {
        assert_eq!(
            controlword_for(S::QuickStopActive, r),
            (CW_QUICK_STOP, None)
        );
    }
    assert_eq!(
        controlword_for(S::OperationEnabled, reset),
        (CW_SWITCH_ON, Some(5))
    );
}

#[test]
fn a_cycle_needs_every_drive_and_converts_the_units() {
    let mut a = adapter(2);
    assert_eq!(a.clock_period_s(), Some(0.008));
    assert_eq!((a.counter_modulus(), a.n_joints()), (65536, 2));
    let oe = [SW_OPERATION_ENABLED; 2];
    let fb = cycle(&mut a, &oe, &[0.1, -0.2], 0.0);
    assert_eq!((fb.counter, fb.n), (1, 2));
    for (got, want) in fb.q().iter().zip([0.1, -0.2]) {
        assert!((got - want).abs() < 1e-7);
    }
    assert_eq!(fb.current(), &[5.0, 2.0 * (500.0 - 750.0) / 1000.0]);
    assert_eq!(
        fb.dq()[0],
        2.0 * (0.1 * inc_per_rad(0)).round() / inc_per_rad(0)
    );
    assert_eq!(fb.controller_state, ControllerState::External);
    assert!(fb.servo_power && !fb.estop && fb.fault == "NONE");
    assert_eq!((fb.period_s, a.fault_text()), (0.008, "NONE"));
    assert_eq!(cycle(&mut a, &oe, &[0.0, 0.0], 0.0).counter, 2);
    assert_eq!(a.stats().cycles, 2);
    assert!(a.is_cycle_frame(&tpdo1(1, 0, 0)) && a.is_cycle_frame(&tpdo2(0, 0, 0)));
    assert!(!a.is_cycle_frame(&Frame::classic(0x701, &[5])));
    let health = a.health(0.0);
    assert_eq!(
        health["cia402_drives"],
        json!({"J1": "operation enabled", "J2": "operation enabled"})
    );
    assert_eq!(health["cia402_fault"], json!("NONE"));
}

#[test]
fn the_counter_wraps_at_the_modulus() {
    let mut t = tables(1);
    t["sync_count"] = json!(65535);
    let mut a = Cia402Adapter::from_tables(&t).unwrap();
    assert_eq!(
        cycle(&mut a, &[SW_SWITCH_ON_DISABLED], &[0.0], 0.0).counter,
        0
    );
    assert_eq!(
        cycle(&mut a, &[SW_SWITCH_ON_DISABLED], &[0.0], 0.0).counter,
        1
    );
}

#[test]
fn a_bad_length_corrupts_its_cycle_and_a_missing_drive_makes_it_incomplete() {
    let mut a = adapter(2);
    let mut out = Vec::new();
    a.clock_frames(&mut out);
    assert!(a
        .feed(&Frame::classic(0x181, &[0x37, 0x02, 0x00]), 0.0)
        .is_none());
    assert_eq!(a.stats().last_error, "TPDO1 of node 1: 3 bytes, expected 6");
    for k in 0..2 {
        assert!(a.feed(&tpdo1(k, SW_OPERATION_ENABLED, 0), 0.0).is_none());
    }
    for k in 0..2 {
        assert!(a.feed(&tpdo2(k, 0, 0), 0.0).is_none());
    }
    assert_eq!((a.stats().corrupt_cycles, a.stats().bad_frames), (1, 1));
    let long = Frame::fd(0x282, &[0; 12], false);
    assert!(a.feed(&long, 0.0).is_none());
    assert_eq!(
        a.stats().last_error,
        "TPDO2 of node 2: 12 bytes, expected 8"
    );
    // a drive that never answers: the next SYNC counts the cycle incomplete
    a.clock_frames(&mut out);
    assert!(a.feed(&tpdo1(0, SW_OPERATION_ENABLED, 0), 0.0).is_none());
    assert!(a.feed(&tpdo2(0, 0, 0), 0.0).is_none());
    assert_eq!(a.stats().incomplete_cycles, 0);
    a.clock_frames(&mut out);
    assert_eq!(a.stats().incomplete_cycles, 1);
    assert_eq!(
        a.stats().last_error,
        "a SYNC went out before every drive had answered the last"
    );
    let fb = cycle(&mut a, &[SW_OPERATION_ENABLED; 2], &[0.0; 2], 0.0);
    assert_eq!(fb.counter, 4);
    // frames the protocol refuses, or does not know
    let mut remote = tpdo1(0, 0, 0);
    remote.remote = true;
    let mut extended = tpdo1(0, 0, 0);
    extended.extended = true;
    for f in [remote, extended] {
        assert!(a.feed(&f, 0.0).is_none());
        assert_eq!(a.stats().last_error, "error, remote or extended frame");
    }
    assert!(a.is_cycle_frame(&extended), "by id alone, as Python");
    assert!(a.feed(&Frame::classic(0x7FF, &[]), 0.0).is_none());
    assert!(a.feed(&Frame::classic(0x080, &[]), 0.0).is_none());
    assert_eq!((a.stats().unknown_frames, a.stats().bad_frames), (2, 4));
    assert_eq!(a.stats().frames, 5 + 1 + 2 + 4 + 2 + 2);
}

#[test]
fn a_drive_whose_heartbeat_stops_or_leaves_operational_faults_the_controller() {
    let mut a = adapter(2);
    let oe = [SW_OPERATION_ENABLED; 2];
    for k in 0..2 {
        a.feed(&Frame::classic(0x701 + k, &[0x05]), 0.0);
    }
    let fb = cycle(&mut a, &oe, &[0.0; 2], 0.14); // under 3 periods of 50 ms
    assert_eq!(fb.controller_state, ControllerState::External);
    a.feed(&Frame::classic(0x701, &[0x05]), 0.15);
    let fb = cycle(&mut a, &oe, &[0.0; 2], 0.16);
    assert_eq!(
        (fb.controller_state, fb.fault),
        (ControllerState::Fault, "HEARTBEAT_LOST")
    );
    assert_eq!(a.fault_text(), "J2 heartbeat lost (0.16 s)");
    a.feed(&Frame::classic(0x701, &[0x7F]), 0.16); // drive 1 pre-operational
    cycle(&mut a, &oe, &[0.0; 2], 0.16);
    assert_eq!(
        a.fault_text(),
        "J1 NMT state 0x7F; J2 heartbeat lost (0.16 s)"
    );
    assert_eq!(a.health(0.0)["cia402_fault"], json!(a.fault_text()));
}

#[test]
fn a_drive_that_stops_on_its_own_is_latched_until_a_fault_reset() {
    let mut a = adapter(2);
    let mut out = Vec::new();
    a.request_frames(HostRequest::ServoOn, &mut out);
    let oe = [SW_OPERATION_ENABLED; 2];
    assert_eq!(
        cycle(&mut a, &oe, &[0.0; 2], 0.0).controller_state,
        ControllerState::External
    );
    let dropped = [SW_OPERATION_ENABLED, SW_SWITCH_ON_DISABLED];
    let fb = cycle(&mut a, &dropped, &[0.0; 2], 0.0);
    assert_eq!(
        (fb.controller_state, fb.fault),
        (ControllerState::Fault, "LEFT_OPERATION_ENABLED")
    );
    assert_eq!(
        a.dropped(),
        "J2 left operation enabled on its own (switch on disabled)"
    );
    assert_eq!(a.fault_text(), a.dropped());
    // SERVO_ON again: drive 2 gets no walk, drive 1 is switched off (5)
    out.clear();
    a.request_frames(HostRequest::ServoOn, &mut out);
    assert_eq!(controlwords(&out), [CW_SWITCH_ON, CW_SHUTDOWN]);
    assert_eq!(
        cycle(&mut a, &dropped, &[0.0; 2], 0.0).controller_state,
        ControllerState::Fault
    );
    out.clear();
    a.request_frames(HostRequest::ResetFault, &mut out);
    assert_eq!(a.dropped(), "");
    let off = [SW_SWITCH_ON_DISABLED; 2];
    let fb = cycle(&mut a, &off, &[0.0; 2], 0.0);
    assert_eq!(
        (fb.controller_state, fb.fault),
        (ControllerState::Braked, "NONE")
    );
    out.clear();
    a.request_frames(HostRequest::ServoOn, &mut out);
    assert_eq!(controlwords(&out), [CW_SHUTDOWN, CW_SHUTDOWN]); // transition 2
}

#[test]
fn a_drive_fault_is_reported_with_its_emcy_and_reset_by_a_fault_reset() {
    let mut a = adapter(2);
    a.feed(&Frame::classic(0x082, &[0x11, 0x86, 0, 0, 0, 0, 0, 0]), 0.0);
    let fb = cycle(&mut a, &[SW_OPERATION_ENABLED, SW_FAULT], &[0.0; 2], 0.0);
    assert_eq!(
        (fb.controller_state, fb.fault),
        (ControllerState::Fault, "DRIVE_FAULT")
    );
    assert_eq!(a.fault_text(), "J2 fault EMCY 0x8611");
    assert_eq!(Adapter::fault_detail(&a), Some("J2 fault EMCY 0x8611"));
    let mut out = Vec::new();
    a.request_frames(HostRequest::ResetFault, &mut out);
    assert_eq!(controlwords(&out), [CW_SWITCH_ON, CW_FAULT_RESET]);
    let fb = cycle(&mut a, &[SW_QUICK_STOP, SW_NOT_READY], &[0.0; 2], 0.0);
    assert_eq!((fb.fault, fb.servo_power), ("QUICK_STOP", true));
    assert_eq!(a.fault_text(), "J1 quick stop");
}

#[test]
fn commands_carry_the_targets_in_increments_and_refuse_what_int32_cannot() {
    let mut a = adapter(2);
    cycle(&mut a, &[SW_SWITCHED_ON; 2], &[0.0; 2], 0.0);
    let mut out = Vec::new();
    a.request_frames(HostRequest::ServoOn, &mut out);
    out.clear();
    a.command_frames(1, &[0.1, -0.2], &[0.5, 0.5], true, &mut out)
        .unwrap();
    assert_eq!(
        out.iter().map(|f| f.id).collect::<Vec<_>>(),
        [0x201, 0x301, 0x202, 0x302]
    );
    assert_eq!(controlwords(&out), [CW_ENABLE_OPERATION; 2]);
    assert_eq!(
        i32_at(&out[0], 2) as f64,
        (0.1 * inc_per_rad(0)).round_ties_even()
    );
    assert_eq!((out[0].len, out[1].len, i32_at(&out[1], 0)), (6, 4, 0)); // hold
    out.clear();
    a.command_frames(1, &[0.0, 0.0], &[0.5, -0.25], false, &mut out)
        .unwrap();
    assert_eq!(
        i32_at(&out[3], 0) as f64,
        (-0.25 * inc_per_rad(1)).round_ties_even()
    );
    let before = out.len();
    let e = a
        .command_frames(1, &[1e3, 0.0], &[0.0; 2], false, &mut out)
        .unwrap_err();
    assert_eq!(
        e.0,
        "CiA 402 J1: command 1000 rad, 0 rad/s does not fit int32"
    );
    let e = a
        .command_frames(1, &[0.0, f64::NAN], &[0.0; 2], false, &mut out)
        .unwrap_err();
    assert_eq!(
        e.0,
        "CiA 402 J2: command nan rad, 0 rad/s does not fit int32"
    );
    let e = a
        .command_frames(1, &[0.0], &[0.0], false, &mut out)
        .unwrap_err();
    assert_eq!(
        e.0,
        "CiA 402 RPDO set needs 2 positions and velocities, got 1 and 1"
    );
    let edge = (2147483648.0 - 0.25) / inc_per_rad(1);
    let e = a
        .command_frames(1, &[0.0, edge], &[0.0; 2], false, &mut out)
        .unwrap_err();
    assert_eq!(
        e.0,
        "CiA 402 J2 RPDO1: 'l' format requires -2147483648 <= number <= 2147483647"
    );
    assert_eq!(out.len(), before, "nothing appended on an error");
    // a request re-sends the targets last sent: drive 1's of the refused set (as Python),
    // drive 2's of the last set it could pack
    a.request_frames(HostRequest::ServoOn, &mut out);
    assert_eq!(
        (i32_at(&out[before], 2), i32_at(&out[before + 1], 2)),
        (0, 0)
    );
}

#[test]
fn the_heartbeat_and_sync_frames_are_the_hosts() {
    let mut t = tables(1);
    t["host_node_id"] = json!(5);
    let mut a = Cia402Adapter::from_tables(&t).unwrap();
    let hb = a.heartbeat_frame();
    assert_eq!((hb.id, hb.payload()), (0x705, &[0x05u8][..]));
}

#[test]
fn tables_that_do_not_fit_the_cycle_are_refused() {
    let refused = |edit: &dyn Fn(&mut Value), want: &str| {
        let mut t = tables(2);
        edit(&mut t);
        let e = Cia402Adapter::from_tables(&t).err().unwrap();
        assert!(e.contains(want), "{e:?} lacks {want:?}");
    };
    refused(&|t| t["format"] = json!("other/1"), "tables.format");
    refused(&|t| t["n_joints"] = json!(3), "tables.n_joints");
    refused(
        &|t| t["joints"][1]["tpdo1"]["format"] = json!("<Hf"),
        "integer codes",
    );
    refused(
        &|t| t["joints"][1]["tpdo2"]["format"] = json!("<lh"),
        "the cycle needs 3",
    );
    refused(
        &|t| t["joints"][0]["rpdo1"]["format"] = json!("<bl"),
        "controlword",
    );
    refused(
        &|t| t["joints"][0]["rpdo1"]["format"] = json!("<Hh"),
        "every TPDO1 position",
    );
    refused(
        &|t| t["joints"][0]["rpdo2"]["cob_id"] = json!(0x800),
        "11-bit",
    );
    refused(
        &|t| t["joints"][0]["state"] = json!("asleep"),
        "drive state",
    );
    refused(
        &|t| t["joints"][0]["inc_per_rad"] = json!("nan"),
        "not finite",
    );
    refused(&|t| t["request"] = json!("ON"), "HostRequest");
    refused(&|t| t["clock_period_s"] = json!("0"), "positive");
    // numbers work too (serde_json may parse them one ULP off: the strings are exact)
    let mut t = tables(2);
    t["clock_period_s"] = json!(0.008);
    assert!(Cia402Adapter::from_tables(&t).is_ok());
}

#[test]
fn the_cycle_keeps_its_strings_in_the_capacity_reserved_at_build() {
    let mut a = adapter(MAX_JOINTS);
    for k in 0..MAX_JOINTS as u32 {
        a.feed(
            &Frame::classic(0x081 + k, &[0xFF, 0xFF, 0, 0, 0, 0, 0, 0]),
            0.0,
        );
    }
    let capacities = |a: &Cia402Adapter| {
        (
            a.fault_text.capacity(),
            a.dropped.capacity(),
            a.stats.last_error.capacity(),
        )
    };
    let before = capacities(&a);
    let mut out = Vec::new();
    a.request_frames(HostRequest::ServoOn, &mut out);
    cycle(
        &mut a,
        &[SW_OPERATION_ENABLED; MAX_JOINTS],
        &[0.0; MAX_JOINTS],
        0.0,
    );
    let mut sws = [0x021F; MAX_JOINTS];
    sws[0] = SW_READY;
    cycle(&mut a, &sws, &[0.0; MAX_JOINTS], 0.0);
    assert!(a.fault_text().len() > 600, "{}", a.fault_text());
    a.feed(&Frame::fd(0x181, &[0; 64], false), 0.0);
    assert_eq!(capacities(&a), before);
}

#[test]
fn floats_format_as_pythons_g() {
    for (x, want) in [
        (0.0, "0"),
        (-0.0, "-0"),
        (1000.0, "1000"),
        (1e16, "1e+16"),
        (123456789.0, "1.23457e+08"),
        (1e-5, "1e-05"),
        (0.0001, "0.0001"),
        (-87.53720462, "-87.5372"),
        (999999.5, "1e+06"),
        (0.1, "0.1"),
        (f64::NEG_INFINITY, "-inf"),
    ] {
        assert_eq!(format_g(x), want, "{x}");
    }
}
