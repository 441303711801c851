//! Constrained guiding in the admittance (issue 47, item 6): the reference's new speed
//! projected onto the speeds the guide allows, in the metric of the step itself.
//!
//! (A2)'s semi-implicit step solves `W q̇ = b` with `W = α M̂ + dt D`. A fixture that must hold
//! (the gun's orientation, a plane, an axis) is a set of rows `A q̇ = c` on the reference's
//! speed (the tool's angular speed, its speed along the constrained directions; `c` pulls a
//! drift back). Adding the constraint's force `Aᵀ μ` to the step and solving for `μ` gives
//!
//! ```text
//! q̇ ← q̇ − W⁻¹ Aᵀ (A W⁻¹ Aᵀ)⁻¹ (A q̇ − c)
//! ```
//!
//! the speed nearest the unconstrained one in W's metric (Gauss's principle of least
//! constraint): a push along an allowed direction moves the reference as it would without
//! the fixture, and a push against it is taken by the fixture whole, however hard, instead of
//! by a spring whose deflection the painter sees as a turned gun (2.3-2.5° on seeds 100-104
//! with a 2,500 N·m/rad spring, 2026-12-02). Rows that say the same thing (a held joint whose
//! axis is also locked) make `A W⁻¹ Aᵀ` singular; a ridge of [`RIDGE`] × its mean diagonal
//! keeps the solve defined and changes nothing along the rows that are independent.
//!
//! No allocation: the caller gives the work buffers ([`ProjectWork`]).

use crate::chain::MAX_JOINTS;

/// Constraint rows at most: the guide's six (orientation, and up to two across an axis or one
/// normal to a plane, with room) and one per held joint.
pub const MAX_ROWS: usize = 6 + MAX_JOINTS;

/// The ridge on `A W⁻¹ Aᵀ` relative to its mean diagonal (module docs).
pub const RIDGE: f64 = 1e-9;

/// The projection's work buffers, sized for [`MAX_ROWS`] rows of [`MAX_JOINTS`] joints.
#[derive(Clone, Debug)]
pub struct ProjectWork {
    chol: [f64; MAX_JOINTS * MAX_JOINTS],
    x: [f64; MAX_ROWS * MAX_JOINTS],
    s: [f64; MAX_ROWS * MAX_ROWS],
    s_chol: [f64; MAX_ROWS * MAX_ROWS],
    r: [f64; MAX_ROWS],
}

impl Default for ProjectWork {
    fn default() -> ProjectWork {
        ProjectWork {
            chol: [0.0; MAX_JOINTS * MAX_JOINTS],
            x: [0.0; MAX_ROWS * MAX_JOINTS],
            s: [0.0; MAX_ROWS * MAX_ROWS],
            s_chol: [0.0; MAX_ROWS * MAX_ROWS],
            r: [0.0; MAX_ROWS],
        }
    }
}

/// The lower Cholesky factor of the symmetric `a` (row-major k × k) into `l`; Err where `a`
/// is not positive definite.
fn cholesky(a: &[f64], k: usize, l: &mut [f64]) -> Result<(), String> {
    l[..k * k].fill(0.0);
    for i in 0..k {
        for j in 0..=i {
            let mut sum = a[i * k + j];
            for p in 0..j {
                sum -= l[i * k + p] * l[j * k + p];
            }
            if i == j {
                if !(sum > 0.0) {
                    return Err(format!(
                        "constrained guiding: the step's matrix is not positive definite \
                         (pivot {sum} at row {i})"
                    ));
                }
                l[i * k + i] = sum.sqrt();
            } else {
                l[i * k + j] = sum / l[j * k + j];
            }
        }
    }
    Ok(())
}

