//! The admittance's soft joint walls: a spring and a damper on each joint past its soft limit.
//!
//! Inside its soft limits a joint is free; past one, the wall pushes its reference back with
//! `k` × the depth (`[control] wall_stiffness_nm_per_rad`) and damps the reference's speed
//! deeper into it. Only deeper: a painter guiding a joint along inside its wall zone or out of
//! it pays no damper. (Seed 110's raster keeps J3 in its wall zone for 20-35 s; its painter sat
//! at the hand's 80 N for long stretches with a damper either way, since the path asks J3 past
//! its soft limit there; without one, the run ended on the speed monitor below.)
//!
//! A spring alone is no wall for an admittance: against the share α of the arm's inertia the
//! reference renders, 2,000 N·m/rad rings at about 1.3 Hz on J3 (α M ≈ 30 kg·m²), and the
//! law's own damping (a few N·m·s/rad where the hand pushes, so the painter does not pay it)
//! leaves it almost undamped; the spring acts on the measured position, a vendor loop behind
//! the reference, and a delayed spring feeds the ringing. On plant seed 110 (teach-bench,
//! session 96) J3 bounced off its wall at ±0.55 rad/s until the CAN driver's speed monitor
//! stopped the arm at 311 mm/s. The damper is critical for the rendered inertia, `2 √(k α
//! M_jj)`, at most `α M_jj / dt`: the law adds a wall's torque explicitly, and a damper that
//! took more than the reference's whole speed in one step would reverse it.

use super::numpy_semantics::{np_max, np_min};

/// The walls' torque on the reference per joint into `out` [N·m] (module docs): `q` the
/// measured positions [rad], `dq_r` the reference's speed [rad/s], `lower`/`upper` the soft
/// limits [rad], `rendered_inertia` α M̂_jj per joint [kg·m²], `dt_s` the law's step [s]. Err
/// where `dt_s` is not > 0.
#[allow(clippy::too_many_arguments)]
pub fn wall_torque(
    q: &[f64],
    dq_r: &[f64],
    lower: &[f64],
    upper: &[f64],
    stiffness_nm_per_rad: f64,
    rendered_inertia: &[f64],
    dt_s: f64,
    out: &mut [f64],
) -> Result<(), String> {
    if !(dt_s > 0.0) {
        return Err(format!("soft walls: step {dt_s} s must be > 0"));
    }
    let k = stiffness_nm_per_rad;
    for j in 0..q.len() {
        let above = np_max(q[j] - upper[j], 0.0);
        let below = np_max(lower[j] - q[j], 0.0);
        let inertia = np_max(rendered_inertia[j], 0.0);
        let damping = np_min(2.0 * (k * inertia).sqrt(), inertia / dt_s);
        let deeper = (above > 0.0 && dq_r[j] > 0.0) || (below > 0.0 && dq_r[j] < 0.0);
        let damper = if deeper { damping * dq_r[j] } else { 0.0 };
        out[j] = -k * above + k * below - damper;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn inside_the_limits_a_joint_is_free_and_deeper_it_is_damped() {
        let mut out = [1.0; 2];
        wall_torque(
            &[0.0, 0.0],
            &[0.5, -0.5],
            &[-1.0, -1.0],
            &[1.0, 1.0],
            2000.0,
            &[30.0; 2],
            0.008,
            &mut out,
        )
        .unwrap();
        assert_eq!(out, [0.0, 0.0]);
        wall_torque(
            &[1.01, 1.01],
            &[0.5, -0.5],
            &[-1.0, -1.0],
            &[1.0, 1.0],
            2000.0,
            &[30.0; 2],
            0.008,
            &mut out,
        )
        .unwrap();
        let spring = -2000.0 * (1.01f64 - 1.0);
        assert!((out[1] - spring).abs() < 1e-9);
        assert!(out[0] < spring);
        assert!(wall_torque(
            &[0.0],
            &[0.0],
            &[-1.0],
            &[1.0],
            2000.0,
            &[1.0],
            0.0,
            &mut out
        )
        .is_err());
    }
}
