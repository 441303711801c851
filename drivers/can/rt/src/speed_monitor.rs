//! Hand guiding's speed monitor in the CAN driver (drivers/can/speed_monitor.py, issue 10),
//! independent of the control law.
//!
//! ISO 10218-1 allows hand guiding at up to 250 mm/s at the tool. This monitor checks what the
//! arm *did*, from the measured joint positions of every cycle, with its own kinematics (the
//! datasheet's, as a [`KinematicChain`] built from the table drivers/can/rt_kinematics.py
//! makes) and no input from the control process.
//!
//! Per cycle, the speed of the tool point and of the flange is the distance each travelled over
//! the last `window` cycles over that time (the controller's cycle period): positions, not the
//! drives' velocities, and a window long enough that an encoder step does not read as a speed.
//! The monitor trips when one point is faster than the limit in `confirm` consecutive cycles;
//! the trip names the point, its speed and the limit, and stays until
//! [`SpeedMonitor::reset`].

use serde_json::Value;

use crate::adapter::MAX_JOINTS;

/// The table format [`KinematicChain::from_json`] reads (drivers/can/rt_kinematics.py).
pub const CHAIN_FORMAT: &str = "leadthrough-kinematic-chain";
pub const CHAIN_VERSION: i64 = 1;
/// Python's default `window` [cycles].
pub const DEFAULT_WINDOW: usize = 3;
/// Python's default `confirm` [cycles].
pub const DEFAULT_CONFIRM: usize = 2;

type Mat3 = [[f64; 3]; 3];
type Vec3 = [f64; 3];

fn mat_mul(a: &Mat3, b: &Mat3) -> Mat3 {
    let mut out = [[0.0; 3]; 3];
    for (i, row) in out.iter_mut().enumerate() {
        for (j, v) in row.iter_mut().enumerate() {
            *v = a[i][0] * b[0][j] + a[i][1] * b[1][j] + a[i][2] * b[2][j];
        }
    }
    out
}

fn mat_vec(a: &Mat3, v: &Vec3) -> Vec3 {
    [
        a[0][0] * v[0] + a[0][1] * v[1] + a[0][2] * v[2],
        a[1][0] * v[0] + a[1][1] * v[1] + a[1][2] * v[2],
        a[2][0] * v[0] + a[2][1] * v[1] + a[2][2] * v[2],
    ]
}

/// The turn by `angle` [rad] about the unit `axis`: `c·I + s·[a]× + (1 − c)·a·aᵀ`.
fn axis_rotation(axis: &Vec3, angle: f64) -> Mat3 {
    let (s, c) = angle.sin_cos();
    let [x, y, z] = *axis;
    let t = 1.0 - c;
    [
        [c + t * x * x, t * x * y - s * z, t * x * z + s * y],
        [t * x * y + s * z, c + t * y * y, t * y * z - s * x],
        [t * x * z - s * y, t * y * z + s * x, c + t * z * z],
    ]
}

/// URDF's roll-pitch-yaw: `Rz(yaw) · Ry(pitch) · Rx(roll)`.
fn rpy_rotation(rpy: &Vec3) -> Mat3 {
    let rx = axis_rotation(&[1.0, 0.0, 0.0], rpy[0]);
    let ry = axis_rotation(&[0.0, 1.0, 0.0], rpy[1]);
    let rz = axis_rotation(&[0.0, 0.0, 1.0], rpy[2]);
    mat_mul(&rz, &mat_mul(&ry, &rx))
}

