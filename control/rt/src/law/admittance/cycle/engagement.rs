//! The admittance's engagement (cycle.rs): after the arm has rested in the driver's hold,
//! ω̂ calibrated from the hold, the residual b of (A1) at rest and the model's friction level at
//! the pose, then the engagement probe (every joint a few mrad out and back, whose sliding
//! residuals give b free of what friction carried at rest), then the admittance's start where
//! the arm is.

#![allow(clippy::needless_range_loop)] // per-joint arithmetic reads as the formulas

use super::super::numpy_semantics::np_max;
use super::super::{Admittance, EngageProbe};
use super::{
    fmt_list, AdmittanceCycle, Joints, Probe, MIN_NOISE_STATES, PROBE_BREAKAWAY_SHARE,
    PROBE_MAX_RAD_S,
};
use crate::chain::MAX_JOINTS;
use crate::law::zero_moment::{Parts, State, ZeroMoment};

impl AdmittanceCycle {
    /// The engagement probe's cruise speed per joint [rad/s] into `out`: at least the
    /// configured one, and fast enough that the command leads a joint stuck at one end of its
    /// friction by enough to break it away the other way, `2 × 2 f / k` (f the model's
    /// friction level, twice for a true static level above it; k = Υ̂_I / ω̂ the vendor loop's
    /// position stiffness), within [`PROBE_BREAKAWAY_SHARE`] of a quarter of the probe; at
    /// most [`PROBE_MAX_RAD_S`].
    pub fn probe_speeds(&self, omega: &[f64], upsilon_i: &[f64], level: &[f64], out: &mut [f64]) {
        let quarter = 0.25 * self.s.probe_s;
        for j in 0..self.n {
            let lead = 4.0 * level[j] * omega[j] / upsilon_i[j];
            let speed = np_max(
                self.s.probe_speed_rad_s,
                lead / (PROBE_BREAKAWAY_SHARE * quarter),
            );
            out[j] = if speed.is_nan() {
                speed
            } else {
                speed.min(PROBE_MAX_RAD_S)
            };
        }
    }

    pub(super) fn engage(
        &mut self,
        zm: &mut ZeroMoment,
        parts: &mut Parts,
        adm: &mut Admittance,
        st: &State,
        p_bar: &[f64],
        period: f64,
    ) -> Result<(), String> {
        let n = self.n;
        let mut tau_m = [0.0; MAX_JOINTS];
        let mut noise: Option<Joints> = None;
        if !parts.hold.is_empty() {
            let mut offset = [0.0; MAX_JOINTS];
            parts.hold.mean(&mut offset[..n], &mut tau_m[..n])?;
            parts.outer.calibrate_from_hold(&offset[..n], &tau_m[..n]);
            if parts.hold.len() >= MIN_NOISE_STATES {
                let mut std = [0.0; MAX_JOINTS];
                parts.hold.torque_std(&mut std[..n])?;
                let mut filtered = [0.0; MAX_JOINTS];
                adm.filtered_noise(&std[..n], period, &mut filtered[..n]);
                noise = Some(filtered);
            }
        } else {
            zm.motor_torque(st.current_a, &mut tau_m[..n]);
        }
        let mut at_rest = [0.0; MAX_JOINTS];
        Self::static_torque(zm, parts.model, &st.q[..n], p_bar, &mut at_rest[..n])?;
        for j in 0..n {
            self.bias[j] = at_rest[j] - tau_m[j];
        }
        // the model's friction at the engagement pose: the stick zone, the probe's speeds and
        // the fallback of a joint the probe did not slide
        let mut level = [0.0; MAX_JOINTS];
        zm.friction_level_at(parts.model, &st.q[..n], &mut level[..n]);
        self.friction_level = level;
        for j in 0..n {
            self.stick[j] = self.s.stick_zone * level[j];
        }
        parts.hold.clear();
        self.sent_ddq.clear();
        zm.engaged = true;
        zm.last_cycle = Some(st.cycle - 1);
        if self.s.probe_speed_rad_s > 0.0 {
            let mut speeds = [0.0; MAX_JOINTS];
            self.probe_speeds(
                parts.outer.omega(),
                parts.outer.upsilon_i(),
                &level[..n],
                &mut speeds[..n],
            );
            let probe = EngageProbe::new(&speeds[..n], self.s.probe_s, period, zm.s.rest_rad_s)?;
            let mut q0 = [0.0; MAX_JOINTS];
            q0[..n].copy_from_slice(&st.q_cmd[..n]);
            let seconds = probe.len() as f64 * period;
            self.probe = Some(Probe {
                probe,
                start: st.cycle,
                q0,
                noise,
                period_s: period,
            });
            self.event(
                false,
                format!(
                "admittance probe: {seconds:.1} s, every joint a few mrad out and back to measure \
                 the model's error; the painter holds the tool lightly"
            ),
            );
        } else {
            self.start(zm, adm, &st.q[..n], noise.as_ref().map(|v| &v[..n]));
        }
        Ok(())
    }

