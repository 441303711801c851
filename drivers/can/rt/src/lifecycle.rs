//! The gateway's lifecycle announcements as the CAN driver reads them (gateway/messages.py
//! LifecycleMsg, decode_json, LifecycleOrder): UTF-8 JSON objects, decoded with serde_json
//! and checked as Python checks them, and the reader's ordering rule that drops an older or
//! conflicting announcement.
//!
//! Lifecycle messages come at `LIFECYCLE_RATE_HZ` (20 Hz), not once a cycle: decoding one
//! allocates (the JSON tree, the reason, the extra members), as Python's does.

use serde_json::{Map, Value};

use crate::messages::{py_repr, Lifecycle, MessageError, LIFECYCLE_STATES};

/// Lifecycle announcement from the gateway (gateway/messages.py LifecycleMsg).
#[derive(Clone, Debug, PartialEq)]
pub struct LifecycleMsg {
    pub state: Lifecycle,
    /// the gateway's number of this state: raised on every change, repeated with it
    pub seq: i64,
    /// gateway monotonic time of the announcement [s]
    pub stamp_s: f64,
    /// why the gateway is in this state ("" if it gave none)
    pub reason: String,
    /// the members beyond state, seq, stamp_s and reason (the plan ...), kept as they came
    pub extra: Map<String, Value>,
}

const KNOWN: [&str; 4] = ["state", "seq", "stamp_s", "reason"];

impl LifecycleMsg {
    pub fn new(
        state: Lifecycle,
        seq: i64,
        stamp_s: f64,
        reason: &str,
        extra: Map<String, Value>,
    ) -> LifecycleMsg {
        LifecycleMsg {
            state,
            seq,
            stamp_s,
            reason: reason.to_string(),
            extra,
        }
    }

    /// The JSON bytes as Python's `to_bytes` writes them (compact, ASCII, the four members
    /// first, then `extra`); Err for a value JSON cannot carry (a non-finite number).
    pub fn to_bytes(&self) -> Result<Vec<u8>, MessageError> {
        let mut out = String::from("{\"state\":");
        json_string(self.state.wire_name(), &mut out);
        out.push_str(&format!(",\"seq\":{},\"stamp_s\":", self.seq));
        json_float(self.stamp_s, &mut out)?;
        out.push_str(",\"reason\":");
        json_string(&self.reason, &mut out);
        for (key, value) in &self.extra {
            out.push(',');
            json_string(key, &mut out);
            out.push(':');
            json_value(value, &mut out)?;
        }
        out.push('}');
        Ok(out.into_bytes())
    }

    /// Decode and check as Python's `LifecycleMsg.from_bytes`: a JSON object (no NaN or
    /// Infinity literal) whose `state` names a lifecycle state (any case), `seq` reads as a
    /// whole number, `stamp_s` as a finite number; errors worded as Python's.
    pub fn from_bytes(data: &[u8]) -> Result<LifecycleMsg, MessageError> {
        let mut obj = decode_json(data, "Lifecycle")?;
        let state = match obj.get("state") {
            Some(Value::String(s)) => Lifecycle::from_name(&s.to_uppercase()),
            _ => None,
        };
        let state = state.ok_or_else(|| {
            let given = obj.get("state").map_or("None".to_string(), py_value_repr);
            let names: Vec<String> = LIFECYCLE_STATES
                .iter()
                .map(|s| format!("'{}'", s.wire_name()))
                .collect();
            MessageError(format!(
                "Lifecycle: state {given} is not one of [{}]",
                names.join(", ")
            ))
        })?;
        let bad = |exc: String| MessageError(format!("Lifecycle: bad or missing field: {exc}"));
        let seq = py_int(
            obj.get("seq")
                .ok_or_else(|| bad("KeyError('seq')".into()))?,
        )
        .map_err(bad)?;
        let stamp = py_float(
            obj.get("stamp_s")
                .ok_or_else(|| bad("KeyError('stamp_s')".into()))?,
        )
        .map_err(bad)?;
        if !stamp.is_finite() {
            return Err(MessageError("Lifecycle: stamp_s is not finite".into()));
        }
        let reason = match obj.get("reason") {
            None => String::new(),
            Some(Value::String(s)) => s.clone(),
            Some(other) => py_value_repr(other),
        };
        for key in KNOWN {
            obj.remove(key);
        }
        Ok(LifecycleMsg {
            state,
            seq,
            stamp_s: stamp,
            reason,
            extra: obj,
        })
    }
}

