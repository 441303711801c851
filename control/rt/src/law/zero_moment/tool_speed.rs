//! Hand guiding's speed limit in the zero-moment law (zero_moment.rs): the tool point's and the
//! flange's speed from their Jacobians, the speed the commands are held to this cycle, and the
//! factor that holds a velocity command to it.

use super::{max_abs_diff, ZeroMoment};
use crate::chain::{Chain, Work, MAX_JOINTS};

impl ZeroMoment {
    /// The tool point's and the flange's linear velocity Jacobians (6 × n, world axes),
    /// recomputed once a joint has moved `speed_jacobian_step_rad`. The flange sits `r = R p`
    /// behind the tool point (p the tool point in the link-6 frame), so `v_flange = v_tool -
    /// ω × r = (J_v + [r]× J_ω) dq`.
    pub fn refresh_speed_jacobians(&mut self, chain: &Chain, work: &mut Work, q: &[f64]) {
        let n = self.n();
        let stale = match &self.jac_at {
            None => true,
            Some(at) => max_abs_diff(q, &at[..n]) > self.s.speed_jacobian_step_rad,
        };
        if !stale {
            return;
        }
        let mut jac = [0.0; 6 * MAX_JOINTS];
        let pose = chain.tool_jacobian(q, work, &mut jac[..6 * n]);
        let p = self.s.tool_in_6_m;
        let r: [f64; 3] = std::array::from_fn(|i| {
            // numpy's R @ p: ((R[i,0] p0 + R[i,1] p1) + R[i,2] p2)
            pose.r[i][0] * p[0] + pose.r[i][1] * p[1] + pose.r[i][2] * p[2]
        });
        let skew = [[0.0, -r[2], r[1]], [r[2], 0.0, -r[0]], [-r[1], r[0], 0.0]];
        for k in 0..n {
            for i in 0..3 {
                self.jac[i * n + k] = jac[i * n + k];
                let mut w = 0.0;
                for (m, s) in skew[i].iter().enumerate() {
                    w += s * jac[(3 + m) * n + k];
                }
                self.jac[(3 + i) * n + k] = jac[i * n + k] + w;
            }
        }
        let mut at = [0.0; MAX_JOINTS];
        at[..n].copy_from_slice(q);
        self.jac_at = Some(at);
    }

    /// The faster of the tool point and the flange at (q, dq) [m/s].
    pub fn point_speed(&mut self, chain: &Chain, work: &mut Work, q: &[f64], dq: &[f64]) -> f64 {
        self.refresh_speed_jacobians(chain, work, q);
        let n = self.n();
        let mut v = [0.0; 6];
        for (i, vi) in v.iter_mut().enumerate() {
            let mut s = 0.0;
            for k in 0..n {
                s += self.jac[i * n + k] * dq[k];
            }
            *vi = s;
        }
        let tool = py_hypot3(v[0], v[1], v[2]);
        let flange = py_hypot3(v[3], v[4], v[5]);
        // Python's max(a, b): b only if b > a (NaN a stays)
        if flange > tool {
            flange
        } else {
            tool
        }
    }

    /// The speed the commands are held to this cycle [m/s]: the limit, less
    /// `speed_feedback_gain` × what the arm's speed at (q, dq) exceeds it by (not below 0).
    pub fn speed_target(&mut self, chain: &Chain, work: &mut Work, q: &[f64], dq: &[f64]) -> f64 {
        let limit = self.s.max_tool_speed_m_s;
        let excess = self.point_speed(chain, work, q, dq) - limit;
        if excess.is_nan() || excess <= 0.0 {
            return limit;
        }
        let t = limit - self.s.speed_feedback_gain * excess;
        if t > 0.0 {
            t
        } else {
            0.0
        }
    }

    /// The factor (≤ 1) on `dq` that keeps the tool point and the flange within this cycle's
    /// speed target.
    pub fn tool_speed_scale(
        &mut self,
        chain: &Chain,
        work: &mut Work,
        q: &[f64],
        dq: &[f64],
    ) -> f64 {
        let fastest = self.point_speed(chain, work, q, dq);
        let limit = self.speed_target;
        if fastest <= limit {
            1.0
        } else {
            limit / fastest
        }
    }
}

/// The length of (a, b, c) (Python's `math.hypot` to rounding).
fn py_hypot3(a: f64, b: f64, c: f64) -> f64 {
    (a * a + b * b + c * c).sqrt()
}
