//! Constrained guiding (issue 47, item 6): virtual fixtures on the tool, as painters ask of
//! hand guiding.
//!
//! - `free`: no fixture; the hand moves the tool anywhere and turns it anyhow.
//! - `orientation-locked`: the tool's orientation is held where it was when the mode took
//!   effect (the gun stays square to the panel) while the hand moves the tool point anywhere.
//! - `plane`: as `orientation-locked`, and the tool point stays in the plane through where it
//!   was, normal to the tool's approach axis (frame 6's z) then: the gun moves parallel to the
//!   panel it faces.
//! - `axis`: as `orientation-locked`, and the tool point stays on the line through where it
//!   was along one of the tool's axes then (`[control] guide_axis`: x, y or z of frame 6).
//!
//! Each fixture is a spring-damper in the task space on the deviation from the constraint,
//! mapped to joint torques through the tool's Jacobian of the nominal rigid body:
//!
//! ```text
//! F = −K_p P (p − p₀) − D_p P v,   M = −K_r log(R R₀ᵀ) − D_r ω,   τ_guide = J_vᵀ F + J_ωᵀ M
//! ```
//!
//! with `P` the projector on the constrained directions (the plane's normal, or the two
//! directions across the axis), `(p, R)` the tool point and orientation, `(v, ω)` their
//! velocities, all on world axes. The law adds `τ_guide` to the torque it asks the drives
//! for, so a joint the fixture does not constrain is free as before; a push along a
//! constrained direction meets a wall of stiffness `K_p` (`K_r`), which the damping keeps
//! from ringing through the vendor loop's delay. The moment is what holds the orientation
//! against the hand's force about the wrist (the tool point is off the wrist's axes), so
//! its stiffness sets how many degrees a push costs: `|r × F| / K_r`.
//!
//! That is the zero-moment law's fixture. The admittance, which integrates a reference of its
//! own, holds the same constraints exactly instead ([`Guide::constraint`]): as rows on the
//! reference's speed,
//!
//! ```text
//! ω = −k e,   nᵀ v = −k nᵀ (p − p₀) for each constrained direction n
//! ```
//!
//! (`e = log(R R₀ᵀ)`, `k` = [`CONSTRAINT_RATE_PER_S`]: a drift of the reference off the
//! fixture decays, nothing else moves it), which law/admittance/constraint.rs meets by
//! projection. A spring there let the gun turn with the hand's moment and the reference's
//! own dynamics: 2.3-2.5° on seeds 100-104 at 2,500 N·m/rad (2026-12-02).
//!
//! The reference is taken at the first cycle the mode applies to (engagement, or a change of
//! mode while engaged), from the state the cycle is computed at. The per-cycle methods
//! allocate nothing.

#![allow(clippy::needless_range_loop)] // per-joint arithmetic reads as the formulas

use crate::chain::{Chain, Work, MAX_JOINTS};
use crate::spatial::{dot, mat_mul_t, mat_vec, sub, Mat3, Placement, Vec3};

/// The admittance's reference drifts back onto its fixture at this rate [1/s]: a time
/// constant of 0.2 s, 25 cycles at 125 Hz, slow against the cycle and the vendor loop's
/// delay, fast against a painter's stroke. The drift it undoes is the reference's own (the
/// trapezoid step along a Jacobian taken at the step's start, the offset limit's clamp).
pub const CONSTRAINT_RATE_PER_S: f64 = 5.0;

/// The guide modes, by the names the operator and the config use.
pub const GUIDE_NAMES: [&str; 4] = ["free", "orientation-locked", "plane", "axis"];

/// What the fixture holds (module docs).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum GuideMode {
    Free,
    OrientationLocked,
    Plane,
    Axis,
}

impl GuideMode {
    pub fn parse(name: &str) -> Result<GuideMode, String> {
        match name {
            "free" => Ok(GuideMode::Free),
            "orientation-locked" => Ok(GuideMode::OrientationLocked),
            "plane" => Ok(GuideMode::Plane),
            "axis" => Ok(GuideMode::Axis),
            _ => Err(format!(
                "guide {name:?} is not one of {}",
                GUIDE_NAMES.join(", ")
            )),
        }
    }