/// A reader's check of the gateway's lifecycle stream (gateway/messages.py LifecycleOrder):
/// it keeps the newest announcement and drops, counting them,
///
/// - `out_of_order`: a lower `seq`, or the same one with an older stamp (a late "teaching"
///   must not undo a "stopped");
/// - `conflicting`: the same `seq` naming another state (not what the gateway sends).
#[derive(Clone, Debug, Default)]
pub struct LifecycleOrder {
    /// the newest announcement admitted
    pub last: Option<LifecycleMsg>,
    /// announcements dropped as older news than `last`
    pub out_of_order: u64,
    /// announcements dropped for naming another state under `last`'s seq
    pub conflicting: u64,
}

impl LifecycleOrder {
    pub fn new() -> LifecycleOrder {
        LifecycleOrder::default()
    }

    /// None if `msg` is the newest (kept, as a copy, in `last`: that copy allocates, once per
    /// lifecycle message, not per cycle), else the reason it is dropped ("out_of_order" or
    /// "conflicting", counted).
    pub fn admit(&mut self, msg: &LifecycleMsg) -> Option<&'static str> {
        let mut reason = None;
        if let Some(last) = &self.last {
            if msg.seq < last.seq || (msg.seq == last.seq && msg.stamp_s < last.stamp_s) {
                reason = Some("out_of_order");
            } else if msg.seq == last.seq && msg.state != last.state {
                reason = Some("conflicting");
            }
        }
        match reason {
            None => self.last = Some(msg.clone()),
            Some("out_of_order") => self.out_of_order += 1,
            Some(_) => self.conflicting += 1,
        }
        reason
    }

    /// Python's `dropped` dict: the count of each reason that occurred (health's
    /// `lifecycle_dropped`; a reason never seen is absent).
    pub fn dropped(&self) -> Map<String, Value> {
        let mut out = Map::new();
        for (name, count) in [
            ("out_of_order", self.out_of_order),
            ("conflicting", self.conflicting),
        ] {
            if count > 0 {
                out.insert(name.into(), Value::from(count));
            }
        }
        out
    }
}

/// Decode a JSON object payload as gateway/messages.py `decode_json`: UTF-8, JSON, an
/// object; a NaN or Infinity literal is refused by name. `what` names the message.
pub fn decode_json(data: &[u8], what: &str) -> Result<Map<String, Value>, MessageError> {
    let text = std::str::from_utf8(data).map_err(|e| {
        let at = e.valid_up_to();
        MessageError(format!(
            "{what}: payload is not JSON: 'utf-8' codec can't decode byte 0x{:02x} in \
             position {at}",
            data[at]
        ))
    })?;
    let value: Value = match serde_json::from_str(text) {
        Ok(v) => v,
        Err(e) => {
            // Python's parser calls its constant hook on a NaN/Infinity literal in a value's
            // place before it meets any later syntax error: serde_json stops right there
            // (at the literal, expecting a value; after the sign of -Infinity)
            if let Some((name, line, column)) = first_constant(text) {
                let text = e.to_string();
                let at_value = if name == "-Infinity" {
                    (e.line(), e.column()) == (line, column + 1)
                        && text.starts_with("invalid number")
                } else {
                    (e.line(), e.column()) == (line, column) && text.starts_with("expected value")
                };
                if at_value {
                    return Err(MessageError(format!(
                        "{what}: non-finite number {name} in JSON"
                    )));
                }
            }
            return Err(MessageError(format!("{what}: payload is not JSON: {e}")));
        }
    };
    match value {
        Value::Object(map) => Ok(map),
        other => Err(MessageError(format!(
            "{what}: payload must be a JSON object, got {}",
            py_type(&other)
        ))),
    }
}

/// The first NaN, Infinity or -Infinity literal outside a string, with its line and column
/// (1-based, in bytes, as serde_json counts them).
fn first_constant(text: &str) -> Option<(&'static str, usize, usize)> {
    let bytes = text.as_bytes();
    let (mut line, mut line_start) = (1, 0);
    let (mut in_string, mut escaped) = (false, false);
    for (i, &b) in bytes.iter().enumerate() {
        if in_string {
            match (escaped, b) {
                (true, _) => escaped = false,
                (false, b'\\') => escaped = true,
                (false, b'"') => in_string = false,
                _ => {}
            }
            continue;
        }
        match b {
            b'"' => in_string = true,
            b'\n' => {
                line += 1;
                line_start = i + 1;
            }
            _ => {
                for name in ["NaN", "Infinity", "-Infinity"] {
                    if bytes[i..].starts_with(name.as_bytes()) {
                        return Some((name, line, i - line_start + 1));
                    }
                }
            }
        }
    }
    None
}

