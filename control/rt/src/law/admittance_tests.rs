//! The admittance's tests (admittance.rs): the law's steps, its dead zone and damping, the
//! engagement probe, and numpy's semantics where they show.

use super::numpy_semantics::median;
use super::*;

const N: usize = 6;
const DT: f64 = 0.004;

fn law(rest_factor: f64) -> Admittance {
    Admittance::new(0.5, &[20.0; N], &[2.0; N], 5.0, &[1.0; N], rest_factor).unwrap()
}

fn diag(d: &[f64]) -> Vec<f64> {
    let n = d.len();
    let mut m = vec![0.0; n * n];
    for (i, v) in d.iter().enumerate() {
        m[i * n + i] = *v;
    }
    m
}

/// Uniform in [lo, hi) from a 64-bit xorshift (the tests need no statistics, only spread).
struct Rng(u64);
impl Rng {
    fn uniform(&mut self, lo: f64, hi: f64) -> f64 {
        self.0 ^= self.0 << 13;
        self.0 ^= self.0 >> 7;
        self.0 ^= self.0 << 17;
        lo + (hi - lo) * (self.0 >> 11) as f64 / (1u64 << 53) as f64
    }
}

#[test]
fn a_hand_torque_inside_the_dead_zone_leaves_the_arm_where_it_is() {
    let mut a = law(1.0);
    let q0: Vec<f64> = (0..N).map(|i| -0.3 + 0.12 * i as f64).collect();
    a.reset(&q0, None);
    let mass = diag(&[50.0, 200.0, 80.0, 1.0, 1.0, 0.3]);
    let mut rng = Rng(0x9e37_79b9_7f4a_7c15);
    for _ in 0..2000 {
        let raw: Vec<f64> = (0..N).map(|_| rng.uniform(-1.9, 1.9)).collect();
        a.step(&raw, &[0.0; N], &mass, DT, None).unwrap();
    }
    assert_eq!(a.q_r(), &q0[..]);
    assert_eq!(a.dq_r(), &[0.0; N]);
    assert!(!a.moving());
}

#[test]
fn a_steady_push_reaches_the_speed_the_damping_allows_beyond_the_band() {
    let mut a = law(1.0);
    a.reset(&[0.0; N], None);
    let mass = diag(&[50.0, 40.0, 80.0, 1.0, 1.0, 0.3]);
    let push = [0.0, 12.0, 0.0, -4.0, 0.0, 0.0];
    for _ in 0..2000 {
        a.step(&push, &[0.0; N], &mass, DT, None).unwrap();
    }
    let want = [0.0, 0.5, 0.0, -0.1, 0.0, 0.0];
    for (v, w) in a.dq_r().iter().zip(want) {
        assert!((v - w).abs() < 0.005, "{:?}", a.dq_r());
    }
    assert!(a.q_r()[1] > 0.0 && a.q_r()[3] < 0.0 && a.q_r()[0] == 0.0);
}

#[test]
fn the_implicit_damping_is_stable_at_any_step_and_the_speed_is_capped() {
    let mut a = Admittance::new(0.01, &[20.0; N], &[2.0; N], 5.0, &[0.5; N], 1.0).unwrap();
    a.reset(&[0.0; N], None);
    let mass = diag(&[1.0; N]);
    for dt in [0.004, 0.1, 1.0] {
        for _ in 0..50 {
            a.step(&[7.0; N], &[0.0; N], &mass, dt, None).unwrap();
            assert!(a.dq_r().iter().all(|v| v.abs() <= 0.5));
        }
    }
    a.reset(&[0.0; N], None);
    for _ in 0..500 {
        a.step(&[1e4; N], &[0.0; N], &mass, DT, None).unwrap();
    }
    assert_eq!(a.dq_r(), &[0.5; N]);
}

#[test]
fn the_speed_limit_scales_the_proposed_speed_and_sees_the_old_reference() {
    let mut a = law(1.0);
    a.reset(&[0.1; N], None);
    let mass = diag(&[1.0; N]);
    let mut seen = (0.0, 0.0);
    let mut half = |q: &[f64], dq: &[f64]| {
        seen = (q[0], dq[0]);
        0.5
    };
    a.step(&[1e3; N], &[0.0; N], &mass, DT, Some(&mut half))
        .unwrap();
    assert_eq!(seen.0, 0.1);
    assert!(seen.1 > 0.0);
    assert_eq!(a.dq_r()[0], 0.5 * seen.1);
    assert_eq!(a.q_r()[0], 0.1 + DT * 0.5 * a.dq_r()[0]);
}

