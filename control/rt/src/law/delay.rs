//! The arm's state when a command takes effect: a Smith predictor over the command delay.
//!
//! The drive follows a command `d` cycles after the state it answers (the inner-loop experiment
//! measures `d`, `inner_loop.json` `delay_cycles`): when the controller applies a command it
//! starts its reference there, `q_c + dq_c (t - t_apply)`, with the arm `d` cycles further on.
//! Eq. (21) sent for the stale state acts on a stale offset: the arm's travel over the delay, `dq
//! h` (h = d T), is a damper of `K K_I h` (J2 of the GR630ST at 8 ms: some 6,600 N·m·s/rad,
//! a 20 N push moves nothing), and its speed-up an inertia of `K K_p h`. Extrapolating the
//! measurement does not cure it: the drive's own velocity loop (`K K_p / J` ≈ 110/s, a 9 ms time
//! constant) moves the arm within the delay more than the hand does, and an extrapolated velocity
//! fed back as the command destabilises the drive as soon as `K K_p h / J` nears 1 (a 1-DOF
//! scan over inertias and gains ±50 % in the note of 2026-11-25).
//!
//! The predictor therefore runs what happens within the delay, as the plant will:
//!
//! - the references already in flight: for a delay of d cycles, the commands the driver sent for
//!   the last d states, as each state's echo (`JointState.q_cmd_rad`/`dq_cmd_rad_s`) reports
//!   them, holds and coasts included; the one echoed by the newest state starts now;
//! - the drive's PI loop of eq. (19) with the estimated gains (`1/ω̂ = K K_p`, `Υ̂_I`) on the
//!   arm's inertia `M(q)` (the datasheet's nominal rigid body with its rotor inertias);
//! - everything else (gravity, cylinders, friction, the operator's hand) held at what the last
//!   cycle showed: `M a - τ_last`, `a` the difference of the last two measured velocities
//!   over their cycle and `τ_last` the drive's torque in that cycle by the same PI model (the
//!   reference then applied against the cycle's mean state), so `ddq = a + M⁻¹ (τ_drive -
//!   τ_last)`. The model rather than the measured current: the current's noise (0.02 A, 0.1 N·m
//!   on a wrist whose inertia is a fraction of a kg·m²) would enter the predicted velocity each
//!   cycle and the wrist would wander (4-5 mrad in 5 s on the virtual cell, against 0.7 with the
//!   model);
//!
//! integrated in steps of at most :data:`SUBSTEP_S` (semi-implicit Euler), and shorter where the
//! drive model is stiffer than that step can integrate: its velocity loop's rate `K K_p
//! (M⁻¹)ⱼⱼ` times the step stays below :data:`STIFF_STEP` (a K̂* 26 times the drive's, as the
//! paper's Υ̂_I(0) gives with the commissioned static gain, made 1 ms steps diverge: commands
//! 10⁴ rad off on the virtual cell), in at most :data:`MAX_SUBSTEPS` per cycle, beyond which the
//! velocity carries on unchanged over the delay. Eq. (21) is then sent
//! for the predicted state. Without a consecutive history (start, a gap, a missing echo) the
//! velocity carries on unchanged over the delay. The scan: with ±30 % inertia and ±20 % gain
//! errors the loop stays stable and as light as without delay, for delays of 1 and 2 cycles.
//!
//! The same arithmetic, in the same order, as the Python it replaced (control/delay.py).

use std::fmt;

use crate::chain::MAX_JOINTS;

/// Longest integration step of the prediction [s] (the drive's servo tick is about 1 ms).
pub const SUBSTEP_S: f64 = 0.001;
/// The drive model's velocity-loop rate K K_p (M⁻¹)ⱼⱼ × the step stays below this (explicit
/// damping is stable below 2; the GR630ST's commissioned drives reach 0.44 at 1 ms).
pub const STIFF_STEP: f64 = 1.0;
/// Most integration steps per cycle of delay.
pub const MAX_SUBSTEPS: usize = 64;
/// Longest command delay the predictor takes [cycles].
pub const MAX_DELAY_CYCLES: usize = 10;

