//! The codec's tests (codec.rs): signals encoded and decoded as codec.py does, its error
//! texts, the tables it refuses, and Python's float repr.

use super::*;
use serde_json::json;

fn signal(name: &str, start: u64, bits: u64, signed: bool, conv: &str, scale: Value) -> Value {
    let (raw_min, raw_max) = field_range(bits as usize, signed);
    json!({"name": name, "start_bit": start, "length_bits": bits, "signed": signed,
           "conversion": conv, "scale": scale, "offset": 0, "minimum": null,
           "maximum": null, "unit": "", "raw_min": raw_min, "raw_max": raw_max,
           "decode_raw": [raw_min, raw_max], "encode_raw": null, "choices": null})
}

/// JOINT_CMD_J1 of ltc_v1.dbc, as rt_tables.py exports it.
fn joint_cmd() -> MessageCodec {
    let mut pos = signal("position_cmd", 0, 24, true, "linear", json!(1e-6));
    pos["minimum"] = json!(-8.388608);
    pos["maximum"] = json!(8.388607);
    pos["unit"] = json!("rad");
    pos["encode_raw"] = json!([-8388608, 8388607]);
    let mut vel = signal("velocity_cmd", 24, 16, true, "linear", json!(0.0001));
    vel["minimum"] = json!(-3.2768);
    vel["maximum"] = json!(3.2767);
    vel["unit"] = json!("rad/s");
    vel["encode_raw"] = json!([-32768, 32767]);
    let mut hold = signal("hold", 40, 1, false, "identity", json!(1));
    hold["minimum"] = json!(0);
    hold["maximum"] = json!(1);
    hold["encode_raw"] = json!([0, 1]);
    let counter = signal("counter", 48, 8, false, "identity", json!(1));
    let crc = signal("crc", 56, 8, false, "identity", json!(1));
    let msg = json!({"name": "JOINT_CMD_J1", "id": 513, "where": "JOINT_CMD_J1 (0x201)",
                     "length": 8, "fd": false, "brs": false, "extended": false,
                     "signals": [pos, vel, hold, counter, crc]});
    MessageCodec::from_table(&msg, "m").unwrap()
}

#[test]
fn python_float_repr() {
    let cases: [(f64, &str); 22] = [
        (0.0, "0.0"),
        (-0.0, "-0.0"),
        (9.0, "9.0"),
        (0.1, "0.1"),
        (-8.388608, "-8.388608"),
        (1e-4, "0.0001"),
        (1e-5, "1e-05"),
        (1.5e-7, "1.5e-07"),
        (1e16, "1e+16"),
        (1234567890123456.0, "1234567890123456.0"),
        (12345678901234567.0, "1.2345678901234568e+16"),
        (1e300, "1e+300"),
        (f64::MAX, "1.7976931348623157e+308"),
        (5e-324, "5e-324"),
        (0.30000000000000004, "0.30000000000000004"),
        (123.456, "123.456"),
        (-0.00012, "-0.00012"),
        (100.0, "100.0"),
        (f64::NAN, "nan"),
        (f64::INFINITY, "inf"),
        (f64::NEG_INFINITY, "-inf"),
        (2.5e-6, "2.5e-06"),
    ];
    for (v, want) in cases {
        assert_eq!(py_float(v), want, "{v:e}");
    }
}

#[test]
fn manual_example_encodes_and_decodes() {
    // PROTOCOL.md §4: position 0.1 rad, velocity −0.25 rad/s, hold 0, counter 0x2A
    let c = joint_cmd();
    let mut data = [0u8; 8];
    c.encode(&[0.1, -0.25, 0.0, 42.0, 0.0], &mut data).unwrap();
    assert_eq!(data, [0xa0, 0x86, 0x01, 0x3c, 0xf6, 0x00, 0x2a, 0x00]);
    let mut raw = [0i64; 5];
    c.decode(&data, &mut raw).unwrap();
    assert_eq!(raw, [100000, -2500, 0, 42, 0]);
    assert_eq!(c.physical(0, raw[0]), 100000.0 * 1e-6);
    assert_eq!(c.physical(1, raw[1]), -2500.0 * 0.0001);
}

