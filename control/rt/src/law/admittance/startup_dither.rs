//! The admittance's start-up dither (`[control] admittance_dither`): the painter's first push
//! from rest breaks a joint's static friction with help (issue 47, item 2).
//!
//! A joint at rest is held by its static friction, and the drive's current does not change
//! while the friction carries the hand's torque: the admittance sees no hand until the push
//! alone has broken the joint away (the demo's J2: about 60 N·m, 46 N at the tool). As Li et
//! al. (Robotica 2025) compensate start-up torque, each joint whose reference rests gets a sine
//! of a share of the model's static friction level on the torque the command asks of the
//! vendor loop; the joints' phases are spread over the period. Below the breakaway it moves
//! nothing by itself: the vendor loop's position stiffness (J2: some 800 N·m per mrad) keeps
//! any slip to tens of µrad. On every swing towards a push the hand needs only the rest of the
//! breakaway; the joint then slips, the loop pulls it back, and the current shows the push.
//!
//! The drive gives the dither too, so the current of a cycle carries the dither that drove it:
//! [`StartupDither::drove`] is that torque, which the admittance adds back to its estimate
//! (`τ̂_h = τ_model − b − (K i − d)`), so a stuck joint's estimate does not swing with it. The
//! dither fades in over [`FADE_S`] after the admittance starts (a step would jolt the arm) and,
//! per joint, out as its reference moves faster than the rest speed (to nothing at twice it).

use std::collections::VecDeque;

use crate::chain::MAX_JOINTS;

/// The dither fades in over this after the admittance starts [s].
pub const FADE_S: f64 = 0.25;

/// Per joint, the dither's torque of each command and of the one that drove a state.
#[derive(Clone, Debug)]
pub struct StartupDither {
    share: f64,
    hz: f64,
    rest_rad_s: f64,
    /// Commands' dithers, newest last: at most `delay + 1` (allocated once).
    sent: VecDeque<[f64; MAX_JOINTS]>,
    keep: usize,
    level: [f64; MAX_JOINTS],
    n: usize,
    phase: f64,
    gain: f64,
}

impl StartupDither {
    /// `share` of the friction level in [0, 1), at `hz` > 0, fading out from `rest_rad_s` > 0;
    /// `delay_cycles` the command delay (the state in was driven `delay + 1` commands back).
    pub fn new(
        share: f64,
        hz: f64,
        rest_rad_s: f64,
        delay_cycles: usize,
    ) -> Result<StartupDither, String> {
        if !(share.is_finite() && (0.0..1.0).contains(&share)) {
            return Err(format!("start-up dither: share {share} not in [0, 1)"));
        }
        if !(hz.is_finite() && hz > 0.0) {
            return Err(format!("start-up dither: {hz} Hz must be > 0"));
        }
        if !(rest_rad_s > 0.0) {
            return Err(format!(
                "start-up dither: rest speed {rest_rad_s} rad/s must be > 0"
            ));
        }
        let keep = delay_cycles + 1;
        Ok(StartupDither {
            share,
            hz,
            rest_rad_s,
            sent: VecDeque::with_capacity(keep + 1),
            keep,
            level: [0.0; MAX_JOINTS],
            n: 0,
            phase: 0.0,
            gain: 0.0,
        })
    }

    pub fn share(&self) -> f64 {
        self.share
    }

    /// Starts again (faded out) on joints of this static friction level [N·m] (at most
    /// MAX_JOINTS; negative levels count as 0).
    pub fn reset(&mut self, friction_level_nm: &[f64]) {
        self.n = friction_level_nm.len().min(MAX_JOINTS);
        for (l, &f) in self.level.iter_mut().zip(friction_level_nm) {
            // np.maximum: NaN stays
            *l = if f.is_nan() { f } else { f.max(0.0) };
        }
        self.sent.clear();
        self.phase = 0.0;
        self.gain = 0.0;
    }

    /// The dither's torque into `out` [N·m] for the command of a cycle of `dt_s` whose
    /// reference speeds are `dq_r` [rad/s], remembered for [`StartupDither::drove`].
    pub fn step(&mut self, dq_r: &[f64], dt_s: f64, out: &mut [f64]) {
        let n = self.n;
        let mut d = [0.0; MAX_JOINTS];
        if self.share > 0.0 && n > 0 {
            self.gain = (self.gain + dt_s / FADE_S).min(1.0);
            let turn = 2.0 * std::f64::consts::PI;
            self.phase = (self.phase + turn * self.hz * dt_s).rem_euclid(turn);
            for j in 0..n {
                // np.clip(2 - |dq| / rest, 0, 1)
                let fade = (2.0 - dq_r[j].abs() / self.rest_rad_s).clamp(0.0, 1.0);
                let phase = self.phase + turn * j as f64 / n as f64;
                d[j] = self.gain * self.share * fade * self.level[j] * phase.sin();
            }
        }
        if self.sent.len() == self.keep {
            self.sent.pop_front();
        }
        self.sent.push_back(d);
        out[..n].copy_from_slice(&d[..n]);
    }

    /// The dither of the command that drove the state now in (`delay + 1` back; none before so
    /// many were sent) into `out` [N·m].
    pub fn drove(&self, out: &mut [f64]) {
        let n = self.n;
        match self.sent.front() {
            Some(d) if self.sent.len() == self.keep => out[..n].copy_from_slice(&d[..n]),
            _ => out[..n].fill(0.0),
        }
    }

    /// The number of joints of the last reset.
    pub fn n(&self) -> usize {
        self.n
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_dither_of_a_state_is_the_command_delay_plus_one_back() {
        let mut d = StartupDither::new(0.5, 4.0, 0.002, 2).unwrap();
        d.reset(&[10.0, 10.0]);
        let mut sent = vec![];
        let mut out = [0.0; 2];
        for _ in 0..10 {
            d.step(&[0.0, 0.0], 0.008, &mut out);
            sent.push(out);
        }
        let mut drove = [0.0; 2];
        d.drove(&mut drove);
        assert_eq!(drove, sent[7]);
    }

    #[test]
    fn a_moving_reference_gets_no_dither_and_share_zero_none() {
        let mut d = StartupDither::new(0.5, 4.0, 0.002, 0).unwrap();
        d.reset(&[10.0]);
        let mut out = [1.0];
        for _ in 0..100 {
            d.step(&[0.004], 0.008, &mut out);
            assert_eq!(out[0], 0.0);
        }
        let mut off = StartupDither::new(0.0, 4.0, 0.002, 0).unwrap();
        off.reset(&[10.0]);
        off.step(&[0.0], 0.008, &mut out);
        assert_eq!(out[0], 0.0);
    }

    #[test]
    fn bad_settings_are_refused() {
        assert!(StartupDither::new(1.0, 4.0, 0.002, 0).is_err());
        assert!(StartupDither::new(-0.1, 4.0, 0.002, 0).is_err());
        assert!(StartupDither::new(0.5, 0.0, 0.002, 0).is_err());
        assert!(StartupDither::new(0.5, f64::INFINITY, 0.002, 0).is_err());
        assert!(StartupDither::new(0.5, 4.0, 0.0, 0).is_err());
    }
}