/// Python's type name of a JSON value.
fn py_type(v: &Value) -> &'static str {
    match v {
        Value::Null => "NoneType",
        Value::Bool(_) => "bool",
        Value::Number(n) if n.is_f64() => "float",
        Value::Number(_) => "int",
        Value::String(_) => "str",
        Value::Array(_) => "list",
        Value::Object(_) => "dict",
    }
}

/// Python's `repr` of a decoded JSON value (`None`, `True`, `'text'`, `[1, 'a']`, ...).
fn py_value_repr(v: &Value) -> String {
    match v {
        Value::Null => "None".into(),
        Value::Bool(true) => "True".into(),
        Value::Bool(false) => "False".into(),
        Value::Number(n) => match (n.as_i64(), n.as_u64()) {
            (Some(i), _) => i.to_string(),
            (None, Some(u)) => u.to_string(),
            _ => py_repr(n.as_f64().unwrap_or(f64::NAN)),
        },
        Value::String(s) => py_str_repr(s),
        Value::Array(items) => {
            let parts: Vec<String> = items.iter().map(py_value_repr).collect();
            format!("[{}]", parts.join(", "))
        }
        Value::Object(map) => {
            let parts: Vec<String> = map
                .iter()
                .map(|(k, v)| format!("{}: {}", py_str_repr(k), py_value_repr(v)))
                .collect();
            format!("{{{}}}", parts.join(", "))
        }
    }
}

/// Python's `repr(str)`.
fn py_str_repr(s: &str) -> String {
    let quote = if s.contains('\'') && !s.contains('"') {
        '"'
    } else {
        '\''
    };
    let mut out = String::with_capacity(s.len() + 2);
    out.push(quote);
    for c in s.chars() {
        match c {
            '\\' => out.push_str("\\\\"),
            '\n' => out.push_str("\\n"),
            '\r' => out.push_str("\\r"),
            '\t' => out.push_str("\\t"),
            c if c == quote => {
                out.push('\\');
                out.push(c);
            }
            c if (c as u32) < 0x20 || c as u32 == 0x7F => {
                out.push_str(&format!("\\x{:02x}", c as u32))
            }
            c => out.push(c),
        }
    }
    out.push(quote);
    out
}

/// Python's `int(v)` of a decoded JSON value; Err is the exception's repr.
fn py_int(v: &Value) -> Result<i64, String> {
    let type_error = |t: &str| {
        format!(
            "TypeError(\"int() argument must be a string, a bytes-like object or a real \
             number, not '{t}'\")"
        )
    };
    match v {
        Value::Bool(b) => Ok(*b as i64),
        Value::Number(n) => {
            if let Some(i) = n.as_i64() {
                return Ok(i);
            }
            let f = n.as_f64().unwrap_or(f64::NAN);
            let t = f.trunc();
            if t.is_finite() && t.abs() < 9.2e18 {
                Ok(t as i64)
            } else {
                Err(format!(
                    "OverflowError('{} outside the seq range')",
                    py_repr(f)
                ))
            }
        }
        Value::String(s) => {
            let digits: String = s.trim().chars().filter(|c| *c != '_').collect();
            digits.parse::<i64>().map_err(|_| {
                format!(
                    "ValueError(\"invalid literal for int() with base 10: {}\")",
                    py_str_repr(s)
                )
            })
        }
        other => Err(type_error(py_type(other))),
    }
}

/// Python's `float(v)` of a decoded JSON value; Err is the exception's repr.
fn py_float(v: &Value) -> Result<f64, String> {
    match v {
        Value::Bool(b) => Ok(*b as i64 as f64),
        Value::Number(n) => Ok(n.as_f64().unwrap_or(f64::NAN)),
        Value::String(s) => s.trim().parse::<f64>().map_err(|_| {
            format!(
                "ValueError(\"could not convert string to float: {}\")",
                py_str_repr(s)
            )
        }),
        other => Err(format!(
            "TypeError(\"float() argument must be a string or a real number, not '{}'\")",
            py_type(other)
        )),
    }
}