#[test]
fn rounding_is_pythons_ties_to_even() {
    let c = joint_cmd();
    let mut data = [0u8; 8];
    let mut raw = [0i64; 5];
    // Python: 5e-07 / 1e-06 == 0.5 → 0 (even), 1.5e-06 → 2, 3.5e-06 → 4; but
    // 2.5e-06 / 1e-06 == 2.5000000000000004 → 3 (the division rounds first)
    for (q, want) in [
        (5e-7, 0),
        (1.5e-6, 2),
        (3.5e-6, 4),
        (-5e-7, 0),
        (-1.5e-6, -2),
        (2.5e-6, 3),
        (-2.5e-6, -3),
        (-0.0, 0),
        (8.388607, 8388607),
    ] {
        c.encode(&[q, 0.0, 1.0, 255.0, 0.0], &mut data).unwrap();
        c.decode(&data, &mut raw).unwrap();
        assert_eq!(raw[0], want, "{q}");
        assert_eq!(raw[2..4], [1, 255]);
    }
}

#[test]
fn encode_errors_are_codec_py_texts() {
    let c = joint_cmd();
    let mut data = [0u8; 8];
    let err = |q: f64, dq: f64, hold: f64| {
        c.encode(&[q, dq, hold, 0.0, 0.0], &mut [0u8; 8])
            .unwrap_err()
            .0
    };
    assert_eq!(
        err(9.0, 0.0, 0.0),
        "JOINT_CMD_J1 (0x201): position_cmd = 9.0 rad outside its DBC range [-8.388608, 8.388607]"
    );
    assert_eq!(
        err(f64::NAN, 0.0, 0.0),
        "JOINT_CMD_J1 (0x201): position_cmd = nan rad is not finite"
    );
    assert_eq!(
        err(0.0, -1e300, 0.0),
        "JOINT_CMD_J1 (0x201): velocity_cmd = -1e+300 rad/s outside its DBC range [-3.2768, 3.2767]"
    );
    assert_eq!(
        err(0.0, 0.0, 0.5),
        "JOINT_CMD_J1 (0x201): hold = 0.5 must be an integer"
    );
    assert_eq!(
        err(0.0, 0.0, 2.0),
        "JOINT_CMD_J1 (0x201): hold = 2 outside its DBC range [0, 1]"
    );
    // counter has no DBC range in this table: the field overflow is checked
    let e = c
        .encode(&[0.0, 0.0, 0.0, 256.0, 0.0], &mut data)
        .unwrap_err()
        .0;
    assert_eq!(
        e,
        "JOINT_CMD_J1 (0x201): counter = 256 is raw 256, outside the 8-bit field's 0..255"
    );
    let e = c
        .encode(&[0.0, 0.0, 0.0, 1e20, 0.0], &mut data)
        .unwrap_err()
        .0;
    assert!(
        e.ends_with("is raw 100000000000000000000, outside the 8-bit field's 0..255"),
        "{e}"
    );
}

