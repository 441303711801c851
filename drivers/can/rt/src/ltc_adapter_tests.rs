//! LTC-1's tests (ltc_adapter.rs): cycles assembled from the controller's frames or lost, the
//! host's commands, requests and heartbeats, the tables it refuses, and the Python adapter's
//! golden vectors.

use super::*;
use crate::adapter::ControllerState;

fn tables(n: usize) -> Value {
    let mut t = golden::cases("ltc_dbc")[0]["tables"].clone();
    t["n_joints"] = n.into();
    t
}

fn adapter(n: usize) -> LtcAdapter {
    LtcAdapter::from_tables(&tables(n)).unwrap()
}

/// The controller's side: JOINT_FB_Jk and CTRL_STATUS encoded with the same codecs.
fn feedback(a: &mut LtcAdapter, joint: usize, q: f64, dq: f64, cur: f64, counter: u32) -> Frame {
    let spec = a.base.spec(&format!("JOINT_FB_J{joint}")).unwrap();
    let [p, v, c, k] = a.base.signals(spec, FEEDBACK_SIGNALS).unwrap();
    let values = &mut a.base.values;
    (values[p], values[v], values[c], values[k]) = (q, dq, cur, (counter & 0xFF) as f64);
    a.base.encode(spec).unwrap()
}

fn status(a: &mut LtcAdapter, counter: u32, state: u8, fault: u8, period_us: u32) -> Frame {
    let values = [
        counter as f64,
        state as f64,
        fault as f64,
        3.0,
        1.0,
        1.0,
        period_us as f64,
    ];
    let spec = a.status;
    let idx = a.base.signals(spec, STATUS_SIGNALS).unwrap();
    for (i, v) in idx.into_iter().zip(values) {
        a.base.values[i] = v;
    }
    a.base.encode(spec).unwrap()
}

fn cycle(a: &mut LtcAdapter, counter: u32, n: usize) -> Vec<Frame> {
    let mut frames: Vec<Frame> = (1..=n)
        .map(|k| feedback(a, k, 0.1 * k as f64, -0.01 * k as f64, 1.5, counter))
        .collect();
    frames.push(status(a, counter, 2, 0, 4000));
    frames
}

fn feed_all(a: &mut LtcAdapter, frames: &[Frame]) -> Option<Feedback> {
    let mut last = None;
    for f in frames {
        last = a.feed(f, 0.0);
    }
    last
}

#[test]
fn the_status_closes_a_complete_cycle() {
    let mut a = adapter(6);
    let frames = cycle(&mut a, 0x1234, 6);
    for f in &frames[..6] {
        assert!(a.feed(f, 0.0).is_none());
    }
    let fb = a.feed(&frames[6], 0.0).expect("complete");
    assert_eq!(
        (fb.counter, fb.n, fb.controller_state),
        (0x1234, 6, ControllerState::External)
    );
    assert_eq!(
        (fb.estop, fb.servo_power, fb.fault, fb.period_s),
        (true, true, "NONE", 4000.0 * 1e-6)
    );
    assert_eq!(fb.q()[2], 300000.0 * 1e-6);
    assert_eq!(fb.current(), &[1.5; 6]);
    assert_eq!((a.stats().cycles, a.stats().frames), (1, 7));
}

#[test]
fn missing_or_stale_feedback_makes_an_incomplete_cycle() {
    let mut a = adapter(3);
    let frames = cycle(&mut a, 300, 3);
    assert!(feed_all(&mut a, &[frames[0], frames[3]]).is_none());
    assert_eq!(a.stats().incomplete_cycles, 1);
    assert_eq!(
        a.stats().last_error,
        "cycle 300 dropped: no JOINT_FB with counter 44 for joint(s) [2, 3]"
    );
    let stale = feedback(&mut a, 2, 0.0, 0.0, 0.0, 299);
    assert!(feed_all(&mut a, &[frames[0], stale, frames[2], frames[3]]).is_none());
    assert!(a.stats().last_error.ends_with("for joint(s) [2]"));
    // the latest frame of a joint counts; a 6-joint controller's extra joints are ignored
    let extra = feedback(&mut a, 6, 0.0, 0.0, 0.0, 1);
    assert!(feed_all(
        &mut a,
        &[stale, frames[0], frames[1], extra, frames[2], frames[3]]
    )
    .is_some());
    assert_eq!(a.stats().cycles, 1);
}