/// Solves `L Lᵀ x = b` in place (`l` from [`cholesky`], k × k).
fn cholesky_solve(l: &[f64], k: usize, b: &mut [f64]) {
    for i in 0..k {
        let mut sum = b[i];
        for p in 0..i {
            sum -= l[i * k + p] * b[p];
        }
        b[i] = sum / l[i * k + i];
    }
    for i in (0..k).rev() {
        let mut sum = b[i];
        for p in i + 1..k {
            sum -= l[p * k + i] * b[p];
        }
        b[i] = sum / l[i * k + i];
    }
}

/// Projects `dq` (n) onto `a dq = c` (`a` row-major m × n) in the metric `w` (symmetric
/// positive definite, row-major n × n): module docs. Err where `w` is not positive definite
/// or m exceeds [`MAX_ROWS`]; `dq` is then unchanged.
pub fn project(
    w: &[f64],
    a: &[f64],
    c: &[f64],
    n: usize,
    m: usize,
    dq: &mut [f64],
    work: &mut ProjectWork,
) -> Result<(), String> {
    if m == 0 {
        return Ok(());
    }
    if m > MAX_ROWS || n > MAX_JOINTS {
        return Err(format!(
            "constrained guiding: {m} rows of {n} joints, at most {MAX_ROWS} of {MAX_JOINTS}"
        ));
    }
    cholesky(w, n, &mut work.chol)?;
    // X = W⁻¹ Aᵀ, one row of A at a time (row k of x is column k of X)
    for k in 0..m {
        let xk = &mut work.x[k * n..(k + 1) * n];
        xk.copy_from_slice(&a[k * n..(k + 1) * n]);
        cholesky_solve(&work.chol, n, xk);
    }
    // S = A X + ridge, r = A dq − c
    let mut trace = 0.0;
    for i in 0..m {
        let ai = &a[i * n..(i + 1) * n];
        for j in 0..m {
            let xj = &work.x[j * n..(j + 1) * n];
            work.s[i * m + j] = ai.iter().zip(xj).map(|(u, v)| u * v).sum();
        }
        trace += work.s[i * m + i];
        work.r[i] = ai.iter().zip(&dq[..n]).map(|(u, v)| u * v).sum::<f64>() - c[i];
    }
    let ridge = RIDGE * (trace / m as f64).max(f64::MIN_POSITIVE);
    for i in 0..m {
        work.s[i * m + i] += ridge;
    }
    // μ = S⁻¹ r
    cholesky(&work.s[..m * m], m, &mut work.s_chol)?;
    cholesky_solve(&work.s_chol, m, &mut work.r[..m]);
    for k in 0..m {
        let mu = work.r[k];
        for (v, &x) in dq[..n].iter_mut().zip(&work.x[k * n..(k + 1) * n]) {
            *v -= x * mu;
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn dot(a: &[f64], b: &[f64]) -> f64 {
        a.iter().zip(b).map(|(u, v)| u * v).sum()
    }

    /// A symmetric positive definite 3 × 3 with coupling, as α M̂ + dt D is.
    const W: [f64; 9] = [4.0, 1.0, 0.5, 1.0, 3.0, 0.2, 0.5, 0.2, 2.0];

    #[test]
    fn the_projected_speed_meets_the_rows_and_is_nearest_in_the_metric() {
        let a = [1.0, -1.0, 0.0, 0.0, 0.3, 1.0];
        let c = [0.1, -0.05];
        let mut dq = [0.7, -0.2, 0.4];
        let free = dq;
        project(&W, &a, &c, 3, 2, &mut dq, &mut ProjectWork::default()).unwrap();
        assert!((dot(&a[..3], &dq) - c[0]).abs() < 1e-9, "{dq:?}");
        assert!((dot(&a[3..], &dq) - c[1]).abs() < 1e-9, "{dq:?}");
        // nearest: the correction W (dq − free) lies in the rows' span (a force Aᵀ μ), so it
        // is orthogonal in W's metric to every speed the rows allow (here the one null
        // direction of A, a × a')
        let corr: Vec<f64> = (0..3)
            .map(|i| {
                dot(
                    &W[i * 3..i * 3 + 3],
                    &[dq[0] - free[0], dq[1] - free[1], dq[2] - free[2]],
                )
            })
            .collect();
        let null = [-1.0, -1.0, 0.3]; // a₁ × a₂ = (−1·1 − 0·0.3, 0·0 − 1·1, 1·0.3 − (−1)·0)
        assert!(dot(&a[..3], &null).abs() < 1e-12 && dot(&a[3..], &null).abs() < 1e-12);
        assert!(dot(&corr, &null).abs() < 1e-9, "{corr:?}");
    }

    #[test]
    fn a_speed_the_rows_allow_is_kept_and_no_rows_change_nothing() {
        let a = [0.0, 0.0, 1.0];
        let mut dq = [0.3, -0.4, 0.0];
        project(&W, &a, &[0.0], 3, 1, &mut dq, &mut ProjectWork::default()).unwrap();
        assert!((dq[0] - 0.3).abs() < 1e-12 && (dq[1] + 0.4).abs() < 1e-12 && dq[2].abs() < 1e-12);
        let mut dq = [0.3, -0.4, 0.2];
        project(&W, &[], &[], 3, 0, &mut dq, &mut ProjectWork::default()).unwrap();
        assert_eq!(dq, [0.3, -0.4, 0.2]);
    }

    #[test]
    fn rows_that_repeat_each_other_are_met_all_the_same() {
        // a held joint 3 (its unit row) and a row that is that joint twice
        let a = [0.0, 0.0, 1.0, 0.0, 0.0, 2.0, 1.0, 1.0, 0.0];
        let mut dq = [0.5, 0.1, -0.3];
        project(
            &W,
            &a,
            &[0.0, 0.0, 0.0],
            3,
            3,
            &mut dq,
            &mut ProjectWork::default(),
        )
        .unwrap();
        assert!(dq[2].abs() < 1e-6 && (dq[0] + dq[1]).abs() < 1e-6, "{dq:?}");
        assert!(dq.iter().all(|v| v.is_finite()));
    }

    #[test]
    fn the_most_rows_of_the_most_joints_fit_the_work_buffers() {
        // MAX_JOINTS joints, every one held (a unit row) and six guide rows on top: MAX_ROWS
        let n = MAX_JOINTS;
        let mut w = vec![0.0; n * n];
        for i in 0..n {
            w[i * n + i] = 2.0 + i as f64;
            if i + 1 < n {
                w[i * n + i + 1] = 0.5;
                w[(i + 1) * n + i] = 0.5;
            }
        }
        let mut a = vec![0.0; MAX_ROWS * n];
        for k in 0..6 {
            for j in 0..n {
                a[k * n + j] = ((k * 7 + j * 3) % 5) as f64 - 2.0;
            }
        }
        for i in 0..n {
            a[(6 + i) * n + i] = 1.0;
        }
        let c = vec![0.0; MAX_ROWS];
        let mut dq: Vec<f64> = (0..n).map(|i| 0.1 * i as f64).collect();
        project(
            &w,
            &a,
            &c,
            n,
            MAX_ROWS,
            &mut dq,
            &mut ProjectWork::default(),
        )
        .unwrap();
        assert!(
            dq.iter().all(|v| v.abs() < 1e-6),
            "every joint held: {dq:?}"
        );
    }

    #[test]
    fn a_metric_that_is_not_positive_definite_is_refused_and_the_speed_kept() {
        let w = [1.0, 2.0, 0.0, 2.0, 1.0, 0.0, 0.0, 0.0, 1.0];
        let mut dq = [0.1, 0.2, 0.3];
        let err = project(
            &w,
            &[1.0, 0.0, 0.0],
            &[0.0],
            3,
            1,
            &mut dq,
            &mut ProjectWork::default(),
        );
        assert!(err.unwrap_err().contains("not positive definite"));
        assert_eq!(dq, [0.1, 0.2, 0.3]);
    }
}
