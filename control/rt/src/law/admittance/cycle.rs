//! The admittance law's cycle: one joint state (and the cylinders' pressures) in, one
//! position/velocity command out, with no Python on it (issue 48; the control process's
//! compiled loop answers teaching's states with it, control/rt/src/py_cycle_loop.rs).
//!
//! Around (A1)/(A2) ([`Admittance`]), per cycle:
//!
//! - engagement (cycle/engagement.rs): as the zero-moment law's (the arm rests in the driver's
//!   hold, which calibrates ω̂), then the residual `b` at rest, the model's friction level at
//!   the pose (the stick zone, the probe's speeds, the dither), and the engagement probe
//!   ([`EngageProbe`]: every joint a few mrad out and back to measure the model's error);
//! - τ̂_h from the motor current of the cycle that just ended and the reference acceleration
//!   (and start-up dither) of the command that drove it, the stick zone or anchor
//!   ([`StickAnchor`]) on a joint at rest, the estimate kept over the cycles a drive's own hold
//!   or coast drove ([`DRIVE_SETTLE_CYCLES`]);
//! - (A2) with the soft walls (soft_walls.rs), the constrained guide's rows (law/guide.rs) and
//!   hand guiding's speed limit (the zero-moment law's, law/zero_moment/tool_speed.rs);
//! - the command `q_r + ω̂ (τ_model − b) / Υ̂_I`, within the offset limit of the arm, plus the
//!   start-up dither ([`StartupDither`]) on the command only.
//!
//! M̂: the identified model's at the reference, handed in by the control process off the cycle
//! ([`AdmittanceCycle::set_mass`], recomputed once the reference moved
//! [`Settings::inertia_step_rad`] from where it was computed; [`AdmittanceCycle::mass_wanted`]
//! says where), or the nominal rigid body's with rotor inertias until one is (and for a model
//! without one).
//!
//! The zero-moment law's cycle ([`ZeroMoment`] and its [`Parts`]) lends the pieces both laws
//! share: the hold and its calibration of ω̂, the motor torque, the model's friction level, the
//! speed limit, the guide, `engaged` and `last_cycle`.

#![allow(clippy::needless_range_loop)] // per-joint arithmetic reads as the formulas

use std::collections::VecDeque;

use super::numpy_semantics::{np_clip, np_max, np_sign};
use super::soft_walls::wall_torque;
use super::startup_dither::StartupDither;
use super::stick_anchor::StickAnchor;
use super::{Admittance, EngageProbe};
use crate::chain::MAX_JOINTS;
use crate::law::guide::GuideMode;
use crate::law::zero_moment::{Parts, State, ZeroMoment};
use crate::point_model::PointModel;

mod engagement;
mod inertia;

type Joints = [f64; MAX_JOINTS];
const SQUARE: usize = MAX_JOINTS * MAX_JOINTS;

/// The admittance measures its estimate's noise on at least this many held states.
pub const MIN_NOISE_STATES: usize = 16;
/// The engagement probe breaks a stuck joint away within this share of a quarter of it, at no
/// more than [`PROBE_MAX_RAD_S`] ([`AdmittanceCycle::probe_speeds`]).
pub const PROBE_BREAKAWAY_SHARE: f64 = 0.4;
/// See [`PROBE_BREAKAWAY_SHARE`] [rad/s].
pub const PROBE_MAX_RAD_S: f64 = 0.05;
/// After a cycle the drive held or coasted on its own (the law's command came late or not at
/// all), the currents of this many further states are the vendor loop's answer to that step
/// of the command, not a hand's: the estimate is kept as it was over them. The vendor loop
/// settles a one-cycle hold in about four cycles: in 49 isolated holds while a hand dragged
/// the arm on the LTC cell (one competing CPU load, 2026-12-03), J1-J3's largest current
/// deviation from the cycles before, p90 over the holds, was 20 A at the hold, then 12, 12, 6,
/// 6, 3.6 A, against about 1 A of scatter between the cycles before.
pub const DRIVE_SETTLE_CYCLES: usize = 4;
/// At most this many events are kept for the control process's log (the oldest go first).
const MAX_EVENTS: usize = 32;