    /// The admittance starts at rest at `q` (after the probe, or at once without one).
    pub(super) fn start(
        &mut self,
        zm: &mut ZeroMoment,
        adm: &mut Admittance,
        q: &[f64],
        noise: Option<&[f64]>,
    ) {
        let n = self.n;
        adm.reset(q, noise);
        self.anchor.reset();
        self.drive_own = 0;
        self.dither.reset(&self.friction_level[..n]);
        zm.guide.restart();
        self.sent_ddq.clear();
        let text = format!(
            "admittance engaged: dead zone {} N·m, residual b {} N·m, joints nobody pushes held \
             below {} rad/s",
            fmt_list(adm.band(), 3),
            fmt_list(&self.bias[..n], 2),
            fmt_list(adm.hold_rad_s(), 4),
        );
        self.event(false, text);
    }

    /// One cycle of the engagement probe: take in the state the probe's command `delay + 1`
    /// cycles back drove, answer with its next command; at its end, `b` and the admittance's
    /// start.
    #[allow(clippy::too_many_arguments)]
    pub(super) fn probe_cycle(
        &mut self,
        zm: &mut ZeroMoment,
        parts: &mut Parts,
        adm: &mut Admittance,
        st: &State,
        p_bar: &[f64],
        q_cmd: &mut [f64],
        dq_cmd: &mut [f64],
    ) -> Result<(), String> {
        let n = self.n;
        let delay = zm.s.command_delay_cycles as i64;
        let flags = zm.s.flag_prev_hold | zm.s.flag_prev_coast;
        let Some(p) = self.probe.as_mut() else {
            return Ok(());
        };
        let k = st.cycle - p.start;
        let drove = k - (delay + 1);
        zm.last_cycle = Some(st.cycle);
        if drove >= 0 && st.flags & flags == 0 {
            let mut residual = [0.0; MAX_JOINTS];
            Self::static_torque(zm, parts.model, &st.q[..n], p_bar, &mut residual[..n])?;
            let mut tau_m = [0.0; MAX_JOINTS];
            zm.motor_torque(st.current_a, &mut tau_m[..n]);
            for j in 0..n {
                residual[j] -= tau_m[j];
            }
            if !residual[..n].iter().all(|v| v.is_finite()) {
                return Err(format!(
                    "cycle {}: hand torque estimate undefined",
                    st.cycle
                ));
            }
            p.probe.observe(drove as usize, &st.dq[..n], &residual[..n]);
        }
        let len = p.probe.len() as i64;
        if drove < len - 1 {
            let i = k.clamp(0, len - 1) as usize;
            let (offset, velocity) = (p.probe.offset(i), p.probe.velocity(i));
            for j in 0..n {
                q_cmd[j] = p.q0[j] + offset[j];
                dq_cmd[j] = velocity[j];
            }
            return Ok(());
        }
        let mut b = [0.0; MAX_JOINTS];
        let mut kept = [false; MAX_JOINTS];
        p.probe.bias(
            &self.bias[..n],
            &self.friction_level[..n],
            &mut b[..n],
            &mut kept[..n],
        );
        let samples: Vec<String> = (0..n)
            .map(|j| {
                let (plus, minus) = p.probe.samples(j);
                format!("({plus}, {minus})")
            })
            .collect();
        let noise = p.noise;
        self.bias = b;
        self.probe = None;
        self.event(
            false,
            format!(
                "admittance probe: sliding samples (+, -) per joint [{}]",
                samples.join(", ")
            ),
        );
        let stuck: Vec<String> = (0..n)
            .filter(|&j| kept[j])
            .map(|j| (j + 1).to_string())
            .collect();
        if !stuck.is_empty() {
            self.event(
                true,
                format!(
                "admittance probe: joints [{}] did not slide both ways; their residual b is the \
                 one at rest beyond their friction",
                stuck.join(", ")
            ),
            );
        }
        // the reference starts where the arm is: one where the probe began would lead a joint
        // the probe left stuck a little off by a torque its friction cannot hold (J2: 0.05
        // mrad is 40 N·m of the vendor loop), which reads as a hand, and J2/J3 hunted
        self.start(zm, adm, &st.q[..n], noise.as_ref().map(|v| &v[..n]));
        let period = if st.period_s > 0.0 {
            st.period_s
        } else {
            zm.s.default_cycle_period_s
        };
        self.follow(zm, parts, adm, st, p_bar, period, q_cmd, dq_cmd)
    }
}