fn norm3(v: &Vec3) -> f64 {
    (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt()
}

/// `n` finite numbers of a JSON array named `what`.
fn numbers<const N: usize>(value: Option<&Value>, what: &str) -> Result<[f64; N], String> {
    let items = value
        .and_then(Value::as_array)
        .filter(|a| a.len() == N)
        .ok_or_else(|| format!("kinematic chain: {what} must be {N} numbers"))?;
    let mut out = [0.0; N];
    for (o, item) in out.iter_mut().zip(items) {
        *o = item
            .as_f64()
            .filter(|v| v.is_finite())
            .ok_or_else(|| format!("kinematic chain: {what} must be {N} finite numbers"))?;
    }
    Ok(out)
}

/// One revolute joint of a [`KinematicChain`].
#[derive(Clone, Debug, PartialEq)]
struct ChainJoint {
    /// the joint's body in its parent's at q = 0: rotation, origin [m]
    rotation: Mat3,
    origin_m: Vec3,
    /// the joint axis in its body (unit)
    axis: Vec3,
}

/// Tool point and flange from the joint positions (Python's `Points` callable): the speed
/// monitor's kinematics, so the toy arms of the tests can stand in for the datasheet's.
pub trait Points {
    /// The tool point (`out[0]`) and the flange (`out[1]`) in the world [m] at `q` [rad].
    fn points(&self, q: &[f64], out: &mut [[f64; 3]; 2]);
}

/// Any `Fn(q, out)` is a [`Points`] (a toy arm in a test; `Box<dyn Fn ...>` too).
impl<F: Fn(&[f64], &mut [[f64; 3]; 2])> Points for F {
    fn points(&self, q: &[f64], out: &mut [[f64; 3]; 2]) {
        self(q, out)
    }
}

/// A serial chain of revolute joints with a tool point and a flange in its last body: the
/// datasheet's kinematics as drivers/can/rt_kinematics.py `chain_table` gives them (module
/// docs there). Built once; [`KinematicChain::points`] never allocates.
#[derive(Clone, Debug, PartialEq)]
pub struct KinematicChain {
    joints: Vec<ChainJoint>,
    /// names of the joints, for messages
    pub names: Vec<String>,
    /// the tool point in the last body [m]
    pub tool_m: [f64; 3],
    /// the flange in the last body [m]
    pub flange_m: [f64; 3],
}

impl KinematicChain {
    /// The chain of a `chain_table` dict: `format`, `version`, `joints` (each `axis` and
    /// either `parent_T_joint`, a 4x4 row-major homogeneous transform [m], or `xyz` [m] and
    /// `rpy` [rad] as a URDF origin), `tool_m`, `flange_m`. Err names what is wrong.
    pub fn from_json(table: &Value) -> Result<KinematicChain, String> {
        let obj = table
            .as_object()
            .ok_or("kinematic chain: the table must be a JSON object")?;
        if obj.get("format").and_then(Value::as_str) != Some(CHAIN_FORMAT) {
            return Err(format!("kinematic chain: format is not {CHAIN_FORMAT:?}"));
        }
        if obj.get("version").and_then(Value::as_i64) != Some(CHAIN_VERSION) {
            return Err(format!(
                "kinematic chain: version {}, this driver reads {CHAIN_VERSION}",
                obj.get("version").unwrap_or(&Value::Null)
            ));
        }
        let items = obj
            .get("joints")
            .and_then(Value::as_array)
            .filter(|j| (1..=MAX_JOINTS).contains(&j.len()))
            .ok_or_else(|| format!("kinematic chain: joints must be a list of 1..{MAX_JOINTS}"))?;
        let mut joints = Vec::with_capacity(items.len());
        let mut names = Vec::with_capacity(items.len());
        for (k, item) in items.iter().enumerate() {
            let name = item
                .get("name")
                .and_then(Value::as_str)
                .map_or_else(|| format!("joint {}", k + 1), str::to_string);
            let what = |field: &str| format!("{name} {field}");
            let (rotation, origin_m) = match item.get("parent_T_joint") {
                Some(m) => {
                    let rows = m.as_array().filter(|r| r.len() == 4).ok_or_else(|| {
                        format!("kinematic chain: {} must be 4x4", what("parent_T_joint"))
                    })?;
                    let mut r = [[0.0; 4]; 4];
                    for (i, row) in rows.iter().enumerate() {
                        r[i] = numbers::<4>(Some(row), &what("parent_T_joint row"))?;
                    }
                    if r[3] != [0.0, 0.0, 0.0, 1.0] {
                        return Err(format!(
                            "kinematic chain: {}'s last row is not 0 0 0 1",
                            what("parent_T_joint")
                        ));
                    }
                    let rot = [
                        [r[0][0], r[0][1], r[0][2]],
                        [r[1][0], r[1][1], r[1][2]],
                        [r[2][0], r[2][1], r[2][2]],
                    ];
                    (rot, [r[0][3], r[1][3], r[2][3]])
                }
                None => {
                    let xyz = numbers::<3>(item.get("xyz"), &what("xyz"))?;
                    let rpy = numbers::<3>(item.get("rpy"), &what("rpy"))?;
                    (rpy_rotation(&rpy), xyz)
                }
            };
            // a rotation: R·Rᵀ = I and det R = +1
            let rrt = mat_mul(
                &rotation,
                &[
                    [rotation[0][0], rotation[1][0], rotation[2][0]],
                    [rotation[0][1], rotation[1][1], rotation[2][1]],
                    [rotation[0][2], rotation[1][2], rotation[2][2]],
                ],
            );
            let det = rotation[0][0]
                * (rotation[1][1] * rotation[2][2] - rotation[1][2] * rotation[2][1])
                - rotation[0][1]
                    * (rotation[1][0] * rotation[2][2] - rotation[1][2] * rotation[2][0])
                + rotation[0][2]
                    * (rotation[1][0] * rotation[2][1] - rotation[1][1] * rotation[2][0]);
            let orthonormal = (0..3)
                .all(|i| (0..3).all(|j| (rrt[i][j] - if i == j { 1.0 } else { 0.0 }).abs() < 1e-9));
            if !orthonormal || det <= 0.0 {
                return Err(format!(
                    "kinematic chain: {}'s rotation is not a rotation",
                    what("parent_T_joint")
                ));
            }
            let axis = numbers::<3>(item.get("axis"), &what("axis"))?;
            let length = norm3(&axis);
            if (length - 1.0).abs() > 1e-6 {
                return Err(format!(
                    "kinematic chain: {} has length {length}, not 1",
                    what("axis")
                ));
            }
            let axis = [axis[0] / length, axis[1] / length, axis[2] / length];
            joints.push(ChainJoint {
                rotation,
                origin_m,
                axis,
            });
            names.push(name);
        }
        Ok(KinematicChain {
            joints,
            names,
            tool_m: numbers::<3>(obj.get("tool_m"), "tool_m")?,
            flange_m: numbers::<3>(obj.get("flange_m"), "flange_m")?,
        })
    }

    /// Joints of the chain: the length of the `q` [`KinematicChain::points`] takes.
    pub fn n_joints(&self) -> usize {
        self.joints.len()
    }

    /// The tool point (`out[0]`) and the flange (`out[1]`) in the world [m] at the joint
    /// positions `q` [rad], one per joint (Python's `datasheet_points(desc)(q)`). A missing
    /// angle reads as 0 and extra ones are ignored: the caller checks the joint count against
    /// [`KinematicChain::n_joints`] once, at construction.
    pub fn points(&self, q: &[f64], out: &mut [[f64; 3]; 2]) {
        let mut rotation: Mat3 = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];
        let mut origin: Vec3 = [0.0; 3];
        for (k, joint) in self.joints.iter().enumerate() {
            let step = mat_vec(&rotation, &joint.origin_m);
            for (o, s) in origin.iter_mut().zip(step) {
                *o += s;
            }
            let angle = q.get(k).copied().unwrap_or(0.0);
            rotation = mat_mul(
                &mat_mul(&rotation, &joint.rotation),
                &axis_rotation(&joint.axis, angle),
            );
        }
        for (o, local) in out.iter_mut().zip([&self.tool_m, &self.flange_m]) {
            let v = mat_vec(&rotation, local);
            *o = [origin[0] + v[0], origin[1] + v[1], origin[2] + v[2]];
        }
    }
}