#[test]
fn a_bad_cycle_frame_or_error_frame_loses_the_cycle() {
    let mut a = adapter(2);
    let frames = cycle(&mut a, 5, 2);
    let mut short = frames[1];
    short.len = 7;
    assert!(feed_all(&mut a, &[frames[0], short, frames[2]]).is_none());
    assert_eq!((a.stats().bad_frames, a.stats().corrupt_cycles), (1, 1));
    assert_eq!(
        a.stats().last_error,
        "cycle 5 dropped: JOINT_FB_J2 (0x182): DLC 7 with 7 data bytes, expected 8"
    );
    let mut err = Frame::empty(0x40);
    err.error = true;
    assert!(feed_all(&mut a, &[frames[0], err, frames[1], frames[2]]).is_none());
    assert_eq!(a.stats().corrupt_cycles, 2);
    assert!(a
        .stats()
        .last_error
        .starts_with("cycle 5 dropped: CAN error frame received (id field 0x40)"));
    // a bad frame of another joint of the DBC also counts (it is a per-cycle frame)
    let mut j5 = feedback(&mut a, 5, 0.0, 0.0, 0.0, 5);
    j5.remote = true;
    assert!(feed_all(&mut a, &[frames[0], frames[1], j5, frames[2]]).is_none());
    assert_eq!(a.stats().corrupt_cycles, 3);
    assert!(
        feed_all(&mut a, &frames).is_some(),
        "the next cycle is fine"
    );
}

#[test]
fn a_bad_status_loses_its_cycle_at_once() {
    let mut a = adapter(1);
    let frames = cycle(&mut a, 7, 1);
    let mut bad = frames[1];
    bad.data[2] = 4; // state
    assert!(feed_all(&mut a, &[frames[0], bad]).is_none());
    assert_eq!(a.stats().corrupt_cycles, 1);
    assert_eq!(
        a.stats().last_error,
        "CTRL_STATUS (0x010): state = 4 outside its range [0, 3]"
    );
    // the joints' frames went with it
    assert!(a.feed(&frames[1], 0.0).is_none());
    assert_eq!(a.stats().incomplete_cycles, 1);
    let mut fd = frames[1];
    fd.fd = true;
    a.feed(&fd, 0.0);
    assert_eq!(
        a.stats().last_error,
        "CTRL_STATUS (0x010): CAN FD frame; LTC-1 is classic CAN"
    );
    let mut ext = frames[1];
    ext.extended = true;
    a.feed(&ext, 0.0);
    assert_eq!(
        a.stats().last_error,
        "CTRL_STATUS (0x010): arrived with an extended 29-bit id 0x00000010; LTC-1 uses \
         standard 11-bit ids only"
    );
    assert_eq!(a.stats().corrupt_cycles, 3);
}

#[test]
fn other_frames_neither_help_nor_hurt() {
    let mut a = adapter(1);
    let frames = cycle(&mut a, 9, 1);
    let mut request = Vec::new();
    a.request_frames(HostRequest::ServoOn, &mut request);
    let mut bad_crc = request[0];
    bad_crc.data[7] ^= 1;
    let mut nmt = a.heartbeat_frame();
    nmt.data[0] = 1;
    let unknown = Frame::classic(0x123, &[1, 2]);
    let fb = feed_all(
        &mut a,
        &[frames[0], bad_crc, nmt, unknown, request[0], frames[1]],
    );
    assert!(fb.is_some());
    let s = a.stats();
    assert_eq!(
        (s.frames, s.unknown_frames, s.bad_frames, s.cycles),
        (6, 1, 2, 1)
    );
    a.feed(&bad_crc, 0.0);
    let want = format!(
        "HOST_REQUEST (0x020): CRC 0x{:02X} does not match 0x{:02X} computed over the id and \
         data bytes 0..6",
        bad_crc.data[7], request[0].data[7]
    );
    assert_eq!(a.stats().last_error, want);
    a.feed(&nmt, 0.0);
    assert_eq!(
        a.stats().last_error,
        "HEARTBEAT_HOST (0x710): nmt_state = 1 is not a known value (0 BOOT, 4 STOPPED, 5 \
         OPERATIONAL, 127 PRE_OPERATIONAL)"
    );
}

#[test]
fn command_frames_carry_the_low_byte_hold_and_crc() {
    let mut a = adapter(2);
    let mut out = Vec::with_capacity(8);
    a.command_frames(0x122A, &[0.1, -0.2], &[-0.25, 0.5], false, &mut out)
        .unwrap();
    assert_eq!(out.len(), 2);
    // PROTOCOL.md §4's example frame
    assert_eq!(out[0].id, 0x201);
    assert_eq!(
        out[0].payload(),
        &[0xa0, 0x86, 0x01, 0x3c, 0xf6, 0x00, 0x2a, 0x4f]
    );
    a.command_frames(0, &[0.0, 0.0], &[0.0, 0.0], true, &mut out)
        .unwrap();
    assert_eq!(out[3].data[5], 1, "hold");
    let e = a
        .command_frames(0, &[0.0, 9.0], &[0.0, 0.0], false, &mut out)
        .unwrap_err();
    assert_eq!(
        e.0,
        "JOINT_CMD_J2 (0x202): position_cmd = 9.0 rad outside its DBC range [-8.388608, 8.388607]"
    );
    assert_eq!(out.len(), 4, "nothing appended on error");
    let e = a
        .command_frames(0, &[0.0], &[0.0, 0.0], false, &mut out)
        .unwrap_err();
    assert_eq!(
        e.0,
        "JOINT_CMD set needs 2 positions and velocities, got 1 and 2"
    );
}

