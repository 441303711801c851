//! Spatial algebra of rigid bodies, pinocchio's conventions: a motion or a force is six numbers,
//! linear part first; a placement `(R, p)` puts a child frame in its parent's (`x_parent = R
//! x_child + p`).

pub type Vec3 = [f64; 3];
pub type Mat3 = [[f64; 3]; 3];
/// A motion (v, ω) or a force (f, n), linear first.
pub type Six = [f64; 6];

pub fn cross(a: &Vec3, b: &Vec3) -> Vec3 {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}

pub fn dot(a: &Vec3, b: &Vec3) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

pub fn add(a: &Vec3, b: &Vec3) -> Vec3 {
    [a[0] + b[0], a[1] + b[1], a[2] + b[2]]
}

pub fn sub(a: &Vec3, b: &Vec3) -> Vec3 {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}

pub fn scale(a: &Vec3, s: f64) -> Vec3 {
    [a[0] * s, a[1] * s, a[2] * s]
}

pub fn mat_vec(m: &Mat3, v: &Vec3) -> Vec3 {
    [dot(&m[0], v), dot(&m[1], v), dot(&m[2], v)]
}

/// `mᵀ v`.
pub fn mat_t_vec(m: &Mat3, v: &Vec3) -> Vec3 {
    [
        m[0][0] * v[0] + m[1][0] * v[1] + m[2][0] * v[2],
        m[0][1] * v[0] + m[1][1] * v[1] + m[2][1] * v[2],
        m[0][2] * v[0] + m[1][2] * v[1] + m[2][2] * v[2],
    ]
}

pub fn mat_mul(a: &Mat3, b: &Mat3) -> Mat3 {
    let mut out = [[0.0; 3]; 3];
    for (i, row) in out.iter_mut().enumerate() {
        for (j, v) in row.iter_mut().enumerate() {
            *v = a[i][0] * b[0][j] + a[i][1] * b[1][j] + a[i][2] * b[2][j];
        }
    }
    out
}

/// `a bᵀ`.
pub fn mat_mul_t(a: &Mat3, b: &Mat3) -> Mat3 {
    [
        [dot(&a[0], &b[0]), dot(&a[0], &b[1]), dot(&a[0], &b[2])],
        [dot(&a[1], &b[0]), dot(&a[1], &b[1]), dot(&a[1], &b[2])],
        [dot(&a[2], &b[0]), dot(&a[2], &b[1]), dot(&a[2], &b[2])],
    ]
}

/// The turn by `angle` [rad] about the unit `axis`: `c·I + s·[a]× + (1 − c)·a·aᵀ`.
pub fn axis_rotation(axis: &Vec3, angle: f64) -> Mat3 {
    let (s, c) = angle.sin_cos();
    let [x, y, z] = *axis;
    let t = 1.0 - c;
    [
        [c + t * x * x, t * x * y - s * z, t * x * z + s * y],
        [t * x * y + s * z, c + t * y * y, t * y * z - s * x],
        [t * x * z - s * y, t * y * z + s * x, c + t * z * z],
    ]
}

fn lin(m: &Six) -> Vec3 {
    [m[0], m[1], m[2]]
}

fn ang(m: &Six) -> Vec3 {
    [m[3], m[4], m[5]]
}

fn six(l: Vec3, a: Vec3) -> Six {
    [l[0], l[1], l[2], a[0], a[1], a[2]]
}

/// A placement of a child frame in its parent: rotation and origin.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Placement {
    pub r: Mat3,
    pub p: Vec3,
}

impl Placement {
    pub const IDENTITY: Placement = Placement {
        r: [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]],
        p: [0.0; 3],
    };

    /// `self · other`: `other`'s frame placed in `self`'s parent.
    pub fn compose(&self, other: &Placement) -> Placement {
        Placement {
            r: mat_mul(&self.r, &other.r),
            p: add(&mat_vec(&self.r, &other.p), &self.p),
        }
    }

    /// A point of the child frame in the parent's.
    pub fn point(&self, x: &Vec3) -> Vec3 {
        add(&mat_vec(&self.r, x), &self.p)
    }

    /// A motion of the child frame expressed in the parent's.
    pub fn act_motion(&self, m: &Six) -> Six {
        let w = mat_vec(&self.r, &ang(m));
        let v = add(&mat_vec(&self.r, &lin(m)), &cross(&self.p, &w));
        six(v, w)
    }

    /// A motion of the parent frame expressed in the child's.
    pub fn act_inv_motion(&self, m: &Six) -> Six {
        let w = ang(m);
        let v = mat_t_vec(&self.r, &sub(&lin(m), &cross(&self.p, &w)));
        six(v, mat_t_vec(&self.r, &w))
    }

    /// A force of the child frame expressed in the parent's.
    pub fn act_force(&self, f: &Six) -> Six {
        let fl = mat_vec(&self.r, &lin(f));
        let n = add(&mat_vec(&self.r, &ang(f)), &cross(&self.p, &fl));
        six(fl, n)
    }
}

