//! The robot's rigid-body chain, compiled: forward kinematics, inverse dynamics (RNEA), its
//! regressor, the mass matrix and the tool's Jacobian, the same numbers pinocchio gives on the
//! model `control.model.dynamics.RigidBodyModel` builds (tests/unit/test_control_rt_chain.py
//! checks them on random states).
//!
//! The chain comes as a table (control/rt_tables.py `chain_table`, read once at start): per
//! joint its parent, its placement in the parent at q = 0, its kind (revolute or prismatic)
//! and axis, the
//! ten dynamic parameters of its body (pinocchio's order) and its rotor's armature; the
//! gravity; the tool frame on its joint. Per cycle nothing is allocated: the work arrays are
//! fixed-size, for up to [`MAX_JOINTS`] joints.

use serde_json::Value;

use crate::spatial::{
    axis_rotation, body_wrench, cross, dot, mat_vec, motion_cross, scale, sub, Placement, Six, Vec3,
};
use crate::table;

pub const MAX_JOINTS: usize = 16;
pub const CHAIN_FORMAT: &str = "leadthrough-rigid-chain";
pub const CHAIN_VERSION: i64 = 1;

#[derive(Clone, Debug)]
pub struct Joint {
    /// Index of the parent joint; None: the world.
    pub parent: Option<usize>,
    pub placement: Placement,
    /// Unit axis in the joint's frame.
    pub axis: Vec3,
    /// Slides along its axis (a linear track); otherwise turns about it.
    pub prismatic: bool,
    /// m, m c, I about the origin (xx, xy, yy, xz, yz, zz) [kg, kg·m, kg·m²].
    pub inertia: [f64; 10],
    /// The rotor's inertia reflected to the joint [kg·m²].
    pub armature: f64,
}

impl Joint {
    /// The joint's motion subspace S: (0, axis) turning, (axis, 0) sliding.
    fn subspace(&self) -> Six {
        let a = self.axis;
        if self.prismatic {
            [a[0], a[1], a[2], 0.0, 0.0, 0.0]
        } else {
            [0.0, 0.0, 0.0, a[0], a[1], a[2]]
        }
    }

    /// Sᵀ f: the part of a wrench in the joint's frame its motor takes.
    fn project(&self, f: &Six) -> f64 {
        let s = self.subspace();
        (0..6).map(|k| s[k] * f[k]).sum()
    }
}

#[derive(Clone, Debug)]
pub struct Chain {
    pub joints: Vec<Joint>,
    pub gravity: Vec3,
    /// The tool frame: its joint and its placement in that joint's frame.
    pub tool_joint: usize,
    pub tool: Placement,
}

/// The per-cycle work arrays of a [`Chain`].
pub struct Work {
    /// Each joint's frame in its parent's at q.
    pub x: [Placement; MAX_JOINTS],
    pub v: [Six; MAX_JOINTS],
    pub a: [Six; MAX_JOINTS],
    f: [Six; MAX_JOINTS],
    cols: [[Six; 10]; MAX_JOINTS],
}

impl Default for Work {
    fn default() -> Self {
        Work {
            x: [Placement::IDENTITY; MAX_JOINTS],
            v: [[0.0; 6]; MAX_JOINTS],
            a: [[0.0; 6]; MAX_JOINTS],
            f: [[0.0; 6]; MAX_JOINTS],
            cols: [[[0.0; 6]; 10]; MAX_JOINTS],
        }
    }
}

/// [`table::numbers`] with the chain's prefix on its error.
fn numbers<const N: usize>(value: Option<&Value>, what: &str) -> Result<[f64; N], String> {
    table::numbers(value, what).map_err(|e| format!("rigid chain: {e}"))
}

fn placement(value: Option<&Value>, what: &str) -> Result<Placement, String> {
    let v = value.ok_or_else(|| format!("rigid chain: {what} is missing"))?;
    let rows = v
        .get("rotation")
        .and_then(Value::as_array)
        .filter(|r| r.len() == 3)
        .ok_or_else(|| format!("rigid chain: {what}.rotation must be 3 rows"))?;
    let mut r = [[0.0; 3]; 3];
    for (k, row) in rows.iter().enumerate() {
        r[k] = numbers::<3>(Some(row), &format!("{what}.rotation[{k}]"))?;
    }
    // a rotation: orthonormal rows, determinant +1
    for i in 0..3 {
        for j in 0..3 {
            let want = if i == j { 1.0 } else { 0.0 };
            if (dot(&r[i], &r[j]) - want).abs() > 1e-6 {
                return Err(format!("rigid chain: {what}.rotation is not a rotation"));
            }
        }
    }
    if dot(&cross(&r[0], &r[1]), &r[2]) < 0.0 {
        return Err(format!("rigid chain: {what}.rotation is a reflection"));
    }
    let p = numbers::<3>(v.get("translation"), &format!("{what}.translation"))?;
    Ok(Placement { r, p })
}

