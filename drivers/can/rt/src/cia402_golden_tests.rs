//! The CiA 402 adapter against the Python adapter's golden vectors (cia402.rs): each scenario of
//! tests/data/cia402_golden.json replayed step by step, bit for bit.

use super::from_tables::request_from_name;
use super::table_fields::float_value;
use super::*;
use crate::adapter::Adapter;
use crate::frame::Frame;
use serde_json::json;
use serde_json::Value;

const GOLDEN: &str = include_str!("../tests/data/cia402_golden.json");

fn hex(s: &str) -> Vec<u8> {
    (0..s.len())
        .step_by(2)
        .map(|i| u8::from_str_radix(&s[i..i + 2], 16).unwrap())
        .collect()
}

fn golden_frame(v: &Value) -> Frame {
    let data = hex(v["data"].as_str().unwrap());
    let mut f = Frame::empty(v["id"].as_u64().unwrap() as u32);
    f.extended = v["ext"].as_bool().unwrap();
    f.remote = v["rtr"].as_bool().unwrap();
    f.error = v["err"].as_bool().unwrap();
    f.fd = v["fd"].as_bool().unwrap();
    f.len = if f.remote {
        v["dlc"].as_u64().unwrap() as u8
    } else {
        data.len() as u8
    };
    f.data[..data.len()].copy_from_slice(&data);
    f
}

fn assert_frames(got: &[Frame], want: &Value, at: &str) {
    let want = want.as_array().unwrap();
    assert_eq!(got.len(), want.len(), "{at}: {got:?}");
    for (g, w) in got.iter().zip(want) {
        assert_eq!(*g, golden_frame(w), "{at}");
    }
}

fn golden_float(v: &Value) -> f64 {
    float_value(v).unwrap()
}

fn assert_floats(got: &[f64], want: &Value, at: &str) {
    let want: Vec<u64> = want
        .as_array()
        .unwrap()
        .iter()
        .map(|v| golden_float(v).to_bits())
        .collect();
    let got: Vec<u64> = got.iter().map(|x| x.to_bits()).collect();
    assert_eq!(got, want, "{at}");
}

fn fault_kind(text: &str) -> &'static str {
    let first = text.split("; ").next().unwrap();
    if text == "NONE" {
        "NONE"
    } else if first.contains("left operation enabled") {
        "LEFT_OPERATION_ENABLED"
    } else if first.contains("quick stop") {
        "QUICK_STOP"
    } else if first.contains("NMT state") {
        "NMT_STATE"
    } else if first.contains("heartbeat lost") {
        "HEARTBEAT_LOST"
    } else {
        "DRIVE_FAULT"
    }
}

fn assert_feedback(a: &Cia402Adapter, got: Option<Feedback>, want: &Value, at: &str) {
    let Some(fb) = got else {
        assert!(want.is_null(), "{at}: no feedback, Python's {want}");
        return;
    };
    assert!(!want.is_null(), "{at}: feedback {fb:?}, Python's none");
    assert_eq!(fb.counter as u64, want["counter"].as_u64().unwrap(), "{at}");
    assert_floats(fb.q(), &want["q"], at);
    assert_floats(fb.dq(), &want["dq"], at);
    assert_floats(fb.current(), &want["current"], at);
    assert_eq!(fb.controller_state.name(), want["controller_state"], "{at}");
    assert_eq!(fb.estop, want["estop"].as_bool().unwrap(), "{at}");
    assert_eq!(
        fb.servo_power,
        want["servo_power"].as_bool().unwrap(),
        "{at}"
    );
    let text = want["fault"].as_str().unwrap();
    assert_eq!(a.fault_text(), text, "{at}");
    assert_eq!(fb.fault, fault_kind(text), "{at}");
    assert_eq!(
        fb.period_s.to_bits(),
        golden_float(&want["period_s"]).to_bits(),
        "{at}"
    );
    assert_eq!(a.health(0.0)["cia402_drives"], want["status"], "{at}");
}

fn assert_stats(s: &AdapterStats, want: &Value, at: &str) {
    let got = json!({
        "frames": s.frames,
        "unknown_frames": s.unknown_frames,
        "bad_frames": s.bad_frames,
        "cycles": s.cycles,
        "incomplete_cycles": s.incomplete_cycles,
        "corrupt_cycles": s.corrupt_cycles,
        "last_error": s.last_error,
    });
    assert_eq!(&got, want, "{at}");
}

fn replay(scenario: &Value) -> usize {
    let name = scenario["name"].as_str().unwrap();
    let mut a =
        Cia402Adapter::from_tables(&scenario["tables"]).unwrap_or_else(|e| panic!("{name}: {e}"));
    let steps = scenario["steps"].as_array().unwrap();
    for (i, step) in steps.iter().enumerate() {
        let op = step["op"].as_str().unwrap();
        let at = format!("{name}, step {i} ({op})");
        let mut out = Vec::new();
        match op {
            "clock" => {
                a.clock_frames(&mut out);
                assert_frames(&out, &step["frames"], &at);
            }
            "feed" => {
                let fb = a.feed(&golden_frame(&step["frame"]), golden_float(&step["now"]));
                assert_feedback(&a, fb, &step["feedback"], &at);
            }
            "command" => {
                let floats = |key: &str| -> Vec<f64> {
                    step[key]
                        .as_array()
                        .unwrap()
                        .iter()
                        .map(golden_float)
                        .collect()
                };
                let (q, dq) = (floats("q"), floats("dq"));
                let counter = step["counter"].as_u64().unwrap() as u32;
                let hold = step["hold"].as_bool().unwrap();
                match (
                    a.command_frames(counter, &q, &dq, hold, &mut out),
                    step.get("error"),
                ) {
                    (Ok(()), None) => assert_frames(&out, &step["frames"], &at),
                    (Err(e), Some(want)) => {
                        let want = want.as_str().unwrap();
                        if step["error_kind"] == "FrameError" {
                            assert_eq!(e.0, want, "{at}");
                        } else {
                            assert!(e.0.ends_with(want), "{at}: {e} is not {want}");
                        }
                        assert!(out.is_empty(), "{at}");
                    }
                    (got, want) => panic!("{at}: {got:?}, Python's {want:?}"),
                }
            }
            "request" => {
                let r = request_from_name(step["request"].as_str().unwrap()).unwrap();
                a.request_frames(r, &mut out);
                assert_frames(&out, &step["frames"], &at);
            }
            "heartbeat" => assert_frames(&[a.heartbeat_frame()], &json!([step["frame"]]), &at),
            "is_cycle_frame" => {
                let got = a.is_cycle_frame(&golden_frame(&step["frame"]));
                assert_eq!(got, step["result"].as_bool().unwrap(), "{at}");
            }
            _ => panic!("{at}: unknown op"),
        }
        assert_stats(a.stats(), &step["stats"], &at);
    }
    steps.len()
}

#[test]
fn the_python_adapters_golden_vectors_replay_bit_exact() {
    let golden: Value = serde_json::from_str(GOLDEN).unwrap();
    let scenarios = golden["scenarios"].as_array().unwrap();
    assert!(scenarios.len() >= 4);
    let steps: usize = scenarios.iter().map(replay).sum();
    assert!(steps > 300, "{steps} steps");
}
