//! The outer loop's tests (outer_loop.rs): eq. (21) delivering the desired torque, its limits,
//! the adaptation laws, the hold's calibration and average, and Python's and numpy's arithmetic.

use super::hold_average::pairwise_sum;
use super::*;

const K: [f64; 3] = [46.21, 66.18, 39.0];
const KP: [f64; 3] = [224.4, 375.3, 226.0];
const KI: [f64; 3] = [7479.0, 12510.0, 7532.0];

fn gains(omega_scale: f64, ups_scale: f64) -> ([f64; 3], [f64; 3]) {
    let omega = [0, 1, 2].map(|j| omega_scale / (K[j] * KP[j]));
    let ups = [0, 1, 2].map(|j| ups_scale * KI[j] / KP[j]);
    (omega, ups)
}

fn make(omega_scale: f64, ups_scale: f64, adaptation: Adaptation) -> OuterLoop {
    let (omega, ups) = gains(omega_scale, ups_scale);
    OuterLoop::new(&omega, &ups, &[0.05; 3], &[2.0; 3], adaptation).unwrap()
}

/// Eq. (19)'s torque [N·m] against the command (q_cmd, dq_cmd), the arm at (q, dq).
fn inner_loop_torque(j: usize, q: f64, dq: f64, q_cmd: f64, dq_cmd: f64) -> f64 {
    K[j] * (-KP[j] * (dq - dq_cmd) - KI[j] * (q - q_cmd))
}

fn run(lp: &mut OuterLoop, q: &[f64; 3], tau_d: &[f64; 3], cycles: usize) -> [f64; 3] {
    let (mut q_cmd, mut dq_cmd, mut sat) = ([0.0; 3], [0.0; 3], [false; 3]);
    for _ in 0..cycles {
        lp.step(
            q,
            &[0.0; 3],
            tau_d,
            0.004,
            &mut q_cmd,
            &mut dq_cmd,
            &mut sat,
        );
    }
    [0, 1, 2].map(|j| inner_loop_torque(j, q[j], 0.0, q_cmd[j], dq_cmd[j]))
}

#[test]
fn delivered_torque_converges_to_desired_with_exact_gains() {
    let mut lp = make(1.0, 1.0, Adaptation::None);
    let tau_d = [300.0, -800.0, 150.0];
    let tau = run(&mut lp, &[0.1, -0.2, 0.3], &tau_d, 200);
    for j in 0..3 {
        assert!((tau[j] / tau_d[j] - 1.0).abs() < 1e-6, "{tau:?}");
    }
}

#[test]
fn a_gain_estimate_twice_the_true_one_doubles_the_torque() {
    let mut lp = make(2.0, 1.0, Adaptation::None);
    let tau = run(&mut lp, &[0.0; 3], &[100.0; 3], 300);
    for t in tau {
        assert!((t / 200.0 - 1.0).abs() < 1e-6, "{tau:?}");
    }
}

#[test]
fn the_offset_is_clamped_and_flagged_and_nan_passes_the_limits() {
    let mut lp = make(1.0, 1.0, Adaptation::None);
    let (mut q_cmd, mut dq_cmd, mut sat) = ([0.0; 3], [0.0; 3], [false; 3]);
    for _ in 0..500 {
        let tau = [1e6, 0.0, f64::NAN];
        lp.step(
            &[0.0; 3],
            &[0.0; 3],
            &tau,
            0.004,
            &mut q_cmd,
            &mut dq_cmd,
            &mut sat,
        );
    }
    assert_eq!(q_cmd[0], 0.05);
    assert_eq!(sat, [true, false, false]);
    assert!(q_cmd[2].is_nan() && dq_cmd[2].is_nan());
}

#[test]
fn reset_clips_the_offset_and_the_next_command_carries_it() {
    let mut lp = make(1.0, 1.0, Adaptation::None);
    lp.reset(&[0.001, -0.2, f64::NAN]);
    assert_eq!(lp.offset_rad()[..2], [0.001, -0.05]);
    assert!(lp.offset_rad()[2].is_nan());
    let (mut q_cmd, mut dq_cmd, mut sat) = ([0.0; 3], [0.0; 3], [false; 3]);
    lp.step(
        &[1.0; 3],
        &[0.0; 3],
        &[0.0; 3],
        0.004,
        &mut q_cmd,
        &mut dq_cmd,
        &mut sat,
    );
    assert_eq!(q_cmd[..2], [1.001, 0.95]);
}