impl Chain {
    /// The chain of a table (module docstring); an error names what is wrong.
    pub fn from_json(table: &Value) -> Result<Chain, String> {
        if table.get("format").and_then(Value::as_str) != Some(CHAIN_FORMAT)
            || table.get("version").and_then(Value::as_i64) != Some(CHAIN_VERSION)
        {
            return Err(format!(
                "rigid chain: not a {CHAIN_FORMAT} v{CHAIN_VERSION} table"
            ));
        }
        let items = table
            .get("joints")
            .and_then(Value::as_array)
            .filter(|j| !j.is_empty() && j.len() <= MAX_JOINTS)
            .ok_or_else(|| format!("rigid chain: joints must be 1 to {MAX_JOINTS} tables"))?;
        let mut joints = Vec::with_capacity(items.len());
        for (i, item) in items.iter().enumerate() {
            let what = format!("joints[{i}]");
            let parent = match item.get("parent") {
                Some(Value::Null) => None,
                Some(p) => match p.as_u64() {
                    Some(k) if (k as usize) < i => Some(k as usize),
                    _ => {
                        return Err(format!(
                            "rigid chain: {what}.parent must be an earlier joint or null"
                        ))
                    }
                },
                None => return Err(format!("rigid chain: {what}.parent is missing")),
            };
            let axis = numbers::<3>(item.get("axis"), &format!("{what}.axis"))?;
            if (dot(&axis, &axis) - 1.0).abs() > 1e-9 {
                return Err(format!("rigid chain: {what}.axis is not a unit vector"));
            }
            let prismatic = match item.get("kind").and_then(Value::as_str) {
                Some("revolute") => false,
                Some("prismatic") => true,
                _ => {
                    return Err(format!(
                        "rigid chain: {what}.kind must be revolute or prismatic"
                    ))
                }
            };
            let inertia = numbers::<10>(item.get("inertia"), &format!("{what}.inertia"))?;
            let armature = numbers::<1>(
                item.get("armature")
                    .map(|a| Value::Array(vec![a.clone()]))
                    .as_ref(),
                &format!("{what}.armature"),
            )?[0];
            joints.push(Joint {
                parent,
                placement: placement(item.get("placement"), &format!("{what}.placement"))?,
                axis,
                prismatic,
                inertia,
                armature,
            });
        }
        let tool = table.get("tool").ok_or("rigid chain: tool is missing")?;
        let tool_joint = tool
            .get("joint")
            .and_then(Value::as_u64)
            .map(|k| k as usize)
            .filter(|&k| k < joints.len())
            .ok_or("rigid chain: tool.joint must be a joint's index")?;
        Ok(Chain {
            gravity: numbers::<3>(table.get("gravity_m_s2"), "gravity_m_s2")?,
            tool: placement(tool.get("placement"), "tool.placement")?,
            tool_joint,
            joints,
        })
    }

    pub fn n(&self) -> usize {
        self.joints.len()
    }

    /// Each joint's frame in its parent's at `q`, into `w.x`.
    pub fn placements(&self, q: &[f64], w: &mut Work) {
        for (i, j) in self.joints.iter().enumerate() {
            let motion = if j.prismatic {
                Placement {
                    r: Placement::IDENTITY.r,
                    p: scale(&j.axis, q[i]),
                }
            } else {
                Placement {
                    r: axis_rotation(&j.axis, q[i]),
                    p: [0.0; 3],
                }
            };
            w.x[i] = j.placement.compose(&motion);
        }
    }