#[test]
fn a_singular_system_is_refused_after_the_filter_took_the_sample_in() {
    let mut a = Admittance::new(0.5, &[0.0; 2], &[2.0; 2], 5.0, &[1.0; 2], 1.0).unwrap();
    a.reset(&[0.0; 2], None);
    let err = a.step(&[5.0, 0.0], &[0.0; 2], &[0.0; 4], DT, None);
    assert_eq!(err, Err("Singular matrix".to_string()));
    assert!(a.tau_h()[0] > 0.0);
}

#[test]
fn the_solve_pivots_as_lapack_does() {
    // a zero on the first diagonal needs a row swap
    let mut m = vec![0.0, 2.0, 1.0, 3.0, 1.0, 0.0, 1.0, 1.0, 4.0];
    let x = [1.0, -2.0, 0.5];
    let mut b: Vec<f64> = (0..3)
        .map(|i| (0..3).map(|j| m[i * 3 + j] * x[j]).sum())
        .collect();
    solve_in_place(&mut m, &mut b, 3).unwrap();
    for (v, w) in b.iter().zip(x) {
        assert!((v - w).abs() < 1e-14, "{b:?}");
    }
}

#[test]
fn bad_settings_are_refused() {
    let ok = [1.0; N];
    assert!(Admittance::new(0.0, &ok, &ok, 5.0, &ok, 1.0).is_err());
    assert!(Admittance::new(0.5, &ok, &ok, f64::NAN, &ok, 1.0).is_err());
    assert!(Admittance::new(0.5, &ok, &ok[..5], 5.0, &ok, 1.0).is_err());
    assert!(Admittance::new(0.5, &[-1.0; N], &ok, 5.0, &ok, 1.0).is_err());
    assert!(Admittance::new(0.5, &ok, &ok, 5.0, &[0.0; N], 1.0).is_err());
    assert!(Admittance::new(0.5, &ok, &ok, 5.0, &ok, 0.5).is_err());
    assert!(Admittance::new(0.5, &[1.0; 17], &[1.0; 17], 5.0, &[1.0; 17], 1.0).is_err());
    let err = Admittance::new(3.0, &ok, &ok, 5.0, &ok, 1.0).unwrap_err();
    assert_eq!(err, "admittance mass fraction 3.0 not in (0, 2]");
}

#[test]
fn a_guided_arm_that_only_creeps_settles_and_then_needs_the_static_zone_again() {
    let mut a = law(10.0);
    a.reset(&[0.0; N], Some(&[5.0 / 3.5; N]));
    assert!(a.band().iter().all(|b| (b - 5.0).abs() < 1e-12));
    let mass = diag(&[20.0; N]);
    let mut push = [0.0; N];
    push[1] = 6.0;
    for _ in 0..250 {
        a.step(&push, &[0.0; N], &mass, DT, None).unwrap();
    }
    assert!(a.moving() && a.dq_r()[1] > 0.05);
    push[1] = 2.2;
    let mut steps = 0;
    while a.moving() && steps < 2000 {
        a.step(&push, &[0.0; N], &mass, DT, None).unwrap();
        steps += 1;
    }
    assert!(!a.moving(), "the creep kept the arm guided");
    assert!(steps as f64 * DT < 2.0 + SETTLE_S);
    for _ in 0..500 {
        a.step(&push, &[0.0; N], &mass, DT, None).unwrap();
    }
    assert!(a.dq_r()[1].abs() < 1e-9);
}

#[test]
fn numpy_lets_nan_through_where_rust_would_not() {
    assert!(np_max(f64::NAN, 1.0).is_nan() && np_max(1.0, f64::NAN).is_nan());
    assert!(np_min(f64::NAN, 1.0).is_nan() && np_clip(f64::NAN, -1.0, 1.0).is_nan());
    assert!(np_sign(f64::NAN).is_nan());
    assert_eq!(np_sign(-0.0).to_bits(), 0.0f64.to_bits());
    assert!(median(&mut [1.0, f64::NAN, 2.0]).is_nan());
    assert_eq!(median(&mut [3.0, 1.0, 2.0, 10.0]), 2.5);
}