#[test]
fn bad_gains_and_settings_are_refused_naming_them() {
    let ok = [1.0; 3];
    let err = |a: Adaptation| OuterLoop::new(&ok, &ok, &ok, &ok, a).unwrap_err();
    let new = |w: &[f64], u: &[f64]| OuterLoop::new(w, u, &ok, &ok, Adaptation::None);
    assert!(new(&[1.0, 0.0, 1.0], &ok).unwrap_err().contains("positive"));
    assert!(new(&ok, &[1.0; 2])
        .unwrap_err()
        .contains("upsilon_i must have 3"));
    let omega = |rate: f64, floor: Vec<f64>| {
        Adaptation::Omega(OmegaAdaptation {
            rate_per_s: rate,
            min_torque_nm: floor,
        })
    };
    assert_eq!(
        err(omega(f64::NAN, vec![1.0; 3])),
        "adaptation rate nan must be >= 0"
    );
    assert!(err(omega(1.0, vec![1.0, 0.0, 1.0])).contains("min_torque_nm needs 3"));
    let paper = |ratio: f64, zones: Vec<f64>, bound: f64| {
        Adaptation::Paper(PaperAdaptation {
            rate_per_s: 1.0,
            min_torque_nm: vec![1.0; 3],
            upsilon_ratio: ratio,
            dead_zone_nm: zones,
            bound_factor: bound,
        })
    };
    assert!(err(paper(-1.0, vec![], 50.0)).contains("upsilon_ratio -1.0"));
    assert!(err(paper(2.0, vec![1.0; 2], 50.0)).contains("dead_zone_nm needs 3"));
    assert!(err(paper(2.0, vec![], 1.0)).contains("bound_factor 1.0 must be > 1"));
    assert!(OuterLoop::new(&ok, &ok, &ok, &ok, paper(2.0, vec![0.0; 3], 2.0)).is_ok());
}

fn paper(rate: f64, floor: f64, zones: Vec<f64>) -> Adaptation {
    Adaptation::Paper(PaperAdaptation {
        rate_per_s: rate,
        min_torque_nm: vec![floor; 3],
        upsilon_ratio: PaperAdaptation::UPSILON_RATIO,
        dead_zone_nm: zones,
        bound_factor: PaperAdaptation::BOUND_FACTOR,
    })
}

/// The torque a drive of the true gains reports over a cycle of means (u1, u2).
fn drive(u1: &[f64; 3], u2: &[f64; 3]) -> [f64; 3] {
    [0, 1, 2].map(|j| K[j] * KP[j] * (u1[j] + KI[j] / KP[j] * u2[j]))
}

#[test]
fn the_paper_laws_bring_the_static_gain_to_one_on_a_held_load() {
    let mut lp = make(1.25, 1.0, paper(1.0, 1.0, vec![]));
    let (u1, u2) = ([0.0; 3], [0.003, -0.004, 0.001]);
    for _ in 0..2500 {
        lp.adapt(&u1, &u2, &drive(&u1, &u2), 0.004);
    }
    for j in 0..3 {
        let gain = lp.omega()[j] * K[j] * KI[j] / lp.upsilon_i()[j];
        assert!((gain - 1.0).abs() < 0.005, "joint {j}: {gain}");
    }
}

#[test]
fn eq28_learns_omega_alone_and_skips_nan_and_small_torques() {
    let a = Adaptation::Omega(OmegaAdaptation {
        rate_per_s: 1.0,
        min_torque_nm: vec![1.0; 3],
    });
    let mut lp = make(1.2, 1.0, a);
    let before = lp.omega().to_vec();
    lp.adapt(&[f64::NAN; 3], &[0.001; 3], &[10.0; 3], 0.008);
    lp.adapt(&[0.0; 3], &[0.001; 3], &[f64::NAN; 3], 0.008);
    lp.adapt(&[0.0; 3], &[1e-9; 3], &[500.0; 3], 0.008);
    assert_eq!(lp.omega(), &before[..]);
    let (u1, u2) = ([0.0; 3], [0.003, -0.004, 0.002]);
    for _ in 0..5000 {
        lp.adapt(&u1, &u2, &drive(&u1, &u2), 0.004);
    }
    let (omega, _) = gains(1.0, 1.0);
    for (got, want) in lp.omega().iter().zip(omega) {
        assert!((got / want - 1.0).abs() < 1e-3, "{:?}", lp.omega());
    }
    assert_eq!(lp.upsilon_i(), &gains(1.0, 1.0).1[..]);
}

