//! Reading the CiA 402 tables drivers/can/rt_cia402_tables.py makes (cia402.rs): each reader
//! takes one entry of a JSON object and names it when it is missing, of the wrong type or out
//! of range.

use serde_json::Value;

pub(super) fn field<'a>(v: &'a Value, key: &str, what: &str) -> Result<&'a Value, String> {
    v.get(key).ok_or_else(|| format!("{what}.{key}: missing"))
}

pub(super) fn uint(v: &Value, key: &str, what: &str) -> Result<u64, String> {
    field(v, key, what)?
        .as_u64()
        .ok_or_else(|| format!("{what}.{key}: not a non-negative integer"))
}

pub(super) fn int(v: &Value, key: &str, what: &str) -> Result<i128, String> {
    let x = field(v, key, what)?;
    x.as_i64()
        .map(i128::from)
        .or_else(|| x.as_u64().map(i128::from))
        .ok_or_else(|| format!("{what}.{key}: not an integer"))
}

pub(super) fn text<'a>(v: &'a Value, key: &str, what: &str) -> Result<&'a str, String> {
    field(v, key, what)?
        .as_str()
        .ok_or_else(|| format!("{what}.{key}: not a string"))
}

pub(super) fn boolean(v: &Value, key: &str, what: &str) -> Result<bool, String> {
    field(v, key, what)?
        .as_bool()
        .ok_or_else(|| format!("{what}.{key}: not a boolean"))
}

/// A float of the tables: its repr() string (parsed exactly) or a JSON number.
pub(super) fn float_value(x: &Value) -> Option<f64> {
    match x {
        Value::String(s) => s.parse().ok(),
        Value::Number(n) => n.as_f64(),
        _ => None,
    }
}

pub(super) fn float(v: &Value, key: &str, what: &str) -> Result<f64, String> {
    let x = float_value(field(v, key, what)?)
        .ok_or_else(|| format!("{what}.{key}: not a float (a repr() string or a number)"))?;
    if x.is_finite() {
        Ok(x)
    } else {
        Err(format!("{what}.{key}: {x} is not finite"))
    }
}

pub(super) fn positive(v: &Value, key: &str, what: &str) -> Result<f64, String> {
    let x = float(v, key, what)?;
    if x > 0.0 {
        Ok(x)
    } else {
        Err(format!("{what}.{key}: {x} must be positive"))
    }
}

/// PDO values carried over from Python (`tpdoN_values`: null or a list of integers).
pub(super) fn values<const N: usize>(
    v: &Value,
    key: &str,
    what: &str,
) -> Result<Option<[i128; N]>, String> {
    match v.get(key) {
        None | Some(Value::Null) => Ok(None),
        Some(Value::Array(items)) if items.len() == N => {
            let mut out = [0i128; N];
            for (o, item) in out.iter_mut().zip(items) {
                *o = item
                    .as_i64()
                    .map(i128::from)
                    .or_else(|| item.as_u64().map(i128::from))
                    .ok_or_else(|| format!("{what}.{key}: not integers"))?;
            }
            Ok(Some(out))
        }
        Some(_) => Err(format!("{what}.{key}: not null or {N} integers")),
    }
}
