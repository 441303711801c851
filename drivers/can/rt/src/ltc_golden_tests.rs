//! Replaying drivers/can/rt/tests/data/ltc_golden.json (rt_tables.py `--golden`): the Python
//! adapter's behaviour, frame by frame, for both profiles (used by ltc_fd_adapter.rs's tests too).

use super::*;

pub(crate) const GOLDEN: &str = include_str!("../tests/data/ltc_golden.json");

/// The golden cases of adapter `name`, each with its tables.
pub(crate) fn cases(name: &str) -> Vec<Value> {
    let golden: Value = serde_json::from_str(GOLDEN).expect("ltc_golden.json is JSON");
    assert_eq!(golden["format"], TABLES_FORMAT);
    let cases: Vec<Value> = golden["cases"]
        .as_array()
        .expect("cases")
        .iter()
        .filter(|c| c["adapter"] == name)
        .cloned()
        .collect();
    assert!(!cases.is_empty(), "no golden case for {name}");
    cases
}

fn hex(s: &str) -> Vec<u8> {
    (0..s.len())
        .step_by(2)
        .map(|i| u8::from_str_radix(&s[i..i + 2], 16).unwrap())
        .collect()
}

fn flag(v: &Value, key: &str) -> bool {
    v.get(key).and_then(Value::as_bool).unwrap_or(false)
}

fn float(v: &Value) -> f64 {
    codec::f64_of(v).unwrap_or_else(|| panic!("not a float: {v}"))
}

/// The frame a golden record describes (as SocketCAN would deliver it).
pub(crate) fn frame_of(v: &Value) -> Frame {
    let data = hex(v["data"].as_str().unwrap());
    let mut f = Frame::empty(v["id"].as_u64().unwrap() as u32);
    f.data[..data.len()].copy_from_slice(&data);
    f.len = data.len() as u8;
    f.extended = flag(v, "ext");
    f.remote = flag(v, "rtr");
    f.error = flag(v, "err");
    f.fd = flag(v, "fd");
    f.brs = flag(v, "brs");
    if f.remote {
        f.len = v["dlc"].as_u64().unwrap() as u8;
    }
    f
}

/// `got` is exactly the frame Python sent (id, format, flags, length, every byte).
pub(crate) fn assert_frame(got: &Frame, want: &Value, what: &str) {
    assert_eq!(
        *got,
        frame_of(want),
        "{what}: frame differs from Python's {want}"
    );
}

fn assert_floats(got: &[f64], want: &Value, what: &str) {
    let want: Vec<f64> = want.as_array().unwrap().iter().map(float).collect();
    let bits = |v: &[f64]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
    assert_eq!(
        bits(got),
        bits(&want),
        "{what}: {got:?} != Python's {want:?}"
    );
}

fn assert_feedback(got: &Option<Feedback>, want: &Value, n: usize, what: &str) {
    match (got, want.is_null()) {
        (None, true) => {}
        (Some(fb), false) => {
            assert_eq!(fb.n, n, "{what}: n");
            assert_eq!(
                fb.counter as u64,
                want["counter"].as_u64().unwrap(),
                "{what}: counter"
            );
            assert_floats(fb.q(), &want["q"], &format!("{what}: q"));
            assert_floats(fb.dq(), &want["dq"], &format!("{what}: dq"));
            assert_floats(fb.current(), &want["current"], &format!("{what}: current"));
            assert_eq!(fb.controller_state.name(), want["state"], "{what}: state");
            assert_eq!(fb.estop, want["estop"].as_bool().unwrap(), "{what}: estop");
            assert_eq!(
                fb.servo_power,
                want["servo_power"].as_bool().unwrap(),
                "{what}"
            );
            assert_eq!(fb.fault, want["fault"], "{what}: fault");
            let period = float(&want["period_s"]);
            assert_eq!(fb.period_s.to_bits(), period.to_bits(), "{what}: period_s");
        }
        _ => panic!("{what}: feedback {got:?}, Python's {want}"),
    }
}

