//! Reading the tables rt_tables.py exports: each reader takes one entry of a JSON object and
//! names it when it is missing or of the wrong type. The codec reads its signals with them,
//! LTC's adapters their tables (ltc_base.rs, ltc_adapter.rs).

use serde_json::Value;

// --- reading the tables ----------------------------------------------------------------------
// Every reader names the entry it wanted ("tables.messages[3: CTRL_STATUS].id: missing").

/// A float of the tables: a JSON number, or a string holding Python's repr of a float
/// (rt_tables.py writes a float as a string where serde_json's default parser would not read
/// the number back exactly: long significands, large exponents, nan and infinities).
pub fn f64_of(v: &Value) -> Option<f64> {
    match v {
        Value::Number(n) => n.as_f64(),
        Value::String(s) => s.parse().ok(),
        _ => None,
    }
}

/// `v[key]`, or Err naming `path.key`.
pub(crate) fn field<'a>(v: &'a Value, key: &str, path: &str) -> Result<&'a Value, String> {
    v.get(key).ok_or_else(|| format!("{path}.{key}: missing"))
}

fn wrong(path: &str, key: &str, want: &str, got: &Value) -> String {
    format!("{path}.{key}: expected {want}, got {got}")
}

pub(crate) fn uint(v: &Value, key: &str, path: &str) -> Result<u64, String> {
    let x = field(v, key, path)?;
    x.as_u64()
        .ok_or_else(|| wrong(path, key, "an unsigned integer", x))
}

pub(crate) fn int(v: &Value, key: &str, path: &str) -> Result<i64, String> {
    let x = field(v, key, path)?;
    x.as_i64().ok_or_else(|| wrong(path, key, "an integer", x))
}

pub(crate) fn float(v: &Value, key: &str, path: &str) -> Result<f64, String> {
    let x = field(v, key, path)?;
    f64_of(x).ok_or_else(|| wrong(path, key, "a number", x))
}

pub(super) fn optional_float(v: &Value, key: &str, path: &str) -> Result<Option<f64>, String> {
    match field(v, key, path)? {
        Value::Null => Ok(None),
        x => f64_of(x)
            .map(Some)
            .ok_or_else(|| wrong(path, key, "a number or null", x)),
    }
}

pub(crate) fn boolean(v: &Value, key: &str, path: &str) -> Result<bool, String> {
    let x = field(v, key, path)?;
    x.as_bool()
        .ok_or_else(|| wrong(path, key, "true or false", x))
}

pub(crate) fn text<'a>(v: &'a Value, key: &str, path: &str) -> Result<&'a str, String> {
    let x = field(v, key, path)?;
    x.as_str().ok_or_else(|| wrong(path, key, "a string", x))
}

pub(crate) fn array<'a>(v: &'a Value, key: &str, path: &str) -> Result<&'a Vec<Value>, String> {
    let x = field(v, key, path)?;
    x.as_array().ok_or_else(|| wrong(path, key, "a list", x))
}

/// `[lo, hi]` of integers, or None for null.
pub(super) fn int_pair(v: &Value, path: &str) -> Result<Option<(i64, i64)>, String> {
    if v.is_null() {
        return Ok(None);
    }
    match v
        .as_array()
        .map(|a| a.iter().map(Value::as_i64).collect::<Vec<_>>())
        .as_deref()
    {
        Some([Some(lo), Some(hi)]) => Ok(Some((*lo, *hi))),
        _ => Err(format!(
            "{path}: expected [lo, hi] integers or null, got {v}"
        )),
    }
}
