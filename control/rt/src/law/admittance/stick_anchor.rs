//! The admittance's stick anchor (`[control] admittance_stick = "anchor"`): what a resting
//! joint's friction carries is taken off its hand torque estimate, and nothing more.
//!
//! At rest a joint's friction holds whatever share of its load it was left with when it
//! stopped, anywhere within its static level, and the motor current cannot tell that share from
//! a hand. The stick zone (`"zone"`) dead-zones the estimate of a joint at rest by the model's
//! friction level, symmetric about zero; but the estimate of a stuck joint already lacks what
//! the friction holds (the drive does not feel a push the friction takes), so a push must break
//! the friction away and then exceed the zone as well: about twice the static level. On plant
//! seed 102 J1 (about 50 N·m static) stayed stuck for 14 s under 76 N·m of the hand
//! (teach-bench, 2026-12-01).
//!
//! While a joint is stuck and its reference rests, the drive's torque follows the command
//! alone: the hand, the model's error and the friction's share change nothing it gives. The
//! estimate `τ̂ = τ_model − K i − b` then stays where the joint stopped, whatever the hand does,
//! until the push breaks the friction away: the joint slips, the vendor loop pulls it back, and
//! the estimate moves by what the push exceeds the friction by. So the anchor is the
//! (low-passed) estimate at the moment the joint came to rest, followed slowly while the
//! estimate stays within the dead zone of it (a drift of the model's share as other joints
//! move, the cylinders), and a joint at rest is pushed by `τ̂ − anchor`: it moves once the hand
//! has broken it away, not a static level later. The anchor fades out as the joint slides, as
//! the stick zone does.

use crate::chain::MAX_JOINTS;

/// Within the dead zone of its anchor, a resting joint's estimate is followed with this time
/// constant [s]: slower than a push that has broken the friction away changes it (the vendor
/// loop's integral pulls a slipping joint back within tens of ms), faster than the model's
/// share drifts as the other joints move through a pass (seconds).
pub const FOLLOW_S: f64 = 1.0;
/// A joint that has just come to rest takes its estimate as its anchor for this long [s]: as
/// it stops, the model's friction leaves the estimate and the drive's feedforward leaves the
/// current a loop delay apart, and the friction takes up its share (a few cycles, and the
/// estimate's low-pass); a push in that moment waits for it.
pub const SETTLE_S: f64 = 0.5;

/// Per joint, the estimate a resting joint stopped with (module docs).
#[derive(Clone, Debug)]
pub struct StickAnchor {
    n: usize,
    filter_hz: f64,
    anchor: [f64; MAX_JOINTS],
    filtered: Option<[f64; MAX_JOINTS]>,
    rested_s: [f64; MAX_JOINTS],
}

impl StickAnchor {
    /// Err where `n` is not 1..=MAX_JOINTS or `filter_hz` not > 0.
    pub fn new(n: usize, filter_hz: f64) -> Result<StickAnchor, String> {
        if n == 0 || n > MAX_JOINTS {
            return Err(format!("stick anchor: {n} joints"));
        }
        if !(filter_hz > 0.0) {
            return Err(format!("stick anchor: filter {filter_hz} Hz must be > 0"));
        }
        Ok(StickAnchor {
            n,
            filter_hz,
            anchor: [0.0; MAX_JOINTS],
            filtered: None,
            rested_s: [0.0; MAX_JOINTS],
        })
    }

    pub fn n(&self) -> usize {
        self.n
    }

    /// The anchors [N·m].
    pub fn anchor(&self) -> &[f64] {
        &self.anchor[..self.n]
    }

    /// Forget the anchors (the admittance starts again).
    pub fn reset(&mut self) {
        self.anchor = [0.0; MAX_JOINTS];
        self.filtered = None;
        self.rested_s = [0.0; MAX_JOINTS];
    }

    /// `τ̂ − anchor` per joint into `rel` [N·m], and into `settled` the joints that have rested
    /// longer than [`SETTLE_S`], for which the difference is the push (elsewhere it means
    /// nothing). `resting`: the joints at rest this cycle. A joint that has just come to rest
    /// takes its filtered estimate as its anchor for [`SETTLE_S`]; then, while it rests, the
    /// anchor follows the estimate within `band` of it over [`FOLLOW_S`] and stays where it is
    /// beyond.
    pub fn hand(
        &mut self,
        tau_h: &[f64],
        resting: &[bool],
        band: &[f64],
        dt_s: f64,
        rel: &mut [f64],
        settled: &mut [bool],
    ) {
        let n = self.n;
        let a = 1.0 - (-2.0 * std::f64::consts::PI * self.filter_hz * dt_s).exp();
        let f = match self.filtered.as_mut() {
            None => {
                let mut first = [0.0; MAX_JOINTS];
                first[..n].copy_from_slice(&tau_h[..n]);
                self.filtered.insert(first)
            }
            Some(f) => {
                for j in 0..n {
                    f[j] += a * (tau_h[j] - f[j]);
                }
                f
            }
        };
        let follow = (dt_s / FOLLOW_S).min(1.0);
        for j in 0..n {
            self.rested_s[j] = if resting[j] {
                self.rested_s[j] + dt_s
            } else {
                0.0
            };
            settled[j] = self.rested_s[j] > SETTLE_S;
            let near = settled[j] && (f[j] - self.anchor[j]).abs() <= band[j];
            let rate = if !settled[j] {
                1.0
            } else if near {
                follow
            } else {
                0.0
            };
            self.anchor[j] += rate * (f[j] - self.anchor[j]);
            rel[j] = tau_h[j] - self.anchor[j];
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const DT: f64 = 0.008;

    #[test]
    fn a_settled_joint_is_pushed_by_what_moved_it_off_its_anchor() {
        let mut a = StickAnchor::new(1, 5.0).unwrap();
        let (mut rel, mut settled) = ([0.0], [false]);
        for _ in 0..((SETTLE_S / DT) as usize + 20) {
            a.hand(&[12.0], &[true], &[3.0], DT, &mut rel, &mut settled);
        }
        assert!(settled[0]);
        assert!((a.anchor()[0] - 12.0).abs() < 1e-6, "{:?}", a.anchor());
        a.hand(&[32.0], &[true], &[3.0], DT, &mut rel, &mut settled);
        assert!((rel[0] - 20.0).abs() < 1e-6, "{rel:?}");
    }

    #[test]
    fn a_sliding_joint_is_never_settled_and_follows_its_estimate() {
        let mut a = StickAnchor::new(2, 5.0).unwrap();
        let (mut rel, mut settled) = ([0.0; 2], [false; 2]);
        for _ in 0..200 {
            a.hand(
                &[5.0, -5.0],
                &[false, true],
                &[1.0, 1.0],
                DT,
                &mut rel,
                &mut settled,
            );
        }
        assert_eq!(settled, [false, true]);
        assert_eq!(rel[0], 0.0);
    }

    #[test]
    fn bad_settings_are_refused() {
        assert!(StickAnchor::new(0, 5.0).is_err());
        assert!(StickAnchor::new(MAX_JOINTS + 1, 5.0).is_err());
        assert!(StickAnchor::new(6, f64::NAN).is_err());
        assert!(StickAnchor::new(6, 0.0).is_err());
    }
}