impl Points for KinematicChain {
    fn points(&self, q: &[f64], out: &mut [[f64; 3]; 2]) {
        KinematicChain::points(self, q, out);
    }
}

/// Why the monitor tripped.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SpeedTrip {
    /// "tool" or "flange"
    pub point: &'static str,
    /// its speed over the window [m/s]
    pub speed_m_s: f64,
    /// hand guiding's limit [m/s]
    pub limit_m_s: f64,
    pub cycle: i64,
}

impl SpeedTrip {
    pub fn message(&self) -> String {
        format!(
            "the {} moved at {:.0} mm/s (measured positions, cycle {}), over hand guiding's \
             {:.0} mm/s",
            self.point,
            self.speed_m_s * 1e3,
            self.cycle,
            self.limit_m_s * 1e3
        )
    }
}

/// One cycle the monitor keeps: (cycle, tool [m], flange [m]).
type Sample = (i64, [f64; 3], [f64; 3]);

/// The monitor of the module docs: [`SpeedMonitor::update`] once per cycle while it
/// applies, [`SpeedMonitor::reset`] when it does not (the positions before a gap are no
/// speed). Its history is a ring allocated at construction: nothing per cycle allocates.
#[derive(Clone, Debug)]
pub struct SpeedMonitor<P: Points = KinematicChain> {
    /// the kinematics: tool point and flange of q
    pub points: P,
    /// hand guiding's limit [m/s]
    pub limit_m_s: f64,
    /// cycles the speed is measured over
    pub window: usize,
    /// cycles in a row over the limit that trip
    pub confirm: usize,
    /// the latched trip
    pub trip: Option<SpeedTrip>,
    /// the fastest point speed seen since the last reset [m/s]
    pub peak_m_s: f64,
    /// the newest window + 1 cycles, oldest at `head`
    history: Vec<Sample>,
    head: usize,
    len: usize,
    over: usize,
}