    pub fn name(self) -> &'static str {
        match self {
            GuideMode::Free => GUIDE_NAMES[0],
            GuideMode::OrientationLocked => GUIDE_NAMES[1],
            GuideMode::Plane => GUIDE_NAMES[2],
            GuideMode::Axis => GUIDE_NAMES[3],
        }
    }
}

/// The fixture's springs and dampers, and the tool axis of `axis` mode.
#[derive(Clone, Copy, Debug)]
pub struct GuideSettings {
    /// On the tool point's deviation from the plane or the line [N/m], [N·s/m].
    pub stiffness_n_per_m: f64,
    pub damping_n_s_per_m: f64,
    /// On the tool's rotation from its reference [N·m/rad], [N·m·s/rad].
    pub rot_stiffness_nm_per_rad: f64,
    pub rot_damping_nm_s_per_rad: f64,
    /// `axis` mode's line: frame 6's x (0), y (1) or z (2) at the reference.
    pub axis: usize,
}

impl GuideSettings {
    pub fn check(&self) -> Result<(), String> {
        let named = [
            ("guide_stiffness_n_per_m", self.stiffness_n_per_m),
            ("guide_damping_n_s_per_m", self.damping_n_s_per_m),
            (
                "guide_rot_stiffness_nm_per_rad",
                self.rot_stiffness_nm_per_rad,
            ),
            (
                "guide_rot_damping_nm_s_per_rad",
                self.rot_damping_nm_s_per_rad,
            ),
        ];
        for (name, v) in named {
            if !(v.is_finite() && v >= 0.0) {
                return Err(format!("{name}: {v} is not a finite value >= 0"));
            }
        }
        if self.axis > 2 {
            return Err(format!(
                "guide_axis: {} is not 0, 1 or 2 (x, y, z)",
                self.axis
            ));
        }
        Ok(())
    }
}

/// The rotation vector of `r` (its axis × angle, angle in [0, π]): SO(3)'s logarithm.
pub fn rotation_vector(r: &Mat3) -> Vec3 {
    let trace = r[0][0] + r[1][1] + r[2][2];
    let c = ((trace - 1.0) / 2.0).clamp(-1.0, 1.0);
    let angle = c.acos();
    let w = [r[2][1] - r[1][2], r[0][2] - r[2][0], r[1][0] - r[0][1]];
    if angle < 1e-6 {
        // log R ≈ (R − Rᵀ)/2 near the identity
        return [w[0] / 2.0, w[1] / 2.0, w[2] / 2.0];
    }
    if std::f64::consts::PI - angle < 1e-6 {
        // near π the skew part vanishes: the axis from the symmetric part, R = 2 a aᵀ − I
        let d = [r[0][0], r[1][1], r[2][2]];
        let k = if d[0] >= d[1] && d[0] >= d[2] {
            0
        } else if d[1] >= d[2] {
            1
        } else {
            2
        };
        let mut a = [0.0; 3];
        a[k] = ((d[k] + 1.0) / 2.0).max(0.0).sqrt();
        for i in 0..3 {
            if i != k {
                a[i] = (r[i][k] + r[k][i]) / (4.0 * a[k]);
            }
        }
        return [a[0] * angle, a[1] * angle, a[2] * angle];
    }
    let s = angle / (2.0 * angle.sin());
    [w[0] * s, w[1] * s, w[2] * s]
}

/// The fixture's state: its mode, the mode waiting for its reference, the reference.
pub struct Guide {
    pub s: GuideSettings,
    mode: GuideMode,
    /// The reference is taken at the next cycle.
    pending: bool,
    p0: Vec3,
    r0: Mat3,
    /// The projector on the constrained directions of the tool point (world axes).
    projector: Mat3,
    /// The same directions as unit vectors (world axes): the first `n_dirs` of them.
    dirs: [Vec3; 2],
    n_dirs: usize,
    /// The last cycle's deviation: the tool point off its plane or line [m], its rotation
    /// from the reference [rad].
    deviation_m: f64,
    rotation_rad: f64,
}

