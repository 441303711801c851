//! A built plan played one command per controller cycle (control/plan_player.py's
//! `PlanPlayer` builds it off the cycle and hands it here; issue 48: the replay's cycle has no
//! Python in it).
//!
//! The plan waits for the robot: a sample the CAN driver answered with a hold (the next
//! state's FLAG_PREV_HOLD) is sent again instead of running ahead, and a plan held for longer
//! than `max_pause_s` in a row fails with the reason. A coast moves the arm on as the plan
//! does, so the plan moves on too. A hold stopped the arm, so the plan resumes from rest: its
//! speed along the samples is scaled by σ, 0 after a hold, rising each cycle so that no joint's
//! commanded velocity rises faster than `resume_accel_rad_s2`, up to 1 (the plan's own timing).
//! Between samples, positions and velocities are interpolated. Each segment's first and last
//! sample are recorded with the cycle that carried them out, for the export.

/// A JointState's flag: the CAN driver held the cycle before it (the bus contract's).
const FLAG_PREV_HOLD: u32 = bus_rt::messages::FLAG_PREV_HOLD as u32;
/// A fractional plan index this close to a sample is that sample.
const INDEX_TOLERANCE: f64 = 1e-9;

/// Where a plan is.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Phase {
    Running,
    Done,
    Failed,
}

impl Phase {
    pub fn name(self) -> &'static str {
        match self {
            Phase::Running => "running",
            Phase::Done => "done",
            Phase::Failed => "failed",
        }
    }
}

/// A plan being played (module docs).
#[derive(Clone, Debug)]
pub struct PlanPlay {
    n: usize,
    len: usize,
    q: Vec<f64>,
    dq: Vec<f64>,
    bounds: Vec<(usize, usize)>,
    /// The cycles that carried out each segment's first and last sample (-1: not yet).
    pub segment_cycles: Vec<(i64, i64)>,
    period_s: f64,
    max_pause_s: f64,
    resume_accel_rad_s2: f64,
    /// The sample to play next.
    pub k: usize,
    s: f64,
    sigma: f64,
    sent_cycle: Option<i64>,
    /// How long the plan's commands have been held in a row [s].
    pub held_s: f64,
    /// Samples sent again after a hold.
    pub repeats: u64,
    pub phase: Phase,
    pub reason: String,
}

impl PlanPlay {
    /// A plan of `q`, `dq` (rows of `n` joints, flat), in segments of `lengths` samples, played
    /// every `period_s`.
    pub fn new(
        q: Vec<f64>,
        dq: Vec<f64>,
        n: usize,
        lengths: &[usize],
        period_s: f64,
        max_pause_s: f64,
        resume_accel_rad_s2: f64,
    ) -> Result<PlanPlay, String> {
        if n == 0 || q.is_empty() || q.len() % n != 0 || dq.len() != q.len() {
            return Err(format!(
                "a plan needs rows of {n} joints: q has {} values, dq {}",
                q.len(),
                dq.len()
            ));
        }
        let len = q.len() / n;
        if lengths.iter().sum::<usize>() != len || lengths.contains(&0) {
            return Err(format!("segments of {lengths:?} samples do not make {len}"));
        }
        if !(period_s > 0.0 && max_pause_s > 0.0 && resume_accel_rad_s2 > 0.0) {
            return Err(format!(
                "period {period_s} s, pause {max_pause_s} s, resumption {resume_accel_rad_s2} rad/s²: not positive"
            ));
        }
        if q.iter().chain(&dq).any(|v| !v.is_finite()) {
            return Err("the plan has a value that is not finite".into());
        }
        let mut bounds = Vec::with_capacity(lengths.len());
        let mut first = 0;
        for &l in lengths {
            bounds.push((first, first + l - 1));
            first += l;
        }
        Ok(PlanPlay {
            n,
            len,
            q,
            dq,
            segment_cycles: vec![(-1, -1); bounds.len()],
            bounds,
            period_s,
            max_pause_s,
            resume_accel_rad_s2,
            k: 0,
            s: 0.0,
            sigma: 1.0,
            sent_cycle: None,
            held_s: 0.0,
            repeats: 0,
            phase: Phase::Running,
            reason: String::new(),
        })
    }