/// What the admittance's cycle needs beyond the zero-moment law's settings.
#[derive(Clone, Debug)]
pub struct Settings {
    /// The command may lead the arm by at most this per joint [rad] (the controller faults at
    /// a larger following error).
    pub max_offset_rad: Vec<f64>,
    /// The stick zone: this share of the model's friction level at the engagement's pose.
    pub stick_zone: f64,
    /// `admittance_stick = "anchor"` (else the zone).
    pub anchor: bool,
    /// The engagement probe's least cruise speed [rad/s] (0: no probe) and length [s].
    pub probe_speed_rad_s: f64,
    pub probe_s: f64,
    /// The start-up dither: share of the friction level and frequency [Hz].
    pub dither: f64,
    pub dither_hz: f64,
    /// M̂ is handed in (an identified model) rather than the nominal chain's.
    pub identified_mass: bool,
    /// M̂ is computed again once the reference moved this far from where it was [rad].
    pub inertia_step_rad: f64,
}

/// Something the operator's log should say (`warning` or info).
#[derive(Clone, Debug, PartialEq)]
pub struct Event {
    pub warning: bool,
    pub text: String,
}

/// The engagement probe while it runs.
struct Probe {
    probe: EngageProbe,
    start: i64,
    q0: Joints,
    noise: Option<Joints>,
    period_s: f64,
}

/// The admittance law's state between cycles (module docs).
pub struct AdmittanceCycle {
    s: Settings,
    n: usize,
    probe: Option<Probe>,
    /// The residual b of (A1) [N·m].
    bias: Joints,
    /// The model's friction level at the engagement's pose [N·m].
    friction_level: Joints,
    /// The hand torque a joint at rest hides in its friction [N·m].
    stick: Joints,
    /// The desired torque of the last cycle [N·m].
    tau_d: Joints,
    /// States still to come whose currents a cycle the drive held or coasted drove.
    drive_own: usize,
    /// Reference accelerations sent, newest last (at most `delay + 1`).
    sent_ddq: VecDeque<Joints>,
    anchor: StickAnchor,
    dither: StartupDither,
    /// M̂ and the reference it was computed at (None: none yet).
    mass: [f64; SQUARE],
    mass_at: Option<Joints>,
    events: Vec<Event>,
}

fn sign_dead(x: f64, dead: f64) -> f64 {
    // np.sign(x) * np.maximum(np.abs(x) - dead, 0.0)
    np_sign(x) * np_max(x.abs() - dead, 0.0)
}

fn fmt_list(v: &[f64], digits: i32) -> String {
    let k = 10f64.powi(digits);
    let items: Vec<String> = v
        .iter()
        .map(|x| format!("{}", (x * k).round() / k))
        .collect();
    format!("[{}]", items.join(", "))
}

impl AdmittanceCycle {
    /// For `n` joints, the command delay `delay_cycles`, the rest speed `rest_rad_s` and the
    /// estimate's low-pass `filter_hz`. Err naming a bad setting.
    pub fn new(
        s: Settings,
        n: usize,
        delay_cycles: usize,
        rest_rad_s: f64,
        filter_hz: f64,
    ) -> Result<AdmittanceCycle, String> {
        if n == 0 || n > MAX_JOINTS {
            return Err(format!("admittance cycle: {n} joints"));
        }
        if s.max_offset_rad.len() != n {
            return Err(format!(
                "admittance cycle: max_offset_rad has {} values for {n} joints",
                s.max_offset_rad.len()
            ));
        }
        if !(s.stick_zone.is_finite() && s.stick_zone >= 0.0) {
            return Err(format!(
                "admittance cycle: stick zone {} not >= 0",
                s.stick_zone
            ));
        }
        if !(s.probe_speed_rad_s >= 0.0 && s.probe_s >= 0.0) {
            return Err("admittance cycle: probe speed and length must be >= 0".into());
        }
        if !(s.inertia_step_rad >= 0.0) {
            return Err("admittance cycle: inertia step must be >= 0".into());
        }
        let anchor = StickAnchor::new(n, filter_hz)?;
        let dither = StartupDither::new(s.dither, s.dither_hz, rest_rad_s, delay_cycles)?;
        Ok(AdmittanceCycle {
            s,
            n,
            probe: None,
            bias: [0.0; MAX_JOINTS],
            friction_level: [0.0; MAX_JOINTS],
            stick: [0.0; MAX_JOINTS],
            tau_d: [0.0; MAX_JOINTS],
            drive_own: 0,
            sent_ddq: VecDeque::with_capacity(delay_cycles + 2),
            anchor,
            dither,
            mass: [0.0; SQUARE],
            mass_at: None,
            events: Vec::with_capacity(MAX_EVENTS),
        })
    }