impl Guide {
    pub fn new(s: GuideSettings, mode: GuideMode) -> Guide {
        Guide {
            s,
            mode,
            pending: true,
            p0: [0.0; 3],
            r0: [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]],
            projector: [[0.0; 3]; 3],
            dirs: [[0.0; 3]; 2],
            n_dirs: 0,
            deviation_m: 0.0,
            rotation_rad: 0.0,
        }
    }

    pub fn mode(&self) -> GuideMode {
        self.mode
    }

    /// Switch to `mode`; its reference is taken at the next cycle (a change to the same mode
    /// keeps the reference).
    pub fn set_mode(&mut self, mode: GuideMode) {
        if mode != self.mode {
            self.mode = mode;
            self.pending = true;
        }
    }

    /// Take the reference again at the next cycle (the law engages).
    pub fn restart(&mut self) {
        self.pending = true;
        self.deviation_m = 0.0;
        self.rotation_rad = 0.0;
    }

    /// The last cycle's distance of the tool point from its plane or line [m] (0 in `free`
    /// and `orientation-locked`).
    pub fn deviation_m(&self) -> f64 {
        self.deviation_m
    }

    /// The last cycle's rotation of the tool from its reference [rad] (0 in `free`).
    pub fn rotation_rad(&self) -> f64 {
        self.rotation_rad
    }

    fn take_reference(&mut self, p: Vec3, r: Mat3) {
        self.p0 = p;
        self.r0 = r;
        let column = |k: usize| [r[0][k], r[1][k], r[2][k]];
        self.n_dirs = match self.mode {
            GuideMode::Plane => {
                self.dirs[0] = column(2);
                1
            }
            GuideMode::Axis => {
                // across the axis: the reference's other two axes
                self.dirs = [column((self.s.axis + 1) % 3), column((self.s.axis + 2) % 3)];
                2
            }
            GuideMode::Free | GuideMode::OrientationLocked => 0,
        };
        // the projector on those directions (orthonormal): Σ d dᵀ, across an axis a: I − a aᵀ
        let mut proj = [[0.0; 3]; 3];
        for d in &self.dirs[..self.n_dirs] {
            for i in 0..3 {
                for j in 0..3 {
                    proj[i][j] += d[i] * d[j];
                }
            }
        }
        self.projector = proj;
        self.pending = false;
    }

    /// What both forms of the fixture start from at `q`: None in `free` (its deviations 0);
    /// else the tool's pose with its Jacobian into `jac` (6 × n), the reference taken there
    /// if pending, and the rotation vector from the reference (`rotation_rad` its length).
    fn track(
        &mut self,
        chain: &Chain,
        work: &mut Work,
        q: &[f64],
        jac: &mut [f64],
    ) -> Option<(Placement, Vec3)> {
        if self.mode == GuideMode::Free {
            self.deviation_m = 0.0;
            self.rotation_rad = 0.0;
            return None;
        }
        let pose = chain.tool_jacobian(q, work, jac);
        if self.pending {
            self.take_reference(pose.p, pose.r);
        }
        let e = rotation_vector(&mat_mul_t(&pose.r, &self.r0));
        self.rotation_rad = dot(&e, &e).sqrt();
        Some((pose, e))
    }

    /// The fixture's joint torque at (q, dq) into `out` (zeros in `free`), on the nominal
    /// chain's tool frame; the first cycle after [`Guide::set_mode`] or [`Guide::restart`]
    /// takes the reference there.
    pub fn torque(
        &mut self,
        chain: &Chain,
        work: &mut Work,
        q: &[f64],
        dq: &[f64],
        out: &mut [f64],
    ) {
        let n = q.len();
        out[..n].fill(0.0);
        let mut jac = [0.0; 6 * MAX_JOINTS];
        let Some((pose, e)) = self.track(chain, work, q, &mut jac[..6 * n]) else {
            return;
        };
        let mut twist = [0.0; 6];
        for (i, t) in twist.iter_mut().enumerate() {
            for k in 0..n {
                *t += jac[i * n + k] * dq[k];
            }
        }
        let mut wrench = [0.0; 6];
        for i in 0..3 {
            wrench[3 + i] = -self.s.rot_stiffness_nm_per_rad * e[i]
                - self.s.rot_damping_nm_s_per_rad * twist[3 + i];
        }
        if matches!(self.mode, GuideMode::Plane | GuideMode::Axis) {
            let off = mat_vec(&self.projector, &sub(&pose.p, &self.p0));
            let v = mat_vec(&self.projector, &[twist[0], twist[1], twist[2]]);
            self.deviation_m = dot(&off, &off).sqrt();
            for i in 0..3 {
                wrench[i] = -self.s.stiffness_n_per_m * off[i] - self.s.damping_n_s_per_m * v[i];
            }
        } else {
            self.deviation_m = 0.0;
        }
        for k in 0..n {
            let mut t = 0.0;
            for i in 0..6 {
                t += jac[i * n + k] * wrench[i];
            }
            out[k] = t;
        }
    }

    /// The admittance's form of the fixture at the reference `q` (module docs): its rows on
    /// the reference's speed into `rows` (row-major, n per row) and their rates into `rates`;
    /// the number of rows (0 in `free`: 3 for the orientation, and 1 for a plane's normal or
    /// 2 across an axis). `rows` needs 5 n values, `rates` 5. The first call after
    /// [`Guide::set_mode`] or [`Guide::restart`] takes the reference there.
    pub fn constraint(
        &mut self,
        chain: &Chain,
        work: &mut Work,
        q: &[f64],
        rows: &mut [f64],
        rates: &mut [f64],
    ) -> usize {
        let n = q.len();
        let mut jac = [0.0; 6 * MAX_JOINTS];
        let Some((pose, e)) = self.track(chain, work, q, &mut jac[..6 * n]) else {
            return 0;
        };
        for i in 0..3 {
            rows[i * n..(i + 1) * n].copy_from_slice(&jac[(3 + i) * n..(4 + i) * n]);
            rates[i] = -CONSTRAINT_RATE_PER_S * e[i];
        }
        let off = sub(&pose.p, &self.p0);
        let mut deviation2 = 0.0;
        for d in 0..self.n_dirs {
            let dir = self.dirs[d];
            let row = &mut rows[(3 + d) * n..(4 + d) * n];
            for k in 0..n {
                row[k] = (0..3).map(|i| dir[i] * jac[i * n + k]).sum();
            }
            let along = dot(&dir, &off);
            deviation2 += along * along;
            rates[3 + d] = -CONSTRAINT_RATE_PER_S * along;
        }
        self.deviation_m = deviation2.sqrt();
        3 + self.n_dirs
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::spatial::axis_rotation;
    use serde_json::json;

    fn settings() -> GuideSettings {
        GuideSettings {
            stiffness_n_per_m: 3000.0,
            damping_n_s_per_m: 300.0,
            rot_stiffness_nm_per_rad: 1000.0,
            rot_damping_nm_s_per_rad: 40.0,
            axis: 0,
        }
    }

    /// A three-joint arm: a vertical axis, then two horizontal ones (shoulder, wrist), so the
    /// tool can turn about two axes and move in the plane.
    fn arm() -> Chain {
        let id = json!([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]);
        let point = |m: f64| json!([m, 0.0, 0.0, 0.0, 0.1, 0.0, 0.0, 0.1, 0.0, 0.1]);
        Chain::from_json(&json!({
            "format": crate::chain::CHAIN_FORMAT, "version": crate::chain::CHAIN_VERSION,
            "gravity_m_s2": [0.0, 0.0, -9.81],
            "joints": [
                {"parent": null, "placement": {"rotation": id, "translation": [0.0, 0.0, 0.5]},
                 "kind": "revolute", "axis": [0.0, 0.0, 1.0], "inertia": point(5.0), "armature": 0.0},
                {"parent": 0, "placement": {"rotation": id, "translation": [0.0, 0.0, 0.0]},
                 "kind": "revolute", "axis": [0.0, 1.0, 0.0], "inertia": point(3.0), "armature": 0.0},
                {"parent": 1, "placement": {"rotation": id, "translation": [1.0, 0.0, 0.0]},
                 "kind": "revolute", "axis": [0.0, 1.0, 0.0], "inertia": point(1.0), "armature": 0.0},
            ],
            "tool": {"joint": 2, "placement": {"rotation": id, "translation": [0.0, 0.0, -0.3]}},
        }))
        .unwrap()
    }

    #[test]
    fn the_rotation_vector_inverts_the_axis_rotation_up_to_pi() {
        let axis = [0.6, 0.0, 0.8];
        for angle in [0.0, 1e-8, 0.01, 1.0, 3.0, std::f64::consts::PI - 1e-9] {
            let e = rotation_vector(&axis_rotation(&axis, angle));
            for i in 0..3 {
                assert!((e[i] - axis[i] * angle).abs() < 1e-6, "{angle}: {e:?}");
            }
        }
    }

    #[test]
    fn the_admittance_rows_are_the_tool_jacobian_and_pull_a_drift_back() {
        let chain = arm();
        let mut w = Work::default();
        let (mut rows, mut rates) = ([0.0; 15], [0.0; 5]);
        let mut free = Guide::new(settings(), GuideMode::Free);
        assert_eq!(
            free.constraint(&chain, &mut w, &[0.1, 0.2, 0.3], &mut rows, &mut rates),
            0
        );
        let mut plane = Guide::new(settings(), GuideMode::Plane);
        let q0 = [0.0, 0.0, 0.0];
        assert_eq!(
            plane.constraint(&chain, &mut w, &q0, &mut rows, &mut rates),
            4
        );
        let mut jac = [0.0; 18];
        chain.tool_jacobian(&q0, &mut w, &mut jac);
        // the angular rows, then the plane's normal (the tool's z, the world's z here) on J_v
        for k in 0..3 {
            for i in 0..3 {
                assert!((rows[i * 3 + k] - jac[(3 + i) * 3 + k]).abs() < 1e-12);
            }
            assert!((rows[9 + k] - jac[2 * 3 + k]).abs() < 1e-12);
        }
        assert!(rates[..4].iter().all(|r| r.abs() < 1e-12), "{rates:?}");
        // pitched by 0.05 and lifted: the rates pull both back at CONSTRAINT_RATE_PER_S
        plane.constraint(&chain, &mut w, &[0.0, -0.01, 0.06], &mut rows, &mut rates);
        let pitch = plane.rotation_rad();
        assert!((pitch - 0.05).abs() < 1e-9);
        let k = CONSTRAINT_RATE_PER_S;
        assert!(rates[0].abs() < 1e-12 && rates[2].abs() < 1e-12);
        assert!((rates[1].abs() - k * pitch).abs() < 1e-9, "{rates:?}");
        assert!((rates[3].abs() - k * plane.deviation_m()).abs() < 1e-12);
        assert!(plane.deviation_m() > 1e-3);
    }

    #[test]
    fn free_gives_nothing_and_a_lock_nothing_at_its_reference() {
        let chain = arm();
        let mut w = Work::default();
        let mut out = [1.0; 3];
        let mut free = Guide::new(settings(), GuideMode::Free);
        free.torque(&chain, &mut w, &[0.1, 0.2, 0.3], &[0.5, 0.5, 0.5], &mut out);
        assert_eq!(out, [0.0; 3]);
        let mut lock = Guide::new(settings(), GuideMode::OrientationLocked);
        lock.torque(&chain, &mut w, &[0.1, 0.2, 0.3], &[0.0; 3], &mut out);
        assert!(out.iter().all(|t| t.abs() < 1e-12), "{out:?}");
    }

    #[test]
    fn a_locked_orientation_pushes_back_against_a_turn_and_lets_a_rotation_free_motion_be() {
        let chain = arm();
        let mut w = Work::default();
        let mut out = [0.0; 3];
        let mut lock = Guide::new(settings(), GuideMode::OrientationLocked);
        lock.torque(&chain, &mut w, &[0.0, 0.2, 0.3], &[0.0; 3], &mut out);
        // the wrist turned by 0.05 rad: the pitch (joints 2 + 3) is 0.05 off; the spring's
        // moment −K e about the pitch axis goes to both pitch joints, none to the vertical one
        lock.torque(&chain, &mut w, &[0.0, 0.2, 0.35], &[0.0; 3], &mut out);
        assert!((lock.rotation_rad() - 0.05).abs() < 1e-9);
        assert!(
            out[0].abs() < 1e-9 && (out[2] + 1000.0 * 0.05).abs() < 1e-6,
            "{out:?}"
        );
        assert!((out[1] - out[2]).abs() < 1e-6, "{out:?}");
        // the shoulder up and the wrist down by as much: the tool moves, its pitch does not
        lock.torque(
            &chain,
            &mut w,
            &[0.0, 0.3, 0.2],
            &[0.0, 0.5, -0.5],
            &mut out,
        );
        assert!(out.iter().all(|t| t.abs() < 1e-9), "{out:?}");
    }

    #[test]
    fn a_plane_holds_the_normal_and_lets_the_tool_slide_in_it() {
        let chain = arm();
        let mut w = Work::default();
        let mut out = [0.0; 3];
        let mut plane = Guide::new(settings(), GuideMode::Plane);
        let q0 = [0.0, 0.0, 0.0];
        plane.torque(&chain, &mut w, &q0, &[0.0; 3], &mut out);
        // the tool's z is the world's z here: the plane is horizontal through the tool point;
        // the vertical joint turns the tool about z, in the plane, and turns the orientation
        plane.torque(&chain, &mut w, &[0.1, 0.0, 0.0], &[0.0; 3], &mut out);
        assert!(plane.deviation_m() < 1e-12);
        assert!((out[0] + 1000.0 * 0.1).abs() < 1e-6, "{out:?}");
        // the shoulder lifts the tool out of the plane: the force −K dz pulls it back down
        plane.torque(&chain, &mut w, &[0.0, -0.01, 0.01], &[0.0; 3], &mut out);
        let lifted = (1.0 * (0.01f64).sin()).abs();
        assert!(
            (plane.deviation_m() - lifted).abs() < 1e-6,
            "{}",
            plane.deviation_m()
        );
        // joint 2 turns about y: the tool ~1 m in front of it, lifted by a negative turn,
        // is pulled down by a positive moment
        let back = 3000.0 * lifted * (0.01f64).cos();
        assert!(
            (out[1] - back).abs() / back.abs() < 0.05,
            "{out:?} vs {back}"
        );
    }

    #[test]
    fn an_axis_holds_the_two_directions_across_it() {
        let chain = arm();
        let mut w = Work::default();
        let mut out = [0.0; 3];
        let mut axis = Guide::new(settings(), GuideMode::Axis); // along the tool's x
        axis.torque(&chain, &mut w, &[0.0, 0.0, 0.0], &[0.0; 3], &mut out);
        // the vertical joint moves the tool sideways (across x): held back
        axis.torque(&chain, &mut w, &[0.01, 0.0, 0.0], &[0.0; 3], &mut out);
        assert!((axis.deviation_m() - 1.0 * 0.01f64.sin()).abs() < 1e-4);
        assert!(out[0] < -3000.0 * 0.0099 * 0.99, "{out:?}");
    }

    #[test]
    fn a_new_mode_takes_its_reference_where_the_arm_is_then() {
        let chain = arm();
        let mut w = Work::default();
        let mut out = [0.0; 3];
        let mut g = Guide::new(settings(), GuideMode::Free);
        g.torque(&chain, &mut w, &[0.3, 0.1, 0.2], &[0.0; 3], &mut out);
        g.set_mode(GuideMode::OrientationLocked);
        g.torque(&chain, &mut w, &[0.5, 0.1, 0.2], &[0.0; 3], &mut out);
        assert!(out.iter().all(|t| t.abs() < 1e-12), "{out:?}");
        g.set_mode(GuideMode::OrientationLocked); // the same mode: the reference stays
        g.torque(&chain, &mut w, &[0.6, 0.1, 0.2], &[0.0; 3], &mut out);
        assert!((out[0] + 100.0).abs() < 1e-6, "{out:?}");
        g.restart();
        g.torque(&chain, &mut w, &[0.6, 0.1, 0.2], &[0.0; 3], &mut out);
        assert!(out.iter().all(|t| t.abs() < 1e-12), "{out:?}");
    }

    #[test]
    fn bad_settings_and_names_are_refused_by_name() {
        let mut s = settings();
        s.rot_stiffness_nm_per_rad = f64::NAN;
        assert!(s
            .check()
            .unwrap_err()
            .contains("guide_rot_stiffness_nm_per_rad"));
        s = settings();
        s.axis = 3;
        assert!(s.check().unwrap_err().contains("guide_axis"));
        assert!(GuideMode::parse("sideways")
            .unwrap_err()
            .contains("orientation-locked"));
        for name in GUIDE_NAMES {
            assert_eq!(GuideMode::parse(name).unwrap().name(), name);
        }
    }
}