impl<P: Points> SpeedMonitor<P> {
    /// A monitor of `points` at `limit_m_s` [m/s] over `window` cycles, tripping after
    /// `confirm` cycles (Python's defaults: [`DEFAULT_WINDOW`], [`DEFAULT_CONFIRM`]). Err
    /// (Python's ValueError) for a limit not > 0 or a window or confirm below 1.
    pub fn new(
        points: P,
        limit_m_s: f64,
        window: usize,
        confirm: usize,
    ) -> Result<SpeedMonitor<P>, String> {
        if !(limit_m_s.is_finite() && limit_m_s > 0.0) {
            return Err(format!(
                "speed limit {} m/s must be > 0",
                crate::messages::py_repr(limit_m_s)
            ));
        }
        if window < 1 || confirm < 1 {
            return Err(format!(
                "window {window} and confirm {confirm} must be >= 1 cycle"
            ));
        }
        Ok(SpeedMonitor {
            points,
            limit_m_s,
            window,
            confirm,
            trip: None,
            peak_m_s: 0.0,
            history: vec![(0, [0.0; 3], [0.0; 3]); window + 1],
            head: 0,
            len: 0,
            over: 0,
        })
    }

    /// A cycle the monitor does not see (the controller not servoing): forget the positions,
    /// keep a trip.
    pub fn gap(&mut self) {
        self.len = 0;
        self.head = 0;
        self.over = 0;
    }

    /// Forget the positions and clear a trip.
    pub fn reset(&mut self) {
        self.gap();
        self.trip = None;
        self.peak_m_s = 0.0;
    }

    /// Take the measured positions `q_rad` [rad] of `cycle` at the cycle period `period_s`
    /// [s]; returns the trip (new or standing).
    pub fn update(&mut self, cycle: i64, q_rad: &[f64], period_s: f64) -> Option<SpeedTrip> {
        if self.trip.is_some() {
            return self.trip;
        }
        let mut p = [[0.0; 3]; 2];
        self.points.points(q_rad, &mut p);
        let cap = self.history.len();
        if self.len > 0 && cycle <= self.history[(self.head + self.len - 1) % cap].0 {
            self.gap_history(); // the cycle count went back: a new link
        }
        if self.len == cap {
            self.head = (self.head + 1) % cap;
            self.len -= 1;
        }
        self.history[(self.head + self.len) % cap] = (cycle, p[0], p[1]);
        self.len += 1;
        let (first_cycle, first_tool, first_flange) = self.history[self.head];
        let span = (cycle - first_cycle) as f64 * period_s;
        if self.len <= self.window || span <= 0.0 || !span.is_finite() {
            return None;
        }
        let distance = |a: &[f64; 3], b: &[f64; 3]| norm3(&[a[0] - b[0], a[1] - b[1], a[2] - b[2]]);
        let v_tool = distance(&p[0], &first_tool) / span;
        let v_flange = distance(&p[1], &first_flange) / span;
        let (point, speed) = if v_tool >= v_flange {
            ("tool", v_tool)
        } else {
            ("flange", v_flange)
        };
        // Python's max(peak, speed): speed only if it is greater
        if speed > self.peak_m_s {
            self.peak_m_s = speed;
        }
        if speed > self.limit_m_s {
            self.over += 1;
            if self.over >= self.confirm {
                self.trip = Some(SpeedTrip {
                    point,
                    speed_m_s: speed,
                    limit_m_s: self.limit_m_s,
                    cycle,
                });
            }
        } else {
            self.over = 0;
        }
        self.trip
    }

    /// Python's `history.clear()` on a cycle count that went back (the run over the limit
    /// stays, as there).
    fn gap_history(&mut self) {
        self.len = 0;
        self.head = 0;
    }
}

#[cfg(test)]
#[path = "speed_monitor_tests.rs"]
mod tests;
