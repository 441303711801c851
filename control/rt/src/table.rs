//! Reading the tables the Python side writes (control/rt_tables.py): numbers that must be
//! finite, with errors that name the entry.

use serde_json::Value;

/// `N` finite numbers of the JSON array `value`, named `what` in the error.
pub fn numbers<const N: usize>(value: Option<&Value>, what: &str) -> Result<[f64; N], String> {
    let mut out = [0.0; N];
    let items = value
        .and_then(Value::as_array)
        .filter(|a| a.len() == N)
        .ok_or_else(|| format!("{what} must be {N} numbers"))?;
    for (o, item) in out.iter_mut().zip(items) {
        *o = item
            .as_f64()
            .filter(|v| v.is_finite())
            .ok_or_else(|| format!("{what} must be {N} finite numbers"))?;
    }
    Ok(out)
}

/// Any number of finite numbers.
pub fn vector(value: Option<&Value>, what: &str) -> Result<Vec<f64>, String> {
    let items = value
        .and_then(Value::as_array)
        .ok_or_else(|| format!("{what} must be a list of numbers"))?;
    items.iter().map(|v| finite(Some(v), what)).collect()
}

/// One finite number.
pub fn finite(value: Option<&Value>, what: &str) -> Result<f64, String> {
    value
        .and_then(Value::as_f64)
        .filter(|v| v.is_finite())
        .ok_or_else(|| format!("{what} must be a finite number"))
}

/// A joint index below `n`.
pub fn joint(value: Option<&Value>, n: usize, what: &str) -> Result<usize, String> {
    value
        .and_then(Value::as_u64)
        .map(|k| k as usize)
        .filter(|&k| k < n)
        .ok_or_else(|| format!("{what} must be a joint index below {n}"))
}