    pub fn n(&self) -> usize {
        self.n
    }
    pub fn bias(&self) -> &[f64] {
        &self.bias[..self.n]
    }
    pub fn tau_d(&self) -> &[f64] {
        &self.tau_d[..self.n]
    }
    pub fn friction_level(&self) -> &[f64] {
        &self.friction_level[..self.n]
    }
    pub fn probing(&self) -> bool {
        self.probe.is_some()
    }

    /// While the probe runs: its first cycle, its length [states] and its period [s].
    pub fn probe_span(&self) -> Option<(i64, usize, f64)> {
        self.probe
            .as_ref()
            .map(|p| (p.start, p.probe.len(), p.period_s))
    }

    /// The law lets go (the probe too); the zero-moment law's part is the caller's.
    pub fn disengage(&mut self) {
        self.probe = None;
    }

    /// The events since the last call, oldest first.
    pub fn take_events(&mut self) -> Vec<Event> {
        std::mem::take(&mut self.events)
    }

    fn event(&mut self, warning: bool, text: String) {
        if self.events.len() >= MAX_EVENTS {
            self.events.remove(0);
        }
        self.events.push(Event { warning, text });
    }

    /// The model's torque holding the arm at rest at `q` into `out`: no speed, no acceleration
    /// (M̂ plays no part): gravity, the cylinders at `p_bar`, the effects at rest.
    pub fn static_torque(
        zm: &ZeroMoment,
        model: &mut PointModel,
        q: &[f64],
        p_bar: &[f64],
        out: &mut [f64],
    ) -> Result<(), String> {
        let n = q.len();
        let zeros = [0.0; MAX_JOINTS];
        let no_mass = [0.0; SQUARE];
        Self::model_torque(
            zm,
            model,
            q,
            &zeros[..n],
            &zeros[..n],
            p_bar,
            &no_mass[..n * n],
            out,
        )
    }

    /// What the drives must give for the arm to move so, without a hand, into `out` [N·m]:
    /// M̂ q̈ + gravity − cylinders + the model's friction where it opposes the motion, at the
    /// speed beyond the friction deadband (as the zero-moment law: at rest the arm stands on
    /// its own friction, and a creep never earns a push). `mass` row-major n × n.
    #[allow(clippy::too_many_arguments)]
    pub fn model_torque(
        zm: &ZeroMoment,
        model: &mut PointModel,
        q: &[f64],
        dq: &[f64],
        ddq: &[f64],
        p_bar: &[f64],
        mass: &[f64],
        out: &mut [f64],
    ) -> Result<(), String> {
        let n = q.len();
        let dead = zm.s.friction_deadband_rad_s;
        let mut dq_f = [0.0; MAX_JOINTS];
        for j in 0..n {
            dq_f[j] = sign_dead(dq[j], dead);
        }
        let mut stat = [0.0; MAX_JOINTS];
        let mut fr = [0.0; MAX_JOINTS];
        model.cycle_torques(q, &dq_f[..n], p_bar, &mut stat[..n], &mut fr[..n])?;
        for i in 0..n {
            let f = if fr[i] * dq_f[i] > 0.0 {
                zm.s.friction_compensation * fr[i]
            } else {
                0.0
            };
            let mut inertial = 0.0;
            for k in 0..n {
                inertial += mass[i * n + k] * ddq[k];
            }
            out[i] = stat[i] + f + inertial;
        }
        Ok(())
    }

    /// `(q_cmd, dq_cmd)` answering `st` with the cylinders' pressures `p_bar` [bar] into the
    /// outputs. Err (naming the cycle) where the model or the estimate is undefined; the caller
    /// then lets go.
    #[allow(clippy::too_many_arguments)]
    pub fn answer(
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
        let period = if st.period_s > 0.0 {
            st.period_s
        } else {
            zm.s.default_cycle_period_s
        };
        if !zm.engaged {
            if zm.still_waiting(st, parts.hold)? {
                q_cmd[..n].copy_from_slice(&st.q_cmd[..n]);
                dq_cmd[..n].fill(0.0);
                return Ok(());
            }
            self.engage(zm, parts, adm, st, p_bar, period)?;
        }
        if self.probe.is_some() {
            return self.probe_cycle(zm, parts, adm, st, p_bar, q_cmd, dq_cmd);
        }
        self.follow(zm, parts, adm, st, p_bar, period, q_cmd, dq_cmd)
    }