#[test]
fn request_counter_rolls_over_and_heartbeat_is_operational() {
    let mut a = adapter(6);
    let mut out = Vec::new();
    for _ in 0..257 {
        a.request_frames(HostRequest::ServoOn, &mut out);
    }
    assert_eq!(out[7].payload(), &[0x01, 0x07, 0, 0, 0, 0, 0, 0xd2]); // PROTOCOL.md §4
    assert_eq!((out[255].data[1], out[256].data[1]), (255, 0));
    let hb = a.heartbeat_frame();
    assert_eq!((hb.id, hb.payload()), (0x710, &[5u8][..]));
    assert_eq!(
        (a.name(), a.counter_modulus(), a.host_heartbeat_timeout_s()),
        ("ltc_dbc", 65536, 0.5)
    );
    assert!(a.is_cycle_frame(&Frame::empty(0x186)) && !a.is_cycle_frame(&Frame::empty(0x201)));
}

#[test]
fn bad_tables_are_named() {
    let err = |f: &dyn Fn(&mut Value)| {
        let mut t = tables(6);
        f(&mut t);
        LtcAdapter::from_tables(&t).err().expect("refused")
    };
    assert_eq!(
        err(&|t| t["n_joints"] = 7.into()),
        "tables.n_joints: LTC-1 carries 1..6 joints, not 7"
    );
    assert_eq!(
        err(&|t| t["adapter"] = "ltc_fd".into()),
        "tables.adapter: \"ltc_fd\", expected \"ltc_dbc\""
    );
    assert_eq!(
        err(&|t| t["format"] = 2.into()),
        "tables.format: 2, this code reads format 1"
    );
    let e = err(&|t| {
        t["messages"]
            .as_array_mut()
            .unwrap()
            .retain(|m| m["name"] != "JOINT_CMD_J4");
    });
    assert_eq!(e, "tables.messages: no message JOINT_CMD_J4");
    let e = err(&|t| {
        t["messages"][0]["signals"][0]
            .as_object_mut()
            .unwrap()
            .clear()
    });
    assert_eq!(
        e,
        "tables.messages[0: HOST_REQUEST].signals[0: ?].name: missing"
    );
    let e = err(&|t| t["messages"][3]["signals"][1]["choices"][3][1] = "LIMBO".into());
    assert!(
        e.starts_with("tables.messages[CTRL_STATUS].signals[state].choices"),
        "{e}"
    );
    let e = err(&|t| {
        t.as_object_mut()
            .unwrap()
            .remove("feedback_counter_modulus")
            .map(|_| ())
            .unwrap()
    });
    assert_eq!(e, "tables.feedback_counter_modulus: missing");
}

#[test]
fn scratch_and_error_buffers_are_reused() {
    // The cycle writes into buffers sized at construction: their addresses stay put over
    // good cycles, corrupt ones (last_error rewritten) and command sets.
    let mut a = adapter(6);
    let frames = cycle(&mut a, 1, 6);
    let mut err = Frame::empty(0x40);
    err.error = true;
    feed_all(&mut a, &[frames[0], err, frames[6]]);
    let buffers = |a: &LtcAdapter| {
        (
            a.base.raw.as_ptr(),
            a.base.values.as_ptr(),
            a.stats.last_error.as_ptr(),
        )
    };
    let before = buffers(&a);
    let mut out = Vec::with_capacity(6);
    for _ in 0..3 {
        assert!(feed_all(&mut a, &frames).is_some());
        assert!(feed_all(&mut a, &[frames[0], err, frames[6]]).is_none());
        out.clear();
        a.command_frames(1, &[0.0; 6], &[0.0; 6], false, &mut out)
            .unwrap();
    }
    assert_eq!(buffers(&a), before);
    assert_eq!(a.stats().corrupt_cycles, 4);
}

#[test]
fn golden_vectors_from_python() {
    let mut totals = (0, 0, 0);
    for case in golden::cases("ltc_dbc") {
        let (f, c, r) = golden::replay(&case, LtcAdapter::from_tables);
        totals = (totals.0 + f, totals.1 + c, totals.2 + r);
    }
    assert!(
        totals.0 > 1000 && totals.1 > 100 && totals.2 > 500,
        "{totals:?}"
    );
}
