//! The model the control law compensates, for one state per cycle: rigid body (and payload)
//! as the chain's regressor times fixed weights, friction and effects per joint, the
//! cylinders apart. The compiled form of control/identification/point.py `PointModel` and of
//! control/declared_model.py `cycle_torques_nm`, from the table control/rt_tables.py
//! `point_model_table` writes; tests/unit/test_control_rt_model.py checks it against the
//! vectorised model (`IdentifiedModel.torque_nm`) for every friction family and effect.

use serde_json::Value;

use crate::chain::{Chain, Work, MAX_JOINTS};
use crate::cylinders::Cylinder;
use crate::effects::Effect;
use crate::friction::Friction;
use crate::table::vector;

pub const MODEL_FORMAT: &str = "leadthrough-point-model";
pub const MODEL_VERSION: i64 = 1;

/// The training envelope the friction and velocity effects are clipped to.
#[derive(Clone, Debug)]
struct Envelope {
    q_lo: Vec<f64>,
    q_hi: Vec<f64>,
    dq_lo: Vec<f64>,
    dq_hi: Vec<f64>,
}

impl Envelope {
    fn none(n: usize) -> Envelope {
        Envelope {
            q_lo: vec![f64::NEG_INFINITY; n],
            q_hi: vec![f64::INFINITY; n],
            dq_lo: vec![f64::NEG_INFINITY; n],
            dq_hi: vec![f64::INFINITY; n],
        }
    }

    fn from_json(v: &Value, n: usize) -> Result<Envelope, String> {
        let get = |k: &str| -> Result<Vec<f64>, String> {
            let x = vector(v.get(k), &format!("envelope.{k}"))?;
            if x.len() != n {
                return Err(format!("envelope.{k} must have {n} values"));
            }
            Ok(x)
        };
        Ok(Envelope {
            q_lo: get("q_min")?,
            q_hi: get("q_max")?,
            dq_lo: get("dq_min")?,
            dq_hi: get("dq_max")?,
        })
    }

    /// numpy's `clip(v, lo, hi)`: NaN stays NaN.
    fn clip(v: f64, lo: f64, hi: f64) -> f64 {
        if v < lo {
            lo
        } else if v > hi {
            hi
        } else {
            v
        }
    }
}

pub struct PointModel {
    pub chain: Chain,
    n: usize,
    /// Velocity-dependent rigid torque (Coriolis, centrifugal) counted: an identified model's
    /// regressor is evaluated at the state's velocity; a declared model's at rest.
    coriolis: bool,
    /// Per joint j, the weights of row j of the regressor: rigid_j = Y[j] · w_rigid[j].
    w_rigid: Vec<f64>,
    w_payload: Option<Vec<f64>>,
    envelope: Envelope,
    friction: Vec<Option<Friction>>,
    effects: Vec<Effect>,
    cylinders: Vec<Cylinder>,
    work: Work,
    y: Vec<f64>,
}

fn matrix(v: Option<&Value>, n: usize, what: &str) -> Result<Vec<f64>, String> {
    let rows = v
        .and_then(Value::as_array)
        .filter(|r| r.len() == n)
        .ok_or_else(|| format!("{what} must be {n} rows"))?;
    let mut out = Vec::with_capacity(n * 10 * n);
    for (k, row) in rows.iter().enumerate() {
        let r = vector(Some(row), &format!("{what}[{k}]"))?;
        if r.len() != 10 * n {
            return Err(format!("{what}[{k}] must have {} values", 10 * n));
        }
        out.extend(r);
    }
    Ok(out)
}

impl PointModel {
    pub fn from_json(t: &Value) -> Result<PointModel, String> {
        if t.get("format").and_then(Value::as_str) != Some(MODEL_FORMAT)
            || t.get("version").and_then(Value::as_i64) != Some(MODEL_VERSION)
        {
            return Err(format!(
                "point model: not a {MODEL_FORMAT} v{MODEL_VERSION} table"
            ));
        }
        let wrap = |e: String| format!("point model: {e}");
        let chain = Chain::from_json(t.get("chain").unwrap_or(&Value::Null))?;
        let n = chain.n();
        let w_rigid = matrix(t.get("w_rigid"), n, "w_rigid").map_err(wrap)?;
        let w_payload = match t.get("w_payload") {
            None | Some(Value::Null) => None,
            v => Some(matrix(v, n, "w_payload").map_err(wrap)?),
        };
        let envelope = match t.get("envelope") {
            None | Some(Value::Null) => Envelope::none(n),
            Some(v) => Envelope::from_json(v, n).map_err(wrap)?,
        };
        let items = t
            .get("friction")
            .and_then(Value::as_array)
            .filter(|f| f.len() == n)
            .ok_or_else(|| wrap(format!("friction must be {n} entries (null: none)")))?;
        let mut friction = Vec::with_capacity(n);
        for (j, f) in items.iter().enumerate() {
            friction.push(match f {
                Value::Null => None,
                v => Some(Friction::from_json(v, &format!("friction[{j}]")).map_err(wrap)?),
            });
        }
        let mut effects = Vec::new();
        for (k, e) in t
            .get("effects")
            .and_then(Value::as_array)
            .into_iter()
            .flatten()
            .enumerate()
        {
            effects.push(Effect::from_json(e, n, &format!("effects[{k}]")).map_err(wrap)?);
        }
        let mut cylinders = Vec::new();
        for (k, c) in t
            .get("cylinders")
            .and_then(Value::as_array)
            .into_iter()
            .flatten()
            .enumerate()
        {
            cylinders.push(Cylinder::from_json(c, n, &format!("cylinders[{k}]")).map_err(wrap)?);
        }
        let coriolis = t
            .get("coriolis")
            .and_then(Value::as_bool)
            .ok_or_else(|| wrap("coriolis must be true or false".into()))?;
        Ok(PointModel {
            n,
            coriolis,
            w_rigid,
            w_payload,
            envelope,
            friction,
            effects,
            cylinders,
            work: Work::default(),
            y: vec![0.0; n * 10 * n],
            chain,
        })
    }