    /// One cycle of the engaged admittance (module docs).
    #[allow(clippy::too_many_arguments)]
    fn follow(
        &mut self,
        zm: &mut ZeroMoment,
        parts: &mut Parts,
        adm: &mut Admittance,
        st: &State,
        p_bar: &[f64],
        period: f64,
        q_cmd: &mut [f64],
        dq_cmd: &mut [f64],
    ) -> Result<(), String> {
        let n = self.n;
        let delay = zm.s.command_delay_cycles;
        let rest = zm.s.rest_rad_s;
        let last = zm.last_cycle.unwrap_or(st.cycle - 1);
        let gap = st.cycle - last;
        let dt = period * gap.clamp(1, 50) as f64;
        if gap > 1 || st.flags & (zm.s.flag_prev_hold | zm.s.flag_prev_coast) != 0 {
            // the drive answered a cycle the law did not command in time: a hold steps the
            // command's speed to zero, which the vendor loop turns into tens of N·m
            self.drive_own = delay + 1 + DRIVE_SETTLE_CYCLES;
        }
        if zm.s.max_tool_speed_m_s > 0.0 {
            let (chain, work) = parts
                .chain
                .as_mut()
                .ok_or_else(|| "the speed limit needs the nominal chain".to_string())?;
            let target = zm.speed_target(chain, work, &st.q[..n], &st.dq[..n]);
            zm.set_speed_target(target);
        }
        zm.last_cycle = Some(st.cycle);
        let q = &st.q[..n];
        let mut drove = [0.0; MAX_JOINTS];
        match self.sent_ddq.front() {
            Some(d) if self.sent_ddq.len() == delay + 1 => drove = *d,
            _ => drove[..n].copy_from_slice(adm.ddq_r()),
        }
        // the drive gave the dither that drove this state too: not a hand
        let mut tau_m = [0.0; MAX_JOINTS];
        zm.motor_torque(st.current_a, &mut tau_m[..n]);
        let mut dithered = [0.0; MAX_JOINTS];
        self.dither.drove(&mut dithered[..n]);
        let mut mass = [0.0; SQUARE];
        let q_r0: Joints = {
            let mut a = [0.0; MAX_JOINTS];
            a[..n].copy_from_slice(adm.q_r());
            a
        };
        self.mass_at(zm, parts, &q_r0[..n], &mut mass)?;
        let mut tau_h = [0.0; MAX_JOINTS];
        // the friction the arm met is at its measured speed, not at the reference's
        Self::model_torque(
            zm,
            parts.model,
            q,
            &st.dq[..n],
            &drove[..n],
            p_bar,
            &mass[..n * n],
            &mut tau_h[..n],
        )?;
        let mut stuck = [0.0; MAX_JOINTS];
        let mut zoned = [0.0; MAX_JOINTS];
        for j in 0..n {
            tau_h[j] = tau_h[j] - self.bias[j] - (tau_m[j] - dithered[j]);
            // a joint at rest: its friction carries any torque up to its static level, which
            // the current cannot tell from a hand (the stick zone, fading out as it slides)
            stuck[j] = self.stick[j] * np_max(0.0, 1.0 - st.dq[j].abs() / (2.0 * rest));
            zoned[j] = sign_dead(tau_h[j], stuck[j]);
        }
        if self.s.anchor {
            // a joint settled at rest: the push is what moved its estimate off the one it
            // settled with (stick_anchor.rs); sliding or settling, the stick zone
            let mut resting = [false; MAX_JOINTS];
            for j in 0..n {
                resting[j] = st.dq[j].abs() <= rest;
            }
            let mut rel = [0.0; MAX_JOINTS];
            let mut settled = [false; MAX_JOINTS];
            self.anchor.hand(
                &tau_h[..n],
                &resting[..n],
                adm.band(),
                dt,
                &mut rel[..n],
                &mut settled[..n],
            );
            let moving = adm.moving();
            for j in 0..n {
                if !moving {
                    // an arm at rest keeps the stick zone about the anchor
                    rel[j] = sign_dead(rel[j], stuck[j]);
                }
                tau_h[j] = if settled[j] { rel[j] } else { zoned[j] };
            }
        } else {
            tau_h = zoned;
        }
        if self.drive_own > 0 {
            // currents the drive's own cycle drove: no hand is read from them, the estimate
            // stays where it was (an arm springing back from a hold read as a hand reversed
            // the reference, and a release's stop then ran the arm back: issue 47's item 4)
            self.drive_own -= 1;
            tau_h[..n].copy_from_slice(adm.tau_h());
        }
        // soft walls, damped for the inertia the reference renders (soft_walls.rs)
        let mut rendered = [0.0; MAX_JOINTS];
        for j in 0..n {
            rendered[j] = adm.alpha() * mass[j * n + j];
        }
        let mut walls = [0.0; MAX_JOINTS];
        wall_torque(
            q,
            adm.dq_r(),
            &zm.s.lower_rad,
            &zm.s.upper_rad,
            zm.s.wall_stiffness_nm_per_rad,
            &rendered[..n],
            dt,
            &mut walls[..n],
        )?;
        if !(tau_h[..n].iter().chain(&walls[..n]).all(|v| v.is_finite())) {
            return Err(format!(
                "cycle {}: hand torque estimate undefined",
                st.cycle
            ));
        }
        // constrained guiding holds the reference the arm follows on its fixture exactly
        // (law/guide.rs, Guide::constraint): rows on its speed, or none
        let mut rows = [0.0; 5 * MAX_JOINTS];
        let mut rates = [0.0; 5];
        let m = match parts.chain.as_mut() {
            Some((chain, work)) => {
                zm.guide
                    .constraint(chain, work, &q_r0[..n], &mut rows[..5 * n], &mut rates)
            }
            None if zm.guide.mode() != GuideMode::Free => {
                return Err("constrained guiding needs the nominal chain".into())
            }
            None => 0,
        };
        if m > 0 {
            adm.set_constraint(&rows[..m * n], &rates[..m])?;
        } else {
            adm.clear_constraint();
        }
        adm.propose(&tau_h[..n], &walls[..n], &mass[..n * n], dt)
            .map_err(|e| format!("cycle {}: {e}", st.cycle))?;
        let scale = match (zm.s.max_tool_speed_m_s > 0.0, parts.chain.as_mut()) {
            (true, Some((chain, work))) => {
                zm.tool_speed_scale(chain, work, adm.q_r(), adm.proposed())
            }
            _ => 1.0,
        };
        adm.commit(scale, dt);
        let mut q_r = [0.0; MAX_JOINTS];
        let mut dq_r = [0.0; MAX_JOINTS];
        let mut ddq_r = [0.0; MAX_JOINTS];
        q_r[..n].copy_from_slice(adm.q_r());
        dq_r[..n].copy_from_slice(adm.dq_r());
        ddq_r[..n].copy_from_slice(adm.ddq_r());
        if self.sent_ddq.len() == delay + 1 {
            self.sent_ddq.pop_front();
        }
        self.sent_ddq.push_back(ddq_r);
        self.mass_at(zm, parts, &q_r[..n], &mut mass)?;
        let mut tau = [0.0; MAX_JOINTS];
        Self::model_torque(
            zm,
            parts.model,
            &q_r[..n],
            &dq_r[..n],
            &ddq_r[..n],
            p_bar,
            &mass[..n * n],
            &mut tau[..n],
        )?;
        let mut dither = [0.0; MAX_JOINTS];
        self.dither.step(&dq_r[..n], dt, &mut dither[..n]);
        let (omega, upsilon) = (parts.outer.omega(), parts.outer.upsilon_i());
        let max_off = &self.s.max_offset_rad;
        let mut offset = [0.0; MAX_JOINTS];
        let mut unclipped = true;
        for j in 0..n {
            tau[j] -= self.bias[j];
            self.tau_d[j] = tau[j] + dither[j];
            offset[j] = np_clip(omega[j] * tau[j] / upsilon[j], -max_off[j], max_off[j]);
            let ahead = q_r[j] + offset[j];
            // the command may lead the arm by at most the offset limit (the controller faults
            // at a larger following error): a hand pushing a joint into a stop cannot wind it up
            q_cmd[j] = np_clip(ahead, q[j] - max_off[j], q[j] + max_off[j]);
            unclipped &= q_cmd[j] == ahead;
        }
        if !unclipped {
            let mut moved = [0.0; MAX_JOINTS];
            for j in 0..n {
                moved[j] = q_cmd[j] - offset[j];
            }
            adm.set_q_r(&moved[..n]);
        }
        if dither[..n].iter().any(|&d| d != 0.0) {
            // on the command only: the reference stays where (A2) put it
            for j in 0..n {
                let nudged = q_cmd[j] + omega[j] * dither[j] / upsilon[j];
                q_cmd[j] = np_clip(nudged, q[j] - max_off[j], q[j] + max_off[j]);
            }
        }
        dq_cmd[..n].copy_from_slice(&dq_r[..n]);
        Ok(())
    }
}
