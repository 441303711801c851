//! numpy's and Python's float semantics where the admittance shows them (admittance.rs):
//! `maximum`, `minimum`, `sign` and `clip` let NaN through, `median` and the linear solve as
//! numpy computes them, and a float as Python's `str` writes it in the messages.

/// numpy's `maximum`: NaN from either side.
pub(super) fn np_max(a: f64, b: f64) -> f64 {
    if a.is_nan() || b.is_nan() {
        f64::NAN
    } else if b > a {
        b
    } else {
        a
    }
}

/// numpy's `minimum`: NaN from either side.
pub(super) fn np_min(a: f64, b: f64) -> f64 {
    if a.is_nan() || b.is_nan() {
        f64::NAN
    } else if b < a {
        b
    } else {
        a
    }
}

/// numpy's `sign`: 0 at ±0, NaN at NaN.
pub(super) fn np_sign(x: f64) -> f64 {
    if x > 0.0 {
        1.0
    } else if x < 0.0 {
        -1.0
    } else if x == 0.0 {
        0.0
    } else {
        f64::NAN
    }
}

/// numpy's `clip`: `minimum(maximum(x, lo), hi)`.
pub(super) fn np_clip(x: f64, lo: f64, hi: f64) -> f64 {
    np_min(np_max(x, lo), hi)
}

/// Solves `a x = b` (a row-major n × n, overwritten; x into b) by Gaussian elimination with
/// partial pivoting, as LAPACK's `gesv` behind `numpy.linalg.solve`; Err where a pivot is
/// exactly 0 (numpy raises `LinAlgError("Singular matrix")` there).
pub(super) fn solve_in_place(a: &mut [f64], b: &mut [f64], n: usize) -> Result<(), String> {
    for k in 0..n {
        // the first largest |a[i][k]| below the diagonal (BLAS idamax)
        let mut p = k;
        let mut best = a[k * n + k].abs();
        for i in k + 1..n {
            let v = a[i * n + k].abs();
            if v > best {
                best = v;
                p = i;
            }
        }
        if a[p * n + k] == 0.0 {
            return Err("Singular matrix".to_string());
        }
        if p != k {
            for j in k..n {
                a.swap(p * n + j, k * n + j);
            }
            b.swap(p, k);
        }
        let pivot = a[k * n + k];
        for i in k + 1..n {
            let l = a[i * n + k] / pivot;
            for j in k + 1..n {
                a[i * n + j] -= l * a[k * n + j];
            }
            b[i] -= l * b[k];
        }
    }
    for i in (0..n).rev() {
        let mut s = b[i];
        for j in i + 1..n {
            s -= a[i * n + j] * b[j];
        }
        b[i] = s / a[i * n + i];
    }
    Ok(())
}

/// A float as Python's `str` writes it where it matters for the messages (nan, inf).
pub(super) fn py_float(x: f64) -> String {
    if x.is_nan() {
        "nan".to_string()
    } else if x.is_infinite() {
        if x > 0.0 { "inf" } else { "-inf" }.to_string()
    } else {
        format!("{x:?}")
    }
}

/// numpy's `median`: NaN with a NaN in it, the mean of the middle two for an even count.
/// Sorts `x` in place.
pub(super) fn median(x: &mut [f64]) -> f64 {
    if x.iter().any(|v| v.is_nan()) {
        return f64::NAN;
    }
    x.sort_unstable_by(f64::total_cmp);
    let m = x.len() / 2;
    if x.len() % 2 == 1 {
        x[m]
    } else {
        (x[m - 1] + x[m]) / 2.0
    }
}