    pub fn joints(&self) -> usize {
        self.n
    }

    /// Samples in the plan.
    pub fn len(&self) -> usize {
        self.len
    }

    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// The plan ends here, failed, with `why`; nothing more is sent for it.
    pub fn fail(&mut self, why: String) {
        self.phase = Phase::Failed;
        self.reason = why;
    }

    /// The command answering the state of `cycle` with `flags`: `(q, dq)` into the outputs,
    /// or false when nothing is to be sent (the plan failed, now or before).
    pub fn command(&mut self, cycle: i64, flags: u32, q: &mut [f64], dq: &mut [f64]) -> bool {
        if self.phase == Phase::Running {
            if let Some(sent) = self.sent_cycle {
                if flags & FLAG_PREV_HOLD != 0 {
                    self.repeats += 1;
                    self.held_s += self.period_s * (cycle - sent).max(1) as f64;
                    if self.held_s > self.max_pause_s {
                        self.fail(format!(
                            "the robot did not follow: the CAN driver held the plan's commands \
                             for {:.2} s at sample {} of {} (its log says why: late or \
                             out-of-range commands)",
                            self.held_s, self.k, self.len
                        ));
                        return false;
                    }
                    self.sigma = 0.0; // the arm was stopped: the plan resumes from rest
                } else {
                    self.held_s = 0.0;
                    self.advance(sent);
                }
            }
        }
        match self.phase {
            Phase::Failed => false,
            Phase::Done => {
                let last = (self.len - 1) * self.n;
                q.copy_from_slice(&self.q[last..last + self.n]);
                dq.fill(0.0);
                true
            }
            Phase::Running => {
                self.sent_cycle = Some(cycle);
                self.interpolate_q(self.s, q);
                self.interpolate_dq(self.s, dq);
                for v in dq.iter_mut() {
                    *v *= self.sigma;
                }
                true
            }
        }
    }

    /// Sample `k` was carried out in `cycle`: note segment bounds, move on.
    fn played(&mut self, cycle: i64) {
        for (seg, &(first, last)) in self.segment_cycles.iter_mut().zip(&self.bounds) {
            if self.k == first {
                seg.0 = cycle;
            }
            if self.k == last {
                seg.1 = cycle;
            }
        }
        self.k += 1;
        if self.k >= self.len {
            self.phase = Phase::Done;
        }
    }

    /// The command sent for `cycle` was carried out: every sample up to where it was is
    /// played; the next command is further along by σ, which recovers towards 1.
    fn advance(&mut self, cycle: i64) {
        while self.phase == Phase::Running && (self.k as f64) <= self.s + INDEX_TOLERANCE {
            self.played(cycle);
        }
        if self.phase != Phase::Running {
            return;
        }
        self.sigma = (self.sigma + self.sigma_step()).min(1.0);
        self.s = (self.s + self.sigma).min(self.len as f64 - 1.0);
    }

    /// How much σ may rise in one cycle: a joint's commanded velocity σ·dq rises by at most
    /// `resume_accel_rad_s2` per second.
    fn sigma_step(&self) -> f64 {
        let (i, frac) = self.place(self.s);
        let fastest = (0..self.n)
            .map(|j| self.at(&self.dq, i, frac, j).abs())
            .fold(0.0, f64::max);
        if fastest <= 0.0 {
            return 1.0;
        }
        self.period_s * self.resume_accel_rad_s2 / fastest
    }

    /// The sample below the fractional index `s` and how far past it `s` is (0: on it).
    fn place(&self, s: f64) -> (usize, f64) {
        let i = ((s + INDEX_TOLERANCE).floor().max(0.0) as usize).min(self.len - 1);
        let frac = s - i as f64;
        if i + 1 >= self.len || frac <= INDEX_TOLERANCE {
            (i, 0.0)
        } else {
            (i, frac)
        }
    }

