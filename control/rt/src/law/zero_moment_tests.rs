//! The zero-moment law's tests (zero_moment.rs): the mass matrix's inverse and Python's
//! rounding.

use super::regression::round_even;
use super::*;

#[test]
fn invert_gives_the_inverse() {
    let a = [4.0, 1.0, 0.5, 1.0, 3.0, 0.2, 0.5, 0.2, 2.0];
    let mut inv = [0.0; 9];
    invert(&a, 3, &mut inv).unwrap();
    for i in 0..3 {
        for k in 0..3 {
            let mut s = 0.0;
            for m in 0..3 {
                s += a[i * 3 + m] * inv[m * 3 + k];
            }
            let want = if i == k { 1.0 } else { 0.0 };
            assert!((s - want).abs() < 1e-14, "{i}{k}: {s}");
        }
    }
    assert!(invert(&[1.0, 2.0, 2.0, 4.0], 2, &mut inv).is_err());
}

#[test]
fn python_round_is_half_to_even() {
    assert_eq!(round_even(2.5), 2);
    assert_eq!(round_even(3.5), 4);
    assert_eq!(round_even(8.0), 8);
}