/// Why a prediction could not be made. The Python raised ValueError for the first two and
/// OverflowError (from `math.ceil`) for the last.
#[derive(Clone, Debug, PartialEq)]
pub enum DelayError {
    /// An argument of the wrong size, named.
    Shape(String),
    /// The number of integration steps is NaN (a NaN period).
    StepsNan,
    /// The number of integration steps is infinite (an infinite period, or a drive model so
    /// stiff that its rate times the period overflows).
    StepsInfinite,
}

impl fmt::Display for DelayError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            DelayError::Shape(what) => f.write_str(what),
            DelayError::StepsNan => f.write_str("delay prediction: the number of steps is NaN"),
            DelayError::StepsInfinite => {
                f.write_str("delay prediction: the number of steps is infinite")
            }
        }
    }
}

/// One cycle's measurement: the state, the command its echo reports, the period.
pub struct Cycle<'a> {
    /// Measured joint positions [rad].
    pub q: &'a [f64],
    /// Measured joint velocities [rad/s].
    pub dq: &'a [f64],
    /// The position command the driver sent last, as this state's echo reports it [rad].
    pub echo_q: &'a [f64],
    /// The velocity command the driver sent last [rad/s].
    pub echo_dq: &'a [f64],
    /// The cycle's period [s].
    pub period_s: f64,
    /// This state follows the last by one cycle.
    pub consecutive: bool,
}

/// The drive model of eq. (19) on the arm.
pub struct Drive<'a> {
    /// M(q)⁻¹, n × n row-major [1/(kg·m²)].
    pub m_inv: &'a [f64],
    /// 1/ω̂ = K K_p per joint [N·m·s/rad].
    pub k_star: &'a [f64],
    /// Υ̂_I per joint [1/s].
    pub upsilon: &'a [f64],
}

type Joints = [f64; MAX_JOINTS];

/// Predicts the measured state `delay_cycles` cycles on. Call [`DelayPredictor::predict`]
/// once per state, in order; [`DelayPredictor::reset`] when the history breaks.
#[derive(Clone, Debug)]
pub struct DelayPredictor {
    delay_cycles: usize,
    /// joints of the stored history (last state, echoes, applied reference)
    n: usize,
    /// the echoes of the last `delay_cycles` states, a ring oldest first from `head`
    echo_q: [Joints; MAX_DELAY_CYCLES],
    echo_dq: [Joints; MAX_DELAY_CYCLES],
    head: usize,
    len: usize,
    /// (q, dq) of the last state, if any
    last: Option<(Joints, Joints)>,
    /// the reference the drive followed since the last state (None: unknown)
    applied: Option<(Joints, Joints)>,
    /// scratch: the acceleration held over the delay, the drive's torque, M⁻¹ τ
    base: Joints,
    tau: Joints,
    m_tau: Joints,
}

/// Eq. (19)'s torque at arm state (qa, dqa) against the reference (ref_q, ref_dq), one joint.
fn drive_nm(k_star: f64, upsilon: f64, ref_q: f64, ref_dq: f64, qa: f64, dqa: f64) -> f64 {
    k_star * ((ref_dq - dqa) + upsilon * (ref_q - qa))
}

/// `m @ v` for an n × n row-major `m`, into `out`.
fn mat_vec(m: &[f64], v: &[f64], out: &mut [f64]) {
    let n = v.len();
    for (i, o) in out.iter_mut().enumerate() {
        *o = m[i * n..(i + 1) * n]
            .iter()
            .zip(v)
            .fold(0.0, |acc, (a, b)| acc + a * b);
    }
}