#[test]
fn decode_checks_the_accepted_raw_range() {
    let mut t = json!({"name": "S", "id": 16, "where": "S (0x010)", "length": 2, "fd": false,
                       "brs": false, "extended": false,
                       "signals": [signal("state", 0, 8, false, "identity", json!(1)),
                                   signal("t", 8, 8, true, "linear", json!(0.5))]});
    t["signals"][0]["minimum"] = json!(0);
    t["signals"][0]["maximum"] = json!(3);
    t["signals"][0]["decode_raw"] = json!([0, 3]);
    t["signals"][1]["minimum"] = json!(-10.0);
    t["signals"][1]["maximum"] = json!(10.0);
    t["signals"][1]["decode_raw"] = json!([-21, 21]);
    let c = MessageCodec::from_table(&t, "m").unwrap();
    let mut raw = [0i64; 2];
    let mut text = String::new();
    let e = c.decode(&[4, 0], &mut raw).unwrap_err();
    c.write_decode_error(&e, &mut text);
    assert_eq!(text, "S (0x010): state = 4 outside its range [0, 3]");
    text.clear();
    let e = c.decode(&[3, (-22i8) as u8], &mut raw).unwrap_err();
    c.write_decode_error(&e, &mut text);
    assert_eq!(text, "S (0x010): t = -11.0 outside its range [-10.0, 10.0]");
    c.decode(&[3, (-21i8) as u8], &mut raw).unwrap();
    assert_eq!((raw, c.physical(1, raw[1])), ([3, -21], -10.5));
    text.clear();
    let e = c.decode(&[3], &mut raw).unwrap_err();
    c.write_decode_error(&e, &mut text);
    assert_eq!(text, "S (0x010): 1 data bytes, expected 2");
}

#[test]
fn wide_fields_anywhere_in_a_64_byte_frame() {
    let sigs = vec![
        signal("a", 3, 64, true, "identity", json!(1)),
        signal("b", 67, 63, false, "identity", json!(1)),
        signal("c", 500, 12, true, "identity", json!(1)),
    ];
    let t = json!({"name": "W", "id": 0x123, "where": "W (0x123)", "length": 64, "fd": true,
                   "brs": true, "extended": false, "signals": sigs});
    let c = MessageCodec::from_table(&t, "m").unwrap();
    let mut data = [0u8; 64];
    let mut raw = [0i64; 3];
    // identity values travel as f64: take ones it holds exactly
    let values = [
        -(1i64 << 62) as f64,
        ((1u64 << 62) + (1 << 20)) as f64,
        -2048.0,
    ];
    c.encode(&values, &mut data).unwrap();
    c.decode(&data, &mut raw).unwrap();
    assert_eq!(raw, [-(1i64 << 62), (1i64 << 62) + (1 << 20), -2048]);
}

#[test]
fn bad_tables_name_the_entry() {
    let mut t = json!({"name": "X", "id": 1, "where": "X (0x001)", "length": 8, "fd": false,
                       "brs": false, "extended": false,
                       "signals": [signal("a", 0, 8, false, "identity", json!(1))]});
    t["signals"][0].as_object_mut().unwrap().remove("scale");
    assert_eq!(
        MessageCodec::from_table(&t, "m").unwrap_err(),
        "m.signals[0: a].scale: missing"
    );
    t["signals"][0]["scale"] = json!("x");
    assert!(MessageCodec::from_table(&t, "m")
        .unwrap_err()
        .starts_with("m.signals[0: a].scale: expected a number"));
    t["signals"][0]["scale"] = json!(1);
    t["signals"][0]["start_bit"] = json!(60);
    assert!(MessageCodec::from_table(&t, "m")
        .unwrap_err()
        .contains("do not fit the 8-byte frame"));
    t["signals"][0]["start_bit"] = json!(0);
    t["signals"]
        .as_array_mut()
        .unwrap()
        .push(signal("b", 4, 8, false, "identity", json!(1)));
    assert!(MessageCodec::from_table(&t, "m")
        .unwrap_err()
        .contains("overlaps another signal of X"));
    t["length"] = json!(9);
    assert!(MessageCodec::from_table(&t, "m")
        .unwrap_err()
        .contains("no classic CAN frame's length"));
}

#[test]
fn floats_as_strings_are_read_exactly() {
    assert_eq!(
        f64_of(&json!("0.30000000000000004")),
        Some(0.30000000000000004)
    );
    assert!(f64_of(&json!("nan")).unwrap().is_nan());
    assert_eq!(f64_of(&json!("-inf")), Some(f64::NEG_INFINITY));
    assert_eq!(f64_of(&json!(1e-6)), Some(1e-6));
    assert_eq!(f64_of(&json!(true)), None);
}