/// A string as Python's `json.dumps` writes it (ensure_ascii: `\uXXXX` beyond ASCII).
fn json_string(s: &str, out: &mut String) {
    out.push('"');
    for c in s.chars() {
        match c {
            '"' => out.push_str("\\\""),
            '\\' => out.push_str("\\\\"),
            '\n' => out.push_str("\\n"),
            '\r' => out.push_str("\\r"),
            '\t' => out.push_str("\\t"),
            '\u{8}' => out.push_str("\\b"),
            '\u{c}' => out.push_str("\\f"),
            c if (c as u32) < 0x20 || (c as u32) > 0x7E => {
                let mut units = [0u16; 2];
                for u in c.encode_utf16(&mut units) {
                    out.push_str(&format!("\\u{u:04x}"));
                }
            }
            c => out.push(c),
        }
    }
    out.push('"');
}

/// A float as Python's `json.dumps(allow_nan=False)` writes it (its repr).
fn json_float(v: f64, out: &mut String) -> Result<(), MessageError> {
    if !v.is_finite() {
        return Err(MessageError(
            "Out of range float values are not JSON compliant".into(),
        ));
    }
    out.push_str(&py_repr(v));
    Ok(())
}

fn json_value(v: &Value, out: &mut String) -> Result<(), MessageError> {
    match v {
        Value::Null => out.push_str("null"),
        Value::Bool(b) => out.push_str(if *b { "true" } else { "false" }),
        Value::Number(n) if n.is_f64() => json_float(n.as_f64().unwrap_or(f64::NAN), out)?,
        Value::Number(n) => out.push_str(&n.to_string()),
        Value::String(s) => json_string(s, out),
        Value::Array(items) => {
            out.push('[');
            for (k, item) in items.iter().enumerate() {
                if k > 0 {
                    out.push(',');
                }
                json_value(item, out)?;
            }
            out.push(']');
        }
        Value::Object(map) => {
            out.push('{');
            for (k, (key, item)) in map.iter().enumerate() {
                if k > 0 {
                    out.push(',');
                }
                json_string(key, out);
                out.push(':');
                json_value(item, out)?;
            }
            out.push('}');
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn msg(state: Lifecycle, seq: i64, stamp_s: f64) -> LifecycleMsg {
        LifecycleMsg::new(state, seq, stamp_s, "", Map::new())
    }

    fn err(data: &[u8]) -> String {
        LifecycleMsg::from_bytes(data).unwrap_err().0
    }

    #[test]
    fn python_bytes_decode_and_encode_the_same() {
        // gateway/messages.py: LifecycleMsg(Lifecycle.TEACHING, 4, 10.0, 'enabling
        // held').to_bytes() and LifecycleMsg(Lifecycle.READY, 12, 1234.5678, '',
        // {'plan': 'p1'}).to_bytes()
        let teaching = br#"{"state":"teaching","seq":4,"stamp_s":10.0,"reason":"enabling held"}"#;
        let ready = br#"{"state":"ready","seq":12,"stamp_s":1234.5678,"reason":"","plan":"p1"}"#;
        let back = LifecycleMsg::from_bytes(teaching).unwrap();
        assert_eq!(
            back,
            LifecycleMsg::new(Lifecycle::Teaching, 4, 10.0, "enabling held", Map::new())
        );
        assert_eq!(back.to_bytes().unwrap(), teaching.to_vec());
        let back = LifecycleMsg::from_bytes(ready).unwrap();
        assert_eq!(
            (back.state, back.seq, back.stamp_s),
            (Lifecycle::Ready, 12, 1234.5678)
        );
        assert_eq!(back.extra.get("plan"), Some(&Value::from("p1")));
        assert_eq!(back.to_bytes().unwrap(), ready.to_vec());
        // json.dumps's ASCII escapes
        let odd = LifecycleMsg::new(Lifecycle::Fault, 1, 1e-5, "é\n\u{1}😀", Map::new());
        assert_eq!(
            String::from_utf8(odd.to_bytes().unwrap()).unwrap(),
            r#"{"state":"fault","seq":1,"stamp_s":1e-05,"reason":"\u00e9\n\u0001\ud83d\ude00"}"#
        );
        assert!(msg(Lifecycle::Fault, 1, f64::NAN).to_bytes().is_err());
    }

    #[test]
    fn the_state_is_read_in_any_case_and_anything_else_is_named() {
        // test_messages.py test_lifecycle_json_round_trip_and_rejects_nan_literals
        let m = LifecycleMsg::from_bytes(br#"{"state":"Teaching","seq":"7","stamp_s":"1.5"}"#);
        let m = m.unwrap();
        assert_eq!(
            (m.state, m.seq, m.stamp_s, m.reason.as_str()),
            (Lifecycle::Teaching, 7, 1.5, "")
        );
        assert_eq!(
            err(br#"{"state":"ready","seq":1,"stamp_s":NaN}"#),
            "Lifecycle: non-finite number NaN in JSON"
        );
        assert_eq!(
            err(br#"{"state":"ready","seq":1,"stamp_s":-Infinity}"#),
            "Lifecycle: non-finite number -Infinity in JSON"
        );
        assert_eq!(
            err(br#"{"state":"flying","seq":1,"stamp_s":1}"#),
            "Lifecycle: state 'flying' is not one of ['stopped', 'ready', 'teaching', \
             'fault', 'identifying', 'replaying']"
        );
        assert!(err(br#"{"seq":1,"stamp_s":1}"#).starts_with("Lifecycle: state None is not"));
        assert!(err(br#"{"state":2,"seq":1,"stamp_s":1}"#).starts_with("Lifecycle: state 2 is"));
        assert_eq!(
            err(br#"{"state":"ready","stamp_s":1}"#),
            "Lifecycle: bad or missing field: KeyError('seq')"
        );
        assert_eq!(
            err(br#"{"state":"ready","seq":1}"#),
            "Lifecycle: bad or missing field: KeyError('stamp_s')"
        );
        assert_eq!(
            err(br#"{"state":"ready","seq":"x","stamp_s":1}"#),
            "Lifecycle: bad or missing field: ValueError(\"invalid literal for int() with base \
             10: 'x'\")"
        );
        assert_eq!(
            err(br#"{"state":"ready","seq":1,"stamp_s":null}"#),
            "Lifecycle: bad or missing field: TypeError(\"float() argument must be a string or \
             a real number, not 'NoneType'\")"
        );
        assert_eq!(
            err(br#"{"state":"ready","seq":1,"stamp_s":"inf"}"#),
            "Lifecycle: stamp_s is not finite"
        );
        assert_eq!(
            err(b"[1, 2]"),
            "Lifecycle: payload must be a JSON object, got list"
        );
        assert!(err(b"{\"state\":").starts_with("Lifecycle: payload is not JSON: "));
        assert_eq!(
            err(b"\xff{}"),
            "Lifecycle: payload is not JSON: 'utf-8' codec can't decode byte 0xff in position 0"
        );
        // a NaN inside a string is text, and a syntax error before a NaN is a syntax error
        let m = LifecycleMsg::from_bytes(
            br#"{"state":"ready","seq":1.9,"stamp_s":true,"reason":"NaN"}"#,
        );
        let m = m.unwrap();
        assert_eq!((m.seq, m.stamp_s, m.reason.as_str()), (1, 1.0, "NaN"));
        assert!(err(br#"{"a" NaN}"#).contains("not JSON"));
        assert!(err(br#"{"state":"ready","x":[-NaN]}"#).contains("not JSON"));
        assert_eq!(
            err("{\"é\":\n Infinity}".as_bytes()),
            "Lifecycle: non-finite number Infinity in JSON"
        );
        let m = LifecycleMsg::from_bytes(br#"{"state":"ready","seq":1,"stamp_s":0,"reason":null}"#);
        assert_eq!(m.unwrap().reason, "None");
    }

    #[test]
    fn an_older_or_conflicting_message_is_dropped_and_counted() {
        // test_can_core.py test_an_older_or_conflicting_lifecycle_message_is_dropped_and_counted
        let t = 500.0;
        let mut order = LifecycleOrder::new();
        assert_eq!(order.admit(&msg(Lifecycle::Teaching, 1, t)), None);
        assert_eq!(order.admit(&msg(Lifecycle::Stopped, 7, t + 0.004)), None);
        let late = msg(Lifecycle::Teaching, 6, t + 0.004); // sent before the stop
        assert_eq!(order.admit(&late), Some("out_of_order"));
        let refresh_before = msg(Lifecycle::Stopped, 7, t + 0.004 - 0.01);
        assert_eq!(order.admit(&refresh_before), Some("out_of_order"));
        let conflicting = msg(Lifecycle::Teaching, 7, t + 0.004);
        assert_eq!(order.admit(&conflicting), Some("conflicting"));
        let refresh = msg(Lifecycle::Stopped, 7, t + 0.054);
        assert_eq!(order.admit(&refresh), None);
        assert_eq!(
            order.last.as_ref(),
            Some(&refresh),
            "still stopped, the newest kept"
        );
        let mut want = Map::new();
        want.insert("out_of_order".into(), Value::from(2));
        want.insert("conflicting".into(), Value::from(1));
        assert_eq!(order.dropped(), want);
        assert!(LifecycleOrder::new().dropped().is_empty());
    }
}
