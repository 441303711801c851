//! Whether the zero-moment arm is being guided, for its friction compensation
//! (the zero-moment law in control/zero_moment_law.py uses it).
//!
//! The compensation ramps in with speed so that an arm at rest does not chatter on its
//! stiction; a guided arm pays for it (on the teach bench's raster the painter pushed 55 N on
//! average with the ramp against 22 N without it). So the ramp applies only to an arm at rest:
//! once one of the positioning joints (the first [`POSITIONING_JOINTS`], whose inertia makes a
//! chatter of theirs unlikely) slides faster than its ramp, every joint's friction is
//! compensated in full until all of them have been slower than their ramps for `hold_s`.

/// The joints whose sliding tells a guided arm (J1-J3).
pub const POSITIONING_JOINTS: usize = 3;

/// The guided/at-rest switch, one update per cycle.
#[derive(Clone, Debug)]
pub struct GuidedFriction {
    hold_s: f64,
    guided: bool,
    /// how long the positioning joints have been slower than their ramps [s]
    slow_s: f64,
}

impl GuidedFriction {
    /// A switch that releases `hold_s` [s] after the positioning joints slowed (0 or less:
    /// never guided).
    pub fn new(hold_s: f64) -> GuidedFriction {
        GuidedFriction {
            hold_s,
            guided: false,
            slow_s: 0.0,
        }
    }

    pub fn hold_s(&self) -> f64 {
        self.hold_s
    }

    pub fn guided(&self) -> bool {
        self.guided
    }

    /// Take in a cycle's measured velocities [rad/s] and the joints' ramp speeds [rad/s];
    /// true while the arm is guided. Only the first [`POSITIONING_JOINTS`] of each are read;
    /// where those differ in count an error names them, unless a sliding joint came first
    /// (as Python's strict `zip` under `any` did).
    pub fn update(&mut self, dq_rad_s: &[f64], ramps: &[f64], dt_s: f64) -> Result<bool, String> {
        if self.hold_s <= 0.0 {
            return Ok(false);
        }
        let dq = &dq_rad_s[..dq_rad_s.len().min(POSITIONING_JOINTS)];
        let ramps = &ramps[..ramps.len().min(POSITIONING_JOINTS)];
        let sliding = dq.iter().zip(ramps).any(|(v, r)| v.abs() > *r && *r > 0.0);
        if !sliding && dq.len() != ramps.len() {
            return Err(format!(
                "guided friction: {} positioning joints in dq_rad_s, {} in ramps",
                dq.len(),
                ramps.len()
            ));
        }
        if sliding {
            self.guided = true;
            self.slow_s = 0.0;
        } else if self.guided {
            self.slow_s += dt_s;
            self.guided = self.slow_s < self.hold_s;
        }
        Ok(self.guided)
    }

    pub fn reset(&mut self) {
        self.guided = false;
        self.slow_s = 0.0;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const RAMPS: [f64; 6] = [0.01, 0.01, 0.01, 0.1, 0.1, 0.1];

    #[test]
    fn a_positioning_joint_past_its_ramp_guides_until_slow_for_hold_s() {
        let mut g = GuidedFriction::new(0.3);
        let wrists = [0.0, 0.0, 0.0, 0.5, 0.5, 0.5];
        assert!(!(0..100).any(|_| g.update(&wrists, &RAMPS, 0.004).unwrap()));
        let j2 = [0.0, 0.02, 0.0, 0.0, 0.0, 0.0];
        assert!(g.update(&j2, &RAMPS, 0.004).unwrap());
        let slow = [0.005, 0.005, 0.005, 0.0, 0.0, 0.0];
        let held: Vec<bool> = (0..100)
            .map(|_| g.update(&slow, &RAMPS, 0.004).unwrap())
            .collect();
        assert!(held[..74].iter().all(|&h| h) && !held[75..].iter().any(|&h| h));
        assert!(!GuidedFriction::new(0.0).update(&j2, &RAMPS, 0.004).unwrap());
        g.update(&j2, &RAMPS, 0.004).unwrap();
        g.reset();
        assert!(!g.guided());
    }

    #[test]
    fn positioning_joints_of_different_counts_are_refused_unless_one_slides_first() {
        let mut g = GuidedFriction::new(0.3);
        assert!(g.update(&[0.0, 0.0], &RAMPS, 0.004).is_err());
        assert!(g.update(&[0.02, 0.0], &RAMPS, 0.004).unwrap());
    }
}