    /// The first pass of RNEA: placements, body velocities and accelerations (the base
    /// accelerating at −gravity when `gravity`), into `w`.
    fn forward(&self, q: &[f64], dq: &[f64], ddq: &[f64], gravity: bool, w: &mut Work) {
        self.placements(q, w);
        let g = if gravity { self.gravity } else { [0.0; 3] };
        let base_a = [-g[0], -g[1], -g[2], 0.0, 0.0, 0.0];
        for (i, j) in self.joints.iter().enumerate() {
            let (vp, ap) = match j.parent {
                None => ([0.0; 6], base_a),
                Some(p) => (w.v[p], w.a[p]),
            };
            let s = j.subspace();
            let mut v = w.x[i].act_inv_motion(&vp);
            let mut a = w.x[i].act_inv_motion(&ap);
            for k in 0..6 {
                v[k] += s[k] * dq[i];
                a[k] += s[k] * ddq[i];
            }
            let sd = s.map(|x| x * dq[i]);
            let c = motion_cross(&v, &sd);
            for k in 0..6 {
                a[k] += c[k];
            }
            w.v[i] = v;
            w.a[i] = a;
        }
    }

    /// Joint torques [N·m] of inverse dynamics at (q, dq, ddq), gravity included when
    /// `gravity`, the rotors' armature when `armature`, into `tau`.
    pub fn rnea(
        &self,
        q: &[f64],
        dq: &[f64],
        ddq: &[f64],
        gravity: bool,
        armature: bool,
        w: &mut Work,
        tau: &mut [f64],
    ) {
        self.forward(q, dq, ddq, gravity, w);
        let n = self.n();
        for i in 0..n {
            w.f[i] = body_wrench(&self.joints[i].inertia, &w.v[i], &w.a[i]);
        }
        for i in (0..n).rev() {
            let j = &self.joints[i];
            let f = w.f[i];
            tau[i] = j.project(&f);
            if armature {
                tau[i] += j.armature * ddq[i];
            }
            if let Some(p) = j.parent {
                let fp = w.x[i].act_force(&f);
                for k in 0..6 {
                    w.f[p][k] += fp[k];
                }
            }
        }
    }

    /// The joint-torque regressor at (q, dq, ddq) with gravity, n × 10 n row-major into `y`:
    /// `y · π = rnea(q, dq, ddq)` for the bodies' parameters π stacked (pinocchio's
    /// `computeJointTorqueRegressor`; armature not included).
    pub fn regressor(&self, q: &[f64], dq: &[f64], ddq: &[f64], w: &mut Work, y: &mut [f64]) {
        self.forward(q, dq, ddq, true, w);
        let n = self.n();
        let width = 10 * n;
        y[..n * width].fill(0.0);
        let mut unit = [0.0; 10];
        for k in 0..n {
            for c in 0..10 {
                unit[c] = 1.0;
                w.cols[k][c] = body_wrench(&unit, &w.v[k], &w.a[k]);
                unit[c] = 0.0;
            }
            // body k's wrench columns, carried to each ancestor joint in turn
            let mut at = k;
            let mut cols = w.cols[k];
            loop {
                let j = &self.joints[at];
                for (c, f) in cols.iter().enumerate() {
                    y[at * width + 10 * k + c] = j.project(f);
                }
                let Some(p) = j.parent else { break };
                for f in cols.iter_mut() {
                    *f = w.x[at].act_force(f);
                }
                at = p;
            }
        }
    }

    /// M(q) (n × n row-major into `m`), with the rotors' armature on the diagonal when
    /// `armature`: column k is the torque of a unit acceleration of joint k at rest without
    /// gravity.
    pub fn mass_matrix(&self, q: &[f64], armature: bool, w: &mut Work, m: &mut [f64]) {
        let n = self.n();
        let zeros = [0.0; MAX_JOINTS];
        let mut unit = [0.0; MAX_JOINTS];
        let mut col = [0.0; MAX_JOINTS];
        for k in 0..n {
            unit[k] = 1.0;
            self.rnea(
                q,
                &zeros[..n],
                &unit[..n],
                false,
                armature,
                w,
                &mut col[..n],
            );
            unit[k] = 0.0;
            for i in 0..n {
                m[i * n + k] = col[i];
            }
        }
        // exactly symmetric (RNEA's columns agree to rounding)
        for i in 0..n {
            for k in 0..i {
                let s = 0.5 * (m[i * n + k] + m[k * n + i]);
                m[i * n + k] = s;
                m[k * n + i] = s;
            }
        }
    }