#[test]
fn the_probe_goes_out_both_ways_and_back_to_where_it_started() {
    let p = EngageProbe::new(&[0.01, 0.02], 0.5, DT, 2e-3).unwrap();
    assert_eq!(p.len(), 4 * 31 + 1);
    let last = p.offset(p.len() - 1);
    assert!(last.iter().all(|v| v.abs() < 1e-15), "{last:?}");
    let out: Vec<f64> = (0..p.len()).map(|k| p.offset(k)[0]).collect();
    let (hi, lo) = out
        .iter()
        .fold((0.0f64, 0.0f64), |(h, l), &v| (h.max(v), l.min(v)));
    assert!((hi + lo).abs() < 1e-15 && hi < 0.01 * 0.125 + 1e-12);
    assert_eq!(p.velocity(15), &[0.01, 0.02]);
    // cruise: + in the first and last quarters, − in the middle two, none on the ramps
    assert_eq!(
        (p.cruise()[0], p.cruise()[15], p.cruise()[46]),
        (0.0, 1.0, -1.0)
    );
    assert_eq!(p.cruise()[1], 0.0);
    // Python's round: half to even (0.25 × 0.1 / 0.01 = 2.5 → 2)
    assert_eq!(EngageProbe::new(&[0.01], 0.1, 0.01, 0.0).unwrap().len(), 9);
    assert!(EngageProbe::new(&[0.01], 0.5, 0.0, 0.0).is_err());
    assert!(EngageProbe::new(&[0.01], f64::NAN, DT, 0.0).is_err());
    assert!(EngageProbe::new(&[0.01], 1e12, DT, 0.0).is_err());
}

#[test]
fn the_probe_bias_is_the_mean_of_the_two_medians_or_the_rest_beyond_friction() {
    let mut p = EngageProbe::new(&[0.01, 0.01], 0.5, DT, 2e-3).unwrap();
    for k in 0..p.len() {
        let way = p.cruise()[k];
        let r = if way > 0.0 {
            -26.0 + k as f64 * 1e-3
        } else {
            34.0
        };
        p.observe(k, &[way * 0.01, 0.0], &[r, 7.0]);
    }
    p.observe(usize::MAX, &[0.01, 0.0], &[0.0, 0.0]);
    let (pos, neg) = p.samples(0);
    assert!(pos.min(neg) >= PROBE_MIN_SAMPLES);
    assert_eq!(p.samples(1), (0, 0));
    let (mut b, mut kept) = ([0.0; 2], [false; 2]);
    p.bias(&[29.0, 7.0], &[30.0, 5.0], &mut b, &mut kept);
    let plus: Vec<f64> = (0..p.len())
        .filter(|&k| p.cruise()[k] > 0.0)
        .map(|k| -26.0 + k as f64 * 1e-3)
        .collect();
    let mut sorted = plus.clone();
    let want = 0.5 * (median(&mut sorted) + 34.0);
    assert_eq!(b[0], want);
    assert_eq!(kept, [false, true]);
    assert_eq!(b[1], 2.0);
}

/// A full mass matrix: J1's deceleration drives J2's reference through the coupling.
fn coupled() -> Vec<f64> {
    let mut m = diag(&[50.0, 40.0, 20.0, 1.0, 1.0, 0.3]);
    m[1] = 15.0; // J1-J2
    m[N] = 15.0;
    m
}

/// Pushes J1 alone for `push_steps`, then lets go for `after_steps`; returns how far J2's
/// reference moved over the let-go's last 250 steps, after the arm has had time to stop.
fn let_go(a: &mut Admittance, push_steps: usize, after_steps: usize) -> f64 {
    a.reset(&[0.0; N], None);
    let mass = coupled();
    let push = [30.0, 0.0, 0.0, 0.0, 0.0, 0.0];
    for _ in 0..push_steps {
        a.step(&push, &[0.0; N], &mass, DT, None).unwrap();
    }
    let mut q2 = 0.0;
    for k in 0..after_steps {
        if k == after_steps - 250 {
            q2 = a.q_r()[1];
        }
        a.step(&[0.0; N], &[0.0; N], &mass, DT, None).unwrap();
    }
    (a.q_r()[1] - q2).abs()
}

#[test]
fn without_a_hold_a_joint_nobody_pushes_still_coasts_seconds_after_the_let_go() {
    // the behaviour the hold is for: J1's stop moves J2's reference through M̂, and the rest
    // damping only slows it down (an exponential never ends)
    let mut a = law(10.0);
    let travel = let_go(&mut a, 500, 1000);
    assert!(travel > 0.0, "J2's reference travelled {travel} rad");
    assert!(a.dq_r()[1] != 0.0);
    assert!(a.held().iter().all(|h| !h));
}