    pub fn n(&self) -> usize {
        self.n
    }

    pub fn n_cylinders(&self) -> usize {
        self.cylinders.len()
    }

    /// Joint torque [N·m] at (q, dq) and ddq = 0 (`dq` None: at rest) into `out`: rigid body
    /// (+ payload) + friction + effects, cylinders excluded.
    pub fn torque(&mut self, q: &[f64], dq: Option<&[f64]>, out: &mut [f64]) {
        let zeros = [0.0; MAX_JOINTS];
        let dq = dq.unwrap_or(&zeros[..self.n]);
        self.regress(q, dq);
        self.combine(q, dq, out);
    }

    /// The chain's regressor at (q, dq) (at rest for a model without Coriolis) into `self.y`.
    fn regress(&mut self, q: &[f64], dq: &[f64]) {
        let zeros = [0.0; MAX_JOINTS];
        let n = self.n;
        let dq_rigid = if self.coriolis { dq } else { &zeros[..n] };
        self.chain
            .regressor(q, dq_rigid, &zeros[..n], &mut self.work, &mut self.y);
    }

    /// [`Self::torque`] at (q, dq) from the regressor in `self.y` ([`Self::regress`]).
    fn combine(&self, q: &[f64], dq: &[f64], out: &mut [f64]) {
        let n = self.n;
        let width = 10 * n;
        let mut rigid = [0.0; MAX_JOINTS];
        let mut fr = [0.0; MAX_JOINTS];
        let env = &self.envelope;
        for j in 0..n {
            let row = &self.y[j * width..(j + 1) * width];
            let w = &self.w_rigid[j * width..(j + 1) * width];
            rigid[j] = row.iter().zip(w).map(|(a, b)| a * b).sum();
            if let Some(f) = &self.friction[j] {
                let qc = Envelope::clip(q[j], env.q_lo[j], env.q_hi[j]);
                let dqc = Envelope::clip(dq[j], env.dq_lo[j], env.dq_hi[j]);
                fr[j] = f.torque(qc, dqc);
            }
            out[j] = rigid[j] + fr[j];
            if let Some(wp) = &self.w_payload {
                let w = &wp[j * width..(j + 1) * width];
                out[j] += row.iter().zip(w).map(|(a, b)| a * b).sum::<f64>();
            }
        }
        for e in &self.effects {
            let j = e.joint;
            let dqc = Envelope::clip(dq[j], env.dq_lo[j], env.dq_hi[j]);
            out[j] += e.torque(q, dqc, &rigid[..n], &fr[..n]);
        }
    }

    /// The cylinders' joint torques [N·m] at `q` with one pressure per cylinder [bar].
    pub fn cylinder_torques(&self, q: &[f64], p_bar: &[f64], out: &mut [f64]) {
        out[..self.n].fill(0.0);
        for (c, &p) in self.cylinders.iter().zip(p_bar) {
            out[c.joint] = c.torque(q[c.joint], p);
        }
    }

    /// `(static, friction)` [N·m]: the torque at rest less the cylinders', and what moving at
    /// `dq` adds to it (friction, velocity effects, Coriolis). Err names the first joint whose
    /// torque is not finite.
    pub fn cycle_torques(
        &mut self,
        q: &[f64],
        dq: &[f64],
        p_bar: &[f64],
        stat: &mut [f64],
        friction: &mut [f64],
    ) -> Result<(), String> {
        let n = self.n;
        let mut rest = [0.0; MAX_JOINTS];
        let mut cyl = [0.0; MAX_JOINTS];
        let zeros = [0.0; MAX_JOINTS];
        if self.coriolis {
            self.torque(q, None, &mut rest[..n]);
            self.torque(q, Some(dq), friction);
        } else {
            // the rigid body at rest for both: one regressor (the costliest part)
            self.regress(q, &zeros[..n]);
            self.combine(q, &zeros[..n], &mut rest[..n]);
            self.combine(q, dq, friction);
        }
        self.cylinder_torques(q, p_bar, &mut cyl[..n]);
        for j in 0..n {
            stat[j] = rest[j] - cyl[j];
            friction[j] -= rest[j];
            if !(stat[j].is_finite() && friction[j].is_finite()) {
                return Err(format!(
                    "the model's torque on joint {} is not finite",
                    j + 1
                ));
            }
        }
        Ok(())
    }
}