    fn at(&self, samples: &[f64], i: usize, frac: f64, j: usize) -> f64 {
        let a = samples[i * self.n + j];
        if frac == 0.0 {
            return a;
        }
        a + frac * (samples[(i + 1) * self.n + j] - a)
    }

    fn interpolate_q(&self, s: f64, out: &mut [f64]) {
        let (i, frac) = self.place(s);
        for (j, v) in out.iter_mut().enumerate() {
            *v = self.at(&self.q, i, frac, j);
        }
    }

    fn interpolate_dq(&self, s: f64, out: &mut [f64]) {
        let (i, frac) = self.place(s);
        for (j, v) in out.iter_mut().enumerate() {
            *v = self.at(&self.dq, i, frac, j);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// One joint ramping 0..len-1 rad at 1 rad per sample, in two segments.
    fn ramp(len: usize) -> PlanPlay {
        let q: Vec<f64> = (0..len).map(|k| k as f64).collect();
        let dq = vec![1.0 / 0.01; len];
        PlanPlay::new(q, dq, 1, &[len / 2, len - len / 2], 0.01, 0.5, 2.0).unwrap()
    }

    fn play(p: &mut PlanPlay, cycles: std::ops::Range<i64>, held: &[i64]) -> Vec<f64> {
        let (mut q, mut dq) = ([0.0], [0.0]);
        let mut out = vec![];
        for c in cycles {
            let flags = if held.contains(&(c - 1)) {
                FLAG_PREV_HOLD
            } else {
                0
            };
            if p.command(c, flags, &mut q, &mut dq) {
                out.push(q[0]);
            }
        }
        out
    }

    #[test]
    fn a_plan_plays_one_sample_a_cycle_and_records_its_segments() {
        let mut p = ramp(10);
        let sent = play(&mut p, 100..115, &[]);
        assert_eq!(&sent[..10], &[0., 1., 2., 3., 4., 5., 6., 7., 8., 9.]);
        assert_eq!(p.phase, Phase::Done);
        assert!(sent[10..].iter().all(|&q| q == 9.0));
        assert_eq!(p.segment_cycles, vec![(100, 104), (105, 109)]);
    }

    #[test]
    fn a_held_sample_is_sent_again_and_the_plan_resumes_from_rest() {
        let mut p = ramp(10);
        let sent = play(&mut p, 100..103, &[101]);
        assert_eq!(sent, vec![0.0, 1.0, 1.0]); // cycle 101's sample held: sent again at 102
        assert_eq!(p.repeats, 1);
        let (mut q, mut dq) = ([0.0], [0.0]);
        assert!(p.command(103, 0, &mut q, &mut dq));
        // σ rose from 0 by period × accel / speed = 0.01 × 2 / 100 of a sample
        assert!((q[0] - 1.0002).abs() < 1e-9 && (dq[0] - 0.0002 * 100.0).abs() < 1e-9);
    }

    #[test]
    fn a_plan_held_too_long_fails_with_the_reason() {
        let mut p = ramp(10);
        let held: Vec<i64> = (100..200).collect();
        play(&mut p, 100..200, &held);
        assert_eq!(p.phase, Phase::Failed);
        assert!(p.reason.contains("did not follow") && p.reason.contains("sample 0 of 10"));
    }

    #[test]
    fn a_plan_that_does_not_add_up_is_refused() {
        assert!(PlanPlay::new(vec![0.0; 6], vec![0.0; 5], 3, &[2], 0.01, 0.5, 2.0).is_err());
        assert!(PlanPlay::new(vec![0.0; 6], vec![0.0; 6], 3, &[1], 0.01, 0.5, 2.0).is_err());
        assert!(PlanPlay::new(vec![f64::NAN; 3], vec![0.0; 3], 3, &[1], 0.01, 0.5, 2.0).is_err());
    }
}