#[test]
fn the_hold_calibrates_omega_within_its_projection_and_the_dead_zone_keeps_its_floor() {
    let mut lp = make(1.0, 1.0, paper(1.0, 5.0, vec![1e4, 0.0, 0.0]));
    let (omega, ups) = gains(1.0, 1.0);
    // joint 0 calibrated, joint 1 below its floor, joint 2 sign disagreeing
    lp.calibrate_from_hold(&[0.002, 0.002, -0.002], &[100.0, 1.0, 100.0]);
    assert_eq!(lp.omega()[0], ups[0] * 0.002 / 100.0);
    assert_eq!(lp.omega()[1..], omega[1..]);
    lp.calibrate_from_hold(&[1e9, 0.0, 0.0], &[100.0, 0.0, 0.0]);
    assert_eq!(lp.omega()[0], omega[0] * 50.0);
    lp.set_dead_zone(&[1.0, 2.0, f64::NAN]);
    assert_eq!(lp.dead_zone_nm(), &[1e4, 6.0, 0.0]);
}

#[test]
fn the_hold_average_keeps_the_last_states_in_order() {
    let mut hold = HoldAverage::new(3);
    let (mut offs, mut taus, mut std) = ([0.0; 2], [0.0; 2], [0.0; 2]);
    assert_eq!(
        hold.mean(&mut offs, &mut taus).unwrap_err(),
        "no hold observed"
    );
    hold.add(&[1.0, 2.0], &[10.0, 20.0]).unwrap();
    assert!(hold.torque_std(&mut std).is_err());
    assert!(hold
        .add(&[1.0], &[1.0])
        .unwrap_err()
        .contains("needs 2 values"));
    for k in 2..=5 {
        let k = f64::from(k);
        hold.add(&[k, 2.0 * k], &[10.0 * k, 20.0]).unwrap();
    }
    assert_eq!(hold.len(), 3); // 3, 4, 5 held
    hold.mean(&mut offs, &mut taus).unwrap();
    assert_eq!((offs, taus), ([4.0, 8.0], [40.0, 20.0]));
    hold.torque_std(&mut std).unwrap();
    assert_eq!(std, [10.0, 0.0]);
    hold.clear();
    assert!(hold.is_empty());
    hold.add(&[1.0], &[2.0]).unwrap(); // any joint count again
    assert_eq!(hold.n(), 1);
}

#[test]
fn hypot_is_pythons() {
    // math.hypot in CPython 3.11, where it differs from libm's (checked there)
    assert_eq!(py_hypot(3.0, -4.0), 5.0);
    assert_eq!(py_hypot(f64::INFINITY, f64::NAN), f64::INFINITY);
    assert!(py_hypot(f64::NAN, 1.0).is_nan());
    assert_eq!(py_hypot(0.0, -0.0), 0.0);
    assert_eq!(py_hypot(3e-320, 4e-320), 5e-320);
    assert_eq!(frexp_exponent(1.0), 1);
    assert_eq!(frexp_exponent(f64::from_bits(1)), -1073);
    assert_eq!(power_of_two(-1074), f64::from_bits(1));
}

#[test]
fn pairwise_sum_is_numpys_blocking() {
    let v: Vec<f64> = (0..300).map(|i| 1.0 / f64::from(i + 1)).collect();
    let got = pairwise_sum(0, v.len(), &|i| v[i]);
    let halves = pairwise_sum(0, 144, &|i| v[i]) + pairwise_sum(144, 156, &|i| v[i]);
    assert_eq!(got, halves);
    assert_eq!(pairwise_sum(0, 3, &|i| v[i]), (0.0 + v[0]) + v[1] + v[2]);
}