/// Replay one golden case against adapters built by `build` from its tables; returns the
/// number of frames fed, command sets, and requests compared.
pub(crate) fn replay<A: Adapter>(
    case: &Value,
    build: fn(&Value) -> Result<A, String>,
) -> (usize, usize, usize) {
    let n = case["n_joints"].as_u64().unwrap() as usize;
    let label = format!("{} n={n}", case["adapter"]);
    let mut a = build(&case["tables"]).expect("tables");
    assert_eq!(a.n_joints(), n);
    let mut last_error = String::new();
    let steps = case["feed"].as_array().unwrap();
    for (k, step) in steps.iter().enumerate() {
        let what = format!("{label} feed step {k} {}", step["frame"]);
        let fb = a.feed(&frame_of(&step["frame"]), 0.0);
        assert_feedback(&fb, &step["feedback"], n, &what);
        if let Some(e) = step.get("last_error") {
            last_error = e.as_str().unwrap().to_string();
        }
        let s = a.stats();
        let counts = [
            s.frames,
            s.unknown_frames,
            s.bad_frames,
            s.cycles,
            s.incomplete_cycles,
            s.corrupt_cycles,
        ];
        let want: Vec<u64> = step["stats"]
            .as_array()
            .unwrap()
            .iter()
            .map(|v| v.as_u64().unwrap())
            .collect();
        assert_eq!(counts.to_vec(), want, "{what}: stats");
        assert_eq!(s.last_error, last_error, "{what}: last_error");
    }
    let commands = case["commands"].as_array().unwrap();
    let sentinel = Frame::classic(0x7FF, &[0xAA]);
    for (k, cmd) in commands.iter().enumerate() {
        let what = format!("{label} command set {k} {cmd}");
        let floats =
            |key: &str| -> Vec<f64> { cmd[key].as_array().unwrap().iter().map(float).collect() };
        let (q, dq) = (floats("q"), floats("dq"));
        let hold = cmd["hold"].as_bool().unwrap();
        let mut out = vec![sentinel];
        let r = a.command_frames(
            cmd["counter"].as_u64().unwrap() as u32,
            &q,
            &dq,
            hold,
            &mut out,
        );
        match (r, cmd.get("error")) {
            (Ok(()), None) => {
                let want = cmd["frames"].as_array().unwrap();
                assert_eq!(out.len(), 1 + want.len(), "{what}: frame count");
                assert_eq!(out[0], sentinel, "{what}: frames before are kept");
                for (j, (got, want)) in out[1..].iter().zip(want).enumerate() {
                    assert_frame(got, want, &format!("{what} frame {j}"));
                }
            }
            (Err(e), Some(want)) => {
                assert_eq!(e.0, want.as_str().unwrap(), "{what}");
                assert_eq!(out, vec![sentinel], "{what}: nothing appended on error");
            }
            (r, want) => panic!("{what}: {r:?}, Python: {want:?}"),
        }
    }
    let mut a = build(&case["tables"]).expect("tables");
    let requests = case["requests"].as_array().unwrap();
    let mut out = Vec::new();
    for (k, pair) in requests.iter().enumerate() {
        let request = match pair[0].as_str().unwrap() {
            "BRAKE" => HostRequest::Brake,
            "SERVO_ON" => HostRequest::ServoOn,
            "RESET_FAULT" => HostRequest::ResetFault,
            other => panic!("request {other}"),
        };
        out.clear();
        a.request_frames(request, &mut out);
        assert_eq!(out.len(), 1);
        assert_frame(&out[0], &pair[1], &format!("{label} request {k}"));
    }
    assert_frame(
        &a.heartbeat_frame(),
        &case["heartbeat"],
        &format!("{label} heartbeat"),
    );
    (steps.len(), commands.len(), requests.len())
}
