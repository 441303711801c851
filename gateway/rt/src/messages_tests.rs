//! The messages' tests (messages.rs): bit-exact with the golden bytes gateway/messages.py made,
//! every check of its decoders, and Python's texts of numbers.

use super::*;
use crate::MAX_JOINTS;

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