#[test]
fn with_a_hold_every_joint_stops_dead_once_slow_and_stays() {
    let mut a = law(10.0);
    a.set_hold(&[4e-3; N]).unwrap();
    let travel = let_go(&mut a, 500, 1000);
    assert_eq!(travel, 0.0, "J2's reference travelled {travel} rad");
    assert!(a.held().iter().all(|&h| h), "{:?}", a.held());
    assert_eq!(a.dq_r(), &[0.0; N]);
}

#[test]
fn each_joint_is_held_below_its_own_hold_speed() {
    // the let-go with J2's hold speed 0: J2 alone coasts on J1's stop, every other joint stops
    let mut a = law(10.0);
    a.set_hold(&[4e-3, 0.0, 4e-3, 4e-3, 4e-3, 4e-3]).unwrap();
    let travel = let_go(&mut a, 500, 1000);
    assert!(travel > 0.0, "J2's reference travelled {travel} rad");
    assert_eq!(a.held(), &[true, false, true, true, true, true]);
    assert_eq!(a.dq_r()[0], 0.0);
}

#[test]
fn a_push_beyond_the_static_band_releases_every_held_joint() {
    // while a hand pushes, every joint is guided as without a hold (the coupling helps a
    // stuck joint break away); a joint is held only once no push exceeds its static band
    let mut a = law(10.0);
    a.set_hold(&[4e-3; N]).unwrap();
    a.reset(&[0.0; N], None);
    assert!(a.held().iter().all(|&h| h));
    let mass = coupled();
    let push = [30.0, 0.0, 0.0, 0.0, 0.0, 0.0];
    for _ in 0..200 {
        a.step(&push, &[0.0; N], &mass, DT, None).unwrap();
    }
    assert!(a.held().iter().all(|h| !h), "{:?}", a.held());
    assert!(a.dq_r()[0] > 0.0 && a.dq_r()[1] != 0.0, "{:?}", a.dq_r());
    // a push inside the band holds J2-J6 (slow) and lets J1 coast down under the rest damping
    let inside = [1.0, 0.0, 0.0, 0.0, 0.0, 0.0];
    a.step(&inside, &[0.0; N], &mass, DT, None).unwrap();
    a.step(&inside, &[0.0; N], &mass, DT, None).unwrap();
    assert!(!a.held()[0], "J1 still fast: {:?}", a.dq_r());
    assert!(a.dq_r()[0] > 4e-3);
}

#[test]
fn a_wall_beyond_the_kinetic_band_moves_a_held_joint() {
    // a push on J1, the let-go until every joint is held, then a wall alone pushes J3 back
    // (a joint past its limit, or a guide's fixture): it acts as a hand, the hold lets it
    let mut a = law(10.0);
    a.set_hold(&[4e-3; N]).unwrap();
    let _ = let_go(&mut a, 200, 1000);
    assert!(a.held().iter().all(|&h| h), "{:?}", a.held());
    let mass = coupled();
    let wall = [0.0, 0.0, -5.0, 0.0, 0.0, 0.0];
    for _ in 0..100 {
        a.step(&[0.0; N], &wall, &mass, DT, None).unwrap();
    }
    assert!(!a.held()[2], "{:?}", a.held());
    assert!(a.dq_r()[2] < 0.0, "{:?}", a.dq_r());
    // one inside the kinetic band does not
    let mut b = law(10.0);
    b.set_hold(&[4e-3; N]).unwrap();
    let _ = let_go(&mut b, 200, 1000);
    for _ in 0..100 {
        b.step(&[0.0; N], &[0.0, 0.0, -1.5, 0.0, 0.0, 0.0], &mass, DT, None)
            .unwrap();
    }
    assert!(b.held()[2] && b.dq_r()[2] == 0.0, "{:?}", b.dq_r());
}

#[test]
fn the_hold_speed_must_be_finite_and_not_negative() {
    let mut a = law(1.0);
    assert!(a.set_hold(&[-1e-3; N]).is_err());
    assert!(a.set_hold(&[f64::NAN; N]).is_err());
    assert!(a.set_hold(&[f64::INFINITY; N]).is_err());
    assert!(a.set_hold(&[4e-3; 2]).is_err());
    assert!(a.set_hold(&[0.0; N]).is_ok());
    a.reset(&[0.0; N], None);
    assert!(a.held().iter().all(|h| !h));
}