/// `math.ceil` of Python, for a count: NaN and ±inf refused as Python does.
fn ceil_count(x: f64) -> Result<f64, DelayError> {
    if x.is_nan() {
        Err(DelayError::StepsNan)
    } else if x.is_infinite() {
        Err(DelayError::StepsInfinite)
    } else {
        Ok(x.ceil())
    }
}

impl DelayPredictor {
    /// A predictor over a delay of `delay_cycles` (0 ..= 10; 0 predicts nothing).
    pub fn new(delay_cycles: i64) -> Result<DelayPredictor, String> {
        if !(0..=MAX_DELAY_CYCLES as i64).contains(&delay_cycles) {
            return Err(format!(
                "command delay {delay_cycles} not in 0..{MAX_DELAY_CYCLES} cycles"
            ));
        }
        Ok(DelayPredictor {
            delay_cycles: delay_cycles as usize,
            n: 0,
            echo_q: [[0.0; MAX_JOINTS]; MAX_DELAY_CYCLES],
            echo_dq: [[0.0; MAX_JOINTS]; MAX_DELAY_CYCLES],
            head: 0,
            len: 0,
            last: None,
            applied: None,
            base: [0.0; MAX_JOINTS],
            tau: [0.0; MAX_JOINTS],
            m_tau: [0.0; MAX_JOINTS],
        })
    }

    pub fn delay_cycles(&self) -> usize {
        self.delay_cycles
    }

    /// Forget the history: the next state predicts by carrying its velocity on.
    pub fn reset(&mut self) {
        self.head = 0;
        self.len = 0;
        self.last = None;
        self.applied = None;
    }

    fn check(cycle: &Cycle, drive: &Drive, q_out: &[f64], dq_out: &[f64]) -> Result<(), String> {
        let n = cycle.q.len();
        if n > MAX_JOINTS {
            return Err(format!("q has {n} joints, at most {MAX_JOINTS}"));
        }
        let sized = [
            ("dq", cycle.dq.len()),
            ("echo_q", cycle.echo_q.len()),
            ("echo_dq", cycle.echo_dq.len()),
            ("k_star", drive.k_star.len()),
            ("upsilon", drive.upsilon.len()),
            ("q_out", q_out.len()),
            ("dq_out", dq_out.len()),
        ];
        for (what, len) in sized {
            if len != n {
                return Err(format!("{what} needs {n} values, got {len}"));
            }
        }
        if drive.m_inv.len() != n * n {
            return Err(format!(
                "m_inv needs {n} x {n} values, got {}",
                drive.m_inv.len()
            ));
        }
        Ok(())
    }

    /// Append an echo, dropping the oldest once `delay_cycles` are held.
    fn push_echo(&mut self, q: &[f64], dq: &[f64]) {
        let cap = self.delay_cycles;
        let slot = if self.len == cap {
            let s = self.head;
            self.head = (self.head + 1) % cap;
            s
        } else {
            self.len += 1;
            (self.head + self.len - 1) % cap
        };
        self.echo_q[slot][..q.len()].copy_from_slice(q);
        self.echo_dq[slot][..dq.len()].copy_from_slice(dq);
    }