/// `a ×ₘ b`, the motion cross product: `(ω × b_v + v × b_ω, ω × b_ω)`.
pub fn motion_cross(a: &Six, b: &Six) -> Six {
    let (v, w) = (lin(a), ang(a));
    six(
        add(&cross(&w, &lin(b)), &cross(&v, &ang(b))),
        cross(&w, &ang(b)),
    )
}

/// The wrench `I a + v ×* (I v)` [N, N·m] of a body whose ten dynamic parameters are `pi`
/// (pinocchio's order: m, m c, then I about the frame's origin as xx, xy, yy, xz, yz, zz),
/// moving at `v` with acceleration `a` (both in its frame). Linear in `pi`: the body regressor
/// is this on the unit vectors.
pub fn body_wrench(pi: &[f64; 10], v: &Six, a: &Six) -> Six {
    let m = pi[0];
    let h = [pi[1], pi[2], pi[3]];
    let inertia = |x: &Vec3| -> Vec3 {
        [
            pi[4] * x[0] + pi[5] * x[1] + pi[7] * x[2],
            pi[5] * x[0] + pi[6] * x[1] + pi[8] * x[2],
            pi[7] * x[0] + pi[8] * x[1] + pi[9] * x[2],
        ]
    };
    // I m = (m m_v + m_ω × h, I_o m_ω + h × m_v)
    let apply = |x: &Six| -> Six {
        let (xv, xw) = (lin(x), ang(x));
        six(
            add(&scale(&xv, m), &cross(&xw, &h)),
            add(&inertia(&xw), &cross(&h, &xv)),
        )
    };
    let ia = apply(a);
    let iv = apply(v);
    let (vl, w) = (lin(v), ang(v));
    // v ×* F = (ω × F_f, ω × F_n + v × F_f)
    let f = add(&lin(&ia), &cross(&w, &lin(&iv)));
    let n = add(
        &ang(&ia),
        &add(&cross(&w, &ang(&iv)), &cross(&vl, &lin(&iv))),
    );
    six(f, n)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_motion_acted_and_acted_back_is_itself() {
        let x = Placement {
            r: axis_rotation(&[0.0, 0.6, 0.8], 0.7),
            p: [0.3, -0.2, 1.1],
        };
        let m = [0.1, -0.4, 0.9, 1.3, 0.2, -0.7];
        let back = x.act_inv_motion(&x.act_motion(&m));
        for k in 0..6 {
            assert!((back[k] - m[k]).abs() < 1e-12);
        }
    }

    #[test]
    fn power_is_the_same_in_either_frame() {
        // v·f is frame-invariant: (X v)·(X* f) = v·f
        let x = Placement {
            r: axis_rotation(&[1.0, 0.0, 0.0], -0.4),
            p: [0.5, 0.1, -0.3],
        };
        let v = [0.2, 0.3, -0.1, 0.5, -0.6, 0.4];
        let f = [10.0, -3.0, 2.0, 0.7, 1.1, -2.5];
        let (va, fa) = (x.act_motion(&v), x.act_force(&f));
        let p1: f64 = (0..6).map(|k| v[k] * f[k]).sum();
        let p2: f64 = (0..6).map(|k| va[k] * fa[k]).sum();
        assert!((p1 - p2).abs() < 1e-12);
    }

    #[test]
    fn a_point_mass_at_rest_under_gravity_weighs_m_g_with_its_moment() {
        // m = 2 kg at c = (0.5, 0, 0); acceleration -gravity = (0, 0, 9.81) upward
        let (m, c) = (2.0, [0.5, 0.0, 0.0]);
        let io = [0.0, 0.0, m * c[0] * c[0], 0.0, 0.0, m * c[0] * c[0]]; // m (|c|² E - c cᵀ)
        let pi = [
            m,
            m * c[0],
            0.0,
            0.0,
            io[0],
            io[1],
            io[2],
            io[3],
            io[4],
            io[5],
        ];
        let f = body_wrench(&pi, &[0.0; 6], &[0.0, 0.0, 9.81, 0.0, 0.0, 0.0]);
        let want = [0.0, 0.0, 2.0 * 9.81, 0.0, -0.5 * 2.0 * 9.81, 0.0]; // c × F
        for k in 0..6 {
            assert!((f[k] - want[k]).abs() < 1e-12, "{k}: {f:?}");
        }
    }
}