/// J1 + J2 turn the tool together (one "orientation" row): the constraint keeps their sum
/// still while a hand pushes J1 alone.
const SUM_ROW: [f64; N] = [1.0, 1.0, 0.0, 0.0, 0.0, 0.0];

#[test]
fn a_constraint_row_is_met_while_a_hand_pushes_against_it() {
    let mut a = law(10.0);
    a.reset(&[0.0; N], None);
    a.set_constraint(&SUM_ROW, &[0.0]).unwrap();
    let mass = coupled();
    let push = [30.0, 0.0, 0.0, 0.0, 0.0, 0.0];
    for _ in 0..500 {
        a.step(&push, &[0.0; N], &mass, DT, None).unwrap();
        assert!((a.dq_r()[0] + a.dq_r()[1]).abs() < 1e-9, "{:?}", a.dq_r()); // the ridge
    }
    // the push moves what the row allows: J1 forward and J2 back by as much
    assert!(
        a.q_r()[0] > 0.05 && (a.q_r()[0] + a.q_r()[1]).abs() < 1e-9,
        "{:?}",
        a.q_r()
    );
    a.clear_constraint();
    for _ in 0..50 {
        a.step(&push, &[0.0; N], &mass, DT, None).unwrap();
    }
    assert!(
        (a.dq_r()[0] + a.dq_r()[1]).abs() > 1e-3,
        "free again: {:?}",
        a.dq_r()
    );
}

#[test]
fn a_held_joint_stays_still_under_a_constraint() {
    // the let-go under the row: once slow, J1 and J2 are held, and the projection keeps
    // them so while a wall pushes J3 (a wall moves its own joint, held or not)
    let mut a = law(10.0);
    a.set_hold(&[4e-3; N]).unwrap();
    a.set_constraint(&SUM_ROW, &[0.0]).unwrap();
    let travel = let_go(&mut a, 500, 1000);
    assert_eq!(travel, 0.0, "J2's reference travelled {travel} rad");
    assert!(a.held()[0] && a.held()[1], "{:?}", a.held());
    let q = a.q_r().to_vec();
    let mut wall = [0.0; N];
    wall[2] = 30.0;
    for _ in 0..100 {
        a.step(&[0.0; N], &wall, &coupled(), DT, None).unwrap();
    }
    assert!(a.q_r()[2] > q[2], "the wall moves J3");
    assert!((a.q_r()[0] - q[0]).abs() < 1e-9 && (a.q_r()[1] - q[1]).abs() < 1e-9);
}

#[test]
fn under_a_constraint_the_speed_cap_scales_every_joint_alike() {
    // a clip per joint would break the row; the cap scales the whole speed instead
    let mut a = Admittance::new(0.01, &[1.0; N], &[2.0; N], 5.0, &[0.5; N], 1.0).unwrap();
    a.reset(&[0.0; N], None);
    let row = [1.0, -0.5, 0.0, 0.0, 0.0, 0.0];
    a.set_constraint(&row, &[0.0]).unwrap();
    for _ in 0..200 {
        a.step(
            &[1e4, 0.0, 1e4, 0.0, 0.0, 0.0],
            &[0.0; N],
            &diag(&[1.0; N]),
            DT,
            None,
        )
        .unwrap();
    }
    let v = a.dq_r();
    assert!(v.iter().all(|x| x.abs() <= 0.5 + 1e-12), "{v:?}");
    assert!((v[0] - 0.5 * v[1]).abs() < 1e-8, "{v:?}"); // the ridge leaves 1e-9 of it
    assert!(
        v.iter().any(|x| (x.abs() - 0.5).abs() < 1e-12),
        "at the cap: {v:?}"
    );
}

#[test]
fn a_constraint_of_the_wrong_size_or_not_finite_is_refused() {
    let mut a = law(1.0);
    assert!(a.set_constraint(&[1.0; N - 1], &[0.0]).is_err());
    assert!(a.set_constraint(&[1.0; 7 * N], &[0.0; 7]).is_err());
    assert!(a.set_constraint(&SUM_ROW, &[f64::NAN]).is_err());
    a.set_constraint(&SUM_ROW, &[0.0]).unwrap();
}