    /// `(q, dq)` when the command answering this state takes effect, into `q_out`, `dq_out`.
    /// A delay of 0 copies the state.
    pub fn predict(
        &mut self,
        cycle: &Cycle,
        drive: &Drive,
        q_out: &mut [f64],
        dq_out: &mut [f64],
    ) -> Result<(), DelayError> {
        let (q, dq, period_s) = (cycle.q, cycle.dq, cycle.period_s);
        Self::check(cycle, drive, q_out, dq_out).map_err(DelayError::Shape)?;
        let d = self.delay_cycles;
        if d == 0 {
            q_out.copy_from_slice(q);
            dq_out.copy_from_slice(dq);
            return Ok(());
        }
        let n = q.len();
        if !cycle.consecutive {
            self.reset();
        } else if self.len > 0 && n != self.n {
            return Err(DelayError::Shape(format!(
                "q has {n} joints, the history {} (reset first)",
                self.n
            )));
        }
        let (last, applied) = (self.last.take(), self.applied.take());
        let mut now = ([0.0; MAX_JOINTS], [0.0; MAX_JOINTS]);
        now.0[..n].copy_from_slice(q);
        now.1[..n].copy_from_slice(dq);
        self.last = Some(now);
        self.n = n;
        self.push_echo(cycle.echo_q, cycle.echo_dq);
        let full = self.len == d;
        if full {
            // followed from now on
            self.applied = Some((self.echo_q[self.head], self.echo_dq[self.head]));
        }
        let h = d as f64 * period_s;
        let carry_on = |q_out: &mut [f64], dq_out: &mut [f64]| {
            for j in 0..n {
                q_out[j] = q[j] + h * dq[j];
                dq_out[j] = dq[j];
            }
        };
        let (Some((last_q, last_dq)), Some((ref_q, ref_dq)), true) = (last, applied, full) else {
            carry_on(q_out, dq_out);
            return Ok(());
        };

        if n == 0 {
            // the Python's np.max of nothing
            return Err(DelayError::Shape("m_inv is empty".into()));
        }
        let (m_inv, k_star, upsilon) = (drive.m_inv, drive.k_star, drive.upsilon);
        // at the middle of the last cycle, against its mean state
        let half = 0.5 * period_s;
        for j in 0..n {
            self.tau[j] = drive_nm(
                k_star[j],
                upsilon[j],
                ref_q[j] + half * ref_dq[j],
                ref_dq[j],
                0.5 * (q[j] + last_q[j]),
                0.5 * (dq[j] + last_dq[j]),
            );
        }
        mat_vec(m_inv, &self.tau[..n], &mut self.m_tau[..n]);
        for j in 0..n {
            self.base[j] = (dq[j] - last_dq[j]) / period_s - self.m_tau[j];
        }
        // np.max: NaN wins
        let rate = (0..n)
            .map(|j| m_inv[j * n + j] * k_star[j])
            .reduce(|a, b| {
                if !a.is_nan() && (b.is_nan() || b > a) {
                    b
                } else {
                    a
                }
            })
            .unwrap_or(f64::NAN);
        let mut steps = ceil_count(period_s / SUBSTEP_S - 1e-9)?.max(1.0);
        let integrable = rate * period_s / steps < STIFF_STEP; // false for NaN too
        if !integrable {
            steps = if rate.is_finite() {
                ceil_count(rate * period_s / STIFF_STEP)?
            } else {
                0.0
            };
            if !(0.0 < steps && steps <= MAX_SUBSTEPS as f64) {
                carry_on(q_out, dq_out);
                return Ok(());
            }
        }
        let step = period_s / steps;
        q_out.copy_from_slice(q);
        dq_out.copy_from_slice(dq);
        for k in 0..d {
            // oldest first: the one applied now
            let slot = (self.head + k) % d;
            let (ref_q, ref_dq) = (&self.echo_q[slot], &self.echo_dq[slot]);
            for s in 0..steps as usize {
                let t = s as f64 * step;
                for j in 0..n {
                    self.tau[j] = drive_nm(
                        k_star[j],
                        upsilon[j],
                        ref_q[j] + ref_dq[j] * t,
                        ref_dq[j],
                        q_out[j],
                        dq_out[j],
                    );
                }
                mat_vec(m_inv, &self.tau[..n], &mut self.m_tau[..n]);
                for ((dqp, base), m_tau) in dq_out.iter_mut().zip(&self.base).zip(&self.m_tau) {
                    *dqp += step * (base + m_tau);
                }
                for j in 0..n {
                    q_out[j] += step * dq_out[j];
                }
            }
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn run(
        p: &mut DelayPredictor,
        q: &[f64],
        dq: &[f64],
        echo: (&[f64], &[f64]),
        consecutive: bool,
        drive: &Drive,
    ) -> Result<(Vec<f64>, Vec<f64>), DelayError> {
        let (mut qo, mut dqo) = (vec![0.0; q.len()], vec![0.0; q.len()]);
        let cycle = Cycle {
            q,
            dq,
            echo_q: echo.0,
            echo_dq: echo.1,
            period_s: 0.008,
            consecutive,
        };
        p.predict(&cycle, drive, &mut qo, &mut dqo)?;
        Ok((qo, dqo))
    }

    const ONE: Drive = Drive {
        m_inv: &[0.05],
        k_star: &[1000.0],
        upsilon: &[1.2],
    };

    #[test]
    fn a_delay_out_of_range_is_refused() {
        assert!(DelayPredictor::new(-1)
            .unwrap_err()
            .contains("not in 0..10"));
        assert!(DelayPredictor::new(11).is_err());
        assert_eq!(DelayPredictor::new(10).unwrap().delay_cycles(), 10);
    }

    #[test]
    fn without_a_history_the_velocity_carries_on() {
        let mut p = DelayPredictor::new(2).unwrap();
        let (q, dq) = run(&mut p, &[0.1], &[0.5], (&[0.1], &[0.5]), true, &ONE).unwrap();
        assert_eq!((q, dq), (vec![0.1 + 0.016 * 0.5], vec![0.5]));
    }

    #[test]
    fn a_consecutive_history_runs_the_drive_model_and_a_gap_forgets_it() {
        let mut p = DelayPredictor::new(1).unwrap();
        // the reference holds the arm where it is: the prediction keeps near it
        for _ in 0..3 {
            run(&mut p, &[0.1], &[0.0], (&[0.1], &[0.0]), true, &ONE).unwrap();
        }
        let (q, dq) = run(&mut p, &[0.1], &[0.0], (&[0.1], &[0.0]), true, &ONE).unwrap();
        assert!(
            (q[0] - 0.1).abs() < 1e-12 && dq[0].abs() < 1e-12,
            "{q:?} {dq:?}"
        );
        // a reference ahead pulls the arm on
        let (q, _) = run(&mut p, &[0.1], &[0.0], (&[0.2], &[0.0]), true, &ONE).unwrap();
        assert!(q[0] > 0.1);
        let (q, dq) = run(&mut p, &[0.1], &[0.3], (&[0.2], &[0.0]), false, &ONE).unwrap();
        assert_eq!((q, dq), (vec![0.1 + 0.008 * 0.3], vec![0.3]));
    }

    #[test]
    fn a_drive_model_too_stiff_for_max_substeps_carries_the_velocity_on() {
        let stiff = Drive {
            k_star: &[1e9],
            ..ONE
        };
        let mut p = DelayPredictor::new(1).unwrap();
        for _ in 0..3 {
            let (q, dq) = run(&mut p, &[0.1], &[0.05], (&[0.101], &[0.05]), true, &stiff).unwrap();
            assert_eq!((q, dq), (vec![0.1 + 0.008 * 0.05], vec![0.05]));
        }
    }

    #[test]
    fn wrong_sizes_and_a_changed_joint_count_are_refused() {
        let mut p = DelayPredictor::new(1).unwrap();
        let err = run(&mut p, &[0.1, 0.2], &[0.0], (&[0.1], &[0.0]), true, &ONE).unwrap_err();
        assert_eq!(err, DelayError::Shape("dq needs 2 values, got 1".into()));
        run(&mut p, &[0.1], &[0.0], (&[0.1], &[0.0]), true, &ONE).unwrap();
        let two = Drive {
            m_inv: &[1.0, 0.0, 0.0, 1.0],
            k_star: &[1.0, 1.0],
            upsilon: &[1.0, 1.0],
        };
        let (z, e) = (&[0.0, 0.0][..], &[0.0, 0.0][..]);
        assert!(run(&mut p, z, z, (e, e), true, &two).is_err());
        assert!(run(&mut p, z, z, (e, e), false, &two).is_ok());
    }
}