    /// Each joint's frame in the world at `q`, into `world` (uses `w.x`).
    pub fn world_placements(&self, q: &[f64], w: &mut Work, world: &mut [Placement]) {
        self.placements(q, w);
        for (i, j) in self.joints.iter().enumerate() {
            world[i] = match j.parent {
                None => w.x[i],
                Some(p) => world[p].compose(&w.x[i]),
            };
        }
    }

    /// The tool frame in the world at `q`.
    pub fn tool_pose(&self, q: &[f64], w: &mut Work) -> Placement {
        let mut world = [Placement::IDENTITY; MAX_JOINTS];
        self.world_placements(q, w, &mut world[..self.n()]);
        world[self.tool_joint].compose(&self.tool)
    }

    /// The tool's Jacobian at `q`, 6 × n row-major into `jac`: rows the tool origin's linear
    /// velocity then the angular velocity, both on world axes (pinocchio's
    /// LOCAL_WORLD_ALIGNED).
    pub fn tool_jacobian(&self, q: &[f64], w: &mut Work, jac: &mut [f64]) -> Placement {
        let n = self.n();
        let mut world = [Placement::IDENTITY; MAX_JOINTS];
        self.world_placements(q, w, &mut world[..n]);
        let tool = world[self.tool_joint].compose(&self.tool);
        jac[..6 * n].fill(0.0);
        let mut at = Some(self.tool_joint);
        while let Some(i) = at {
            let z = mat_vec(&world[i].r, &self.joints[i].axis);
            let (v, w_col) = if self.joints[i].prismatic {
                (z, [0.0; 3])
            } else {
                (cross(&z, &sub(&tool.p, &world[i].p)), z)
            };
            for k in 0..3 {
                jac[k * n + i] = v[k];
                jac[(3 + k) * n + i] = w_col[k];
            }
            at = self.joints[i].parent;
        }
        tool
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use serde_json::json;

    /// A two-link planar arm turning about the world's −y, so that a positive angle raises it
    /// (gravity along −z): links of length 1 and 0.8 with point masses 3 and 2 kg at their
    /// ends.
    fn two_link() -> Chain {
        let id = json!([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]);
        let point =
            |m: f64, x: f64| json!([m, m * x, 0.0, 0.0, 0.0, 0.0, m * x * x, 0.0, 0.0, m * x * x]);
        Chain::from_json(&json!({
            "format": CHAIN_FORMAT, "version": CHAIN_VERSION, "gravity_m_s2": [0.0, 0.0, -9.81],
            "joints": [
                {"parent": null, "placement": {"rotation": id, "translation": [0.0, 0.0, 0.0]},
                 "kind": "revolute", "axis": [0.0, -1.0, 0.0], "inertia": point(3.0, 1.0), "armature": 0.5},
                {"parent": 0, "placement": {"rotation": id, "translation": [1.0, 0.0, 0.0]},
                 "kind": "revolute", "axis": [0.0, -1.0, 0.0], "inertia": point(2.0, 0.8), "armature": 0.0},
            ],
            "tool": {"joint": 1, "placement": {"rotation": id, "translation": [0.8, 0.0, 0.0]}},
        }))
        .unwrap()
    }

    #[test]
    fn a_planar_two_link_arm_matches_its_textbook_dynamics() {
        let chain = two_link();
        let mut w = Work::default();
        let (q, dq, ddq) = ([0.3, -0.5], [0.7, -1.1], [0.4, 2.0]);
        let mut tau = [0.0; 2];
        chain.rnea(&q, &dq, &ddq, true, false, &mut w, &mut tau);
        let (m1, m2, l1, l2, g) = (3.0, 2.0, 1.0, 0.8, 9.81);
        let c2 = (q[1] as f64).cos();
        let s2 = (q[1] as f64).sin();
        let m11 = m1 * l1 * l1 + m2 * (l1 * l1 + l2 * l2 + 2.0 * l1 * l2 * c2);
        let m12 = m2 * (l2 * l2 + l1 * l2 * c2);
        let m22 = m2 * l2 * l2;
        let h = m2 * l1 * l2 * s2;
        let g1 = (m1 * l1 + m2 * l1) * g * q[0].cos() + m2 * l2 * g * (q[0] + q[1]).cos();
        let g2 = m2 * l2 * g * (q[0] + q[1]).cos();
        let t1 = m11 * ddq[0] + m12 * ddq[1] - h * (2.0 * dq[0] * dq[1] + dq[1] * dq[1]) + g1;
        let t2 = m12 * ddq[0] + m22 * ddq[1] + h * dq[0] * dq[0] + g2;
        assert!((tau[0] - t1).abs() < 1e-9, "{} {}", tau[0], t1);
        assert!((tau[1] - t2).abs() < 1e-9, "{} {}", tau[1], t2);
        let mut m = [0.0; 4];
        chain.mass_matrix(&q, true, &mut w, &mut m);
        assert!((m[0] - m11 - 0.5).abs() < 1e-9 && (m[1] - m12).abs() < 1e-9);
        assert!((m[2] - m12).abs() < 1e-9 && (m[3] - m22).abs() < 1e-9);
    }

    #[test]
    fn the_regressor_times_the_parameters_is_the_inverse_dynamics() {
        let chain = two_link();
        let mut w = Work::default();
        let (q, dq, ddq) = ([-0.2, 0.9], [0.3, 0.5], [-1.0, 0.6]);
        let mut y = [0.0; 2 * 20];
        chain.regressor(&q, &dq, &ddq, &mut w, &mut y);
        let mut tau = [0.0; 2];
        chain.rnea(&q, &dq, &ddq, true, false, &mut w, &mut tau);
        for i in 0..2 {
            let mut s = 0.0;
            for k in 0..2 {
                for c in 0..10 {
                    s += y[i * 20 + 10 * k + c] * chain.joints[k].inertia[c];
                }
            }
            assert!((s - tau[i]).abs() < 1e-9);
        }
        assert!(
            y[20..30].iter().all(|&v| v == 0.0),
            "joint 2 does not feel body 1"
        );
    }

    #[test]
    fn the_tool_jacobian_is_the_derivative_of_its_position() {
        let chain = two_link();
        let mut w = Work::default();
        let q = [0.4, -0.7];
        let mut jac = [0.0; 12];
        let p0 = chain.tool_jacobian(&q, &mut w, &mut jac).p;
        // x = l1 cos q1 + l2 cos(q1 + q2), z = l1 sin q1 + l2 sin(q1 + q2)
        let want_x = 1.0 * q[0].cos() + 0.8 * (q[0] + q[1]).cos();
        assert!((p0[0] - want_x).abs() < 1e-12);
        for k in 0..2 {
            let mut qh = q;
            qh[k] += 1e-7;
            let p1 = chain.tool_pose(&qh, &mut w).p;
            for r in 0..3 {
                assert!(((p1[r] - p0[r]) / 1e-7 - jac[r * 2 + k]).abs() < 1e-5);
            }
            assert!((jac[4 * 2 + k] + 1.0).abs() < 1e-12, "ω about −y");
        }
    }

    #[test]
    fn a_bad_table_is_refused_naming_what_is_wrong() {
        let chain = two_link();
        let _ = chain;
        let bad = json!({"format": CHAIN_FORMAT, "version": CHAIN_VERSION, "joints": []});
        assert!(Chain::from_json(&bad).unwrap_err().contains("joints"));
        let id = json!([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]);
        let mut one = json!({
            "format": CHAIN_FORMAT, "version": CHAIN_VERSION, "gravity_m_s2": [0.0, 0.0, -9.81],
            "joints": [{"parent": null, "placement": {"rotation": id, "translation": [0.0, 0.0, 0.0]},
                        "kind": "revolute", "axis": [0.0, 2.0, 0.0], "inertia": [0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0], "armature": 0.0}],
            "tool": {"joint": 0, "placement": {"rotation": id, "translation": [0.0, 0.0, 0.0]}},
        });
        assert!(Chain::from_json(&one)
            .unwrap_err()
            .contains("joints[0].axis"));
        one["joints"][0]["axis"] = json!([0.0, 1.0, 0.0]);
        one["joints"][0]["placement"]["rotation"][0][0] = json!(2.0);
        assert!(Chain::from_json(&one)
            .unwrap_err()
            .contains("joints[0].placement.rotation"));
        one["joints"][0]["placement"]["rotation"][0][0] = json!(1.0);
        one["joints"][0]["parent"] = json!(0);
        assert!(Chain::from_json(&one)
            .unwrap_err()
            .contains("joints[0].parent"));
        one["joints"][0]["parent"] = Value::Null;
        one["tool"]["joint"] = json!(3);
        assert!(Chain::from_json(&one).unwrap_err().contains("tool.joint"));
        one["tool"]["joint"] = json!(0);
        assert!(Chain::from_json(&one).is_ok());
    }
}
