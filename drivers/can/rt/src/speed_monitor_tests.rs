//! The speed monitor's tests (speed_monitor.rs): trips on a toy arm, and the kinematic chain
//! checked by hand and against the datasheet robot's points.

use super::*;

const PERIOD_S: f64 = 0.004;

/// A toy arm (test_speed_monitor.py `_points`): the tool point is q[:3], the flange
/// q[:3] + q[3:].
#[derive(Debug)]
struct Toy;

impl Points for Toy {
    fn points(&self, q: &[f64], out: &mut [[f64; 3]; 2]) {
        out[0] = [q[0], q[1], q[2]];
        out[1] = [q[0] + q[3], q[1] + q[4], q[2] + q[5]];
    }
}

fn run(monitor: &mut SpeedMonitor<Toy>, velocity: [f64; 6], cycles: i64) -> Option<SpeedTrip> {
    let mut trip = None;
    for k in 0..cycles {
        let q: Vec<f64> = velocity.iter().map(|v| v * k as f64 * PERIOD_S).collect();
        trip = monitor.update(k, &q, PERIOD_S);
    }
    trip
}

fn close(a: f64, b: f64) -> bool {
    (a - b).abs() <= 1e-6 * b.abs().max(1e-12)
}

#[test]
fn a_tool_over_the_limit_trips_and_one_under_it_does_not() {
    let mut monitor = SpeedMonitor::new(Toy, 0.25, 3, 2).unwrap();
    assert_eq!(run(&mut monitor, [0.0, 0.24, 0.0, 0.0, 0.0, 0.0], 50), None);
    assert!(close(monitor.peak_m_s, 0.24));
    monitor.reset();
    let trip = run(&mut monitor, [0.0, 0.18, 0.18, 0.0, 0.0, 0.0], 50).unwrap(); // 0.255
    assert_eq!((trip.point, trip.cycle), ("tool", 4));
    assert!(close(trip.speed_m_s, 0.18 * 2f64.sqrt()));
    assert_eq!(
        trip.message(),
        "the tool moved at 255 mm/s (measured positions, cycle 4), over hand guiding's 250 \
         mm/s"
    );
}

#[test]
fn the_flange_is_watched_too_when_the_tool_turns_about_its_point() {
    let mut monitor = SpeedMonitor::new(Toy, 0.25, DEFAULT_WINDOW, DEFAULT_CONFIRM).unwrap();
    let trip = run(&mut monitor, [0.0, 0.0, 0.0, 0.3, 0.0, 0.0], 20).unwrap();
    assert_eq!(trip.point, "flange");
}

#[test]
fn a_single_cycle_over_the_limit_is_not_a_trip_and_a_gap_is_no_speed() {
    let mut monitor = SpeedMonitor::new(Toy, 0.25, 1, 2).unwrap();
    let q = [0.0; 6];
    monitor.update(0, &q, PERIOD_S);
    let mut jump = q;
    jump[0] = 0.002; // 0.5 m/s for one cycle (an encoder glitch), then still
    assert_eq!(monitor.update(1, &jump, PERIOD_S), None);
    assert_eq!(monitor.update(2, &jump, PERIOD_S), None);
    monitor.gap();
    let mut far = jump;
    far[0] = 1.0; // where the arm is after the controller stopped servoing: not a speed
    assert_eq!(monitor.update(40, &far, PERIOD_S), None);
    assert_eq!(monitor.update(41, &far, PERIOD_S), None);
}

#[test]
fn a_trip_stays_until_reset() {
    let mut monitor = SpeedMonitor::new(Toy, 0.25, DEFAULT_WINDOW, DEFAULT_CONFIRM).unwrap();
    assert!(run(&mut monitor, [1.0, 0.0, 0.0, 0.0, 0.0, 0.0], 10).is_some());
    assert!(monitor.update(100, &[0.0; 6], PERIOD_S).is_some());
    monitor.reset();
    assert!(monitor.trip.is_none() && monitor.update(101, &[0.0; 6], PERIOD_S).is_none());
}

#[test]
fn a_cycle_count_that_goes_back_starts_the_history_again_and_nonsense_is_refused() {
    let mut monitor = SpeedMonitor::new(Toy, 0.25, 1, 1).unwrap();
    assert_eq!(monitor.update(10, &[0.0; 6], PERIOD_S), None);
    let far = [1.0, 0.0, 0.0, 0.0, 0.0, 0.0];
    assert_eq!(monitor.update(5, &far, PERIOD_S), None, "a new link");
    assert!(
        monitor.update(6, &[0.0; 6], PERIOD_S).is_some(),
        "then measured"
    );
    let closure = |q: &[f64], out: &mut [[f64; 3]; 2]| Toy.points(q, out);
    let mut monitor = SpeedMonitor::new(closure, 0.25, 1, 1).unwrap();
    assert_eq!(monitor.update(0, &[0.0; 6], PERIOD_S), None);
    assert!(
        monitor.update(1, &far, PERIOD_S).is_some(),
        "a closure is a Points"
    );
    assert!(SpeedMonitor::new(Toy, 0.0, 3, 2)
        .unwrap_err()
        .contains("speed limit"));
    assert!(SpeedMonitor::new(Toy, f64::NAN, 3, 2).is_err());
    assert!(SpeedMonitor::new(Toy, 0.25, 0, 2)
        .unwrap_err()
        .contains("window"));
}

/// Two links in the xy plane, 1 m and then the tool 0.5 m out and 0.2 m up: checked by
/// hand.
fn two_links(second: Value) -> Value {
    serde_json::json!({
        "format": CHAIN_FORMAT,
        "version": 1,
        "joints": [
            {"name": "a", "parent_T_joint": [[1.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0],
                                             [0.0, 0.0, 1.0, 0.0], [0.0, 0.0, 0.0, 1.0]],
             "axis": [0.0, 0.0, 1.0]},
            second,
        ],
        "tool_m": [0.5, 0.0, 0.2],
        "flange_m": [0.0, 0.0, 0.0],
    })
}

fn assert_points(chain: &KinematicChain, q: &[f64], tool: [f64; 3], flange: [f64; 3]) {
    let mut out = [[0.0; 3]; 2];
    chain.points(q, &mut out);
    for (got, want) in out.iter().zip([tool, flange]) {
        for (g, w) in got.iter().zip(want) {
            assert!(
                (g - w).abs() < 1e-12,
                "{q:?}: {out:?}, want {tool:?} {flange:?}"
            );
        }
    }
}

#[test]
fn a_two_link_chain_checked_by_hand() {
    let matrix = serde_json::json!({"parent_T_joint": [
        [1.0, 0.0, 0.0, 1.0], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0],
        [0.0, 0.0, 0.0, 1.0]], "axis": [0.0, 0.0, 1.0]});
    let chain = KinematicChain::from_json(&two_links(matrix)).unwrap();
    assert_eq!(chain.n_joints(), 2);
    let half = std::f64::consts::FRAC_PI_2;
    assert_points(&chain, &[0.0, 0.0], [1.5, 0.0, 0.2], [1.0, 0.0, 0.0]);
    assert_points(&chain, &[half, half], [-0.5, 1.0, 0.2], [0.0, 1.0, 0.0]);
    assert_points(&chain, &[0.0, -half], [1.0, -0.5, 0.2], [1.0, 0.0, 0.0]);
    // the same placement as a URDF origin, the second joint turning about x
    let urdf = serde_json::json!({"xyz": [1.0, 0.0, 0.0], "rpy": [0.0, 0.0, 0.0],
                                  "axis": [1.0, 0.0, 0.0]});
    let chain = KinematicChain::from_json(&two_links(urdf)).unwrap();
    assert_points(&chain, &[0.0, half], [1.5, -0.2, 0.0], [1.0, 0.0, 0.0]);
    assert_points(&chain, &[half, half], [0.2, 1.5, 0.0], [0.0, 1.0, 0.0]);
    // rpy: yaw 90° places the second body turned about z
    let yawed = serde_json::json!({"xyz": [1.0, 0.0, 0.0], "rpy": [0.0, 0.0, half],
                                   "axis": [0.0, 0.0, 1.0]});
    let chain = KinematicChain::from_json(&two_links(yawed)).unwrap();
    assert_points(&chain, &[0.0, 0.0], [1.0, 0.5, 0.2], [1.0, 0.0, 0.0]);
}

#[test]
fn a_bad_table_is_refused_naming_what_is_wrong() {
    let good = serde_json::json!({"parent_T_joint": [
        [1.0, 0.0, 0.0, 1.0], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0],
        [0.0, 0.0, 0.0, 1.0]], "axis": [0.0, 0.0, 1.0], "name": "b"});
    let err = |edit: &dyn Fn(&mut Value)| {
        let mut table = two_links(good.clone());
        edit(&mut table);
        KinematicChain::from_json(&table).unwrap_err()
    };
    assert!(err(&|t| t["format"] = "other".into()).contains("format"));
    assert!(err(&|t| t["version"] = 2.into()).contains("version 2"));
    assert!(err(&|t| t["joints"] = serde_json::json!([])).contains("joints"));
    assert!(err(&|t| t["tool_m"] = serde_json::json!([0.0, 1.0])).contains("tool_m"));
    assert!(
        err(&|t| t["joints"][1]["axis"] = serde_json::json!([0.0, 0.0, 2.0])).contains("b axis")
    );
    assert!(
        err(&|t| t["joints"][1]["parent_T_joint"][0][0] = 2.0.into()).contains("not a rotation")
    );
    assert!(err(&|t| t["joints"][1]["parent_T_joint"][3][0] = 1.0.into()).contains("last row"));
    assert!(err(&|t| t["joints"][1]["parent_T_joint"][1][3] = Value::Null).contains("finite"));
    // a mirror is no rotation either
    assert!(
        err(&|t| t["joints"][1]["parent_T_joint"][2][2] = (-1.0).into()).contains("not a rotation")
    );
}

/// drivers/can/rt_kinematics.py `json.dumps(chain_table())` of the datasheet robot.
const DATASHEET_CHAIN: &str = r#"{"format": "leadthrough-kinematic-chain", "version": 1,
        "joints": [{"name": "j1", "parent_T_joint": [[1.0, -0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0],
        [0.0, 0.0, 1.0, 0.0], [0.0, 0.0, 0.0, 1.0]], "axis": [0.0, 0.0, 1.0]}, {"name": "j2",
        "parent_T_joint": [[-0.0066671083490985675, -0.9999777745861462, 0.0, 0.002402],
        [6.123097904327087e-17, -4.0824264496460774e-19, -1.0, 0.0], [0.9999777745861462,
        -0.0066671083490985675, 6.123233995736766e-17, 0.769], [0.0, 0.0, 0.0, 1.0]], "axis":
        [0.0, 0.0, 1.0]}, {"name": "j3", "parent_T_joint": [[0.033277284019626784,
        0.9994461578135548, 0.0, 0.900073], [-0.9994461578135548, 0.033277284019626784, 0.0,
        0.0], [0.0, 0.0, 1.0, 0.001177], [0.0, 0.0, 0.0, 1.0]], "axis": [0.0, 0.0, 1.0]},
        {"name": "j4", "parent_T_joint": [[0.9999944436310999, -0.0033335726971088935, 0.0,
        1.1008], [0.0033335726971088935, 0.9999944436310999, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0],
        [0.0, 0.0, 0.0, 1.0]], "axis": [0.0, 0.0, 1.0]}, {"name": "j5", "parent_T_joint":
        [[0.015986534925356042, -0.9998722071850384, 0.0, 0.0], [6.122451490427783e-17,
        9.788929412897324e-19, -1.0, 0.0], [0.9998722071850384, 0.015986534925356042,
        6.123233995736766e-17, 0.0], [0.0, 0.0, 0.0, 1.0]], "axis": [0.0, 0.0, 1.0]}, {"name":
        "j6", "parent_T_joint": [[1.0, 0.0, 0.0, 0.0], [0.0, 6.123233995736766e-17, -1.0, 0.0],
        [0.0, 1.0, 6.123233995736766e-17, 0.112981], [0.0, 0.0, 0.0, 1.0]], "axis": [0.0, 0.0,
        1.0]}], "tool_m": [0.0, 0.0, 0.2268], "flange_m": [0.0, 0.0, 0.07680000000000001]}"#;

#[test]
fn the_datasheet_chain_gives_what_datasheet_points_gives() {
    // q -> (tool, flange) of drivers/can/speed_monitor.py datasheet_points()(np.array(q))
    // (pinocchio on the URDF), printed with repr(tool.tolist()), repr(flange.tolist())
    let golden: [([f64; 6], [f64; 3], [f64; 3]); 4] = [
        (
            [0.0; 6],
            [1.327770148331557, 0.002448746121071291, 1.6099562527779112],
            [1.1779297912867452, 5.076588226783857e-05, 1.60346648456497],
        ),
        (
            [0.1, -0.2, 0.3, -0.4, 0.5, -0.6],
            [1.4343597828300583, 0.036665286332697375, 1.6456096007008236],
            [1.2996137398243184, 0.09329626255557491, 1.6793206734565103],
        ),
        (
            [1.0, 0.5, -1.2, 2.0, -0.7, 3.0],
            [0.19119886353274404, 0.5711142004639251, 1.0222473680899924],
            [0.2602539946483358, 0.49644028004245433, 0.9119967695632892],
        ),
        (
            [-2.5, 1.1, 0.9, -1.5, 1.9, -2.2],
            [0.9129144682969446, 0.9527586105530019, 2.0209333472066318],
            [0.9666217828585706, 0.8147561578743752, 2.0448257605895854],
        ),
    ];
    let table: Value = serde_json::from_str(DATASHEET_CHAIN).unwrap();
    let chain = KinematicChain::from_json(&table).unwrap();
    assert_eq!(chain.n_joints(), 6);
    assert_eq!(chain.names, ["j1", "j2", "j3", "j4", "j5", "j6"]);
    let mut out = [[0.0; 3]; 2];
    for (q, tool, flange) in golden {
        chain.points(&q, &mut out);
        for (got, want) in out.iter().zip([tool, flange]) {
            for (g, w) in got.iter().zip(want) {
                assert!((g - w).abs() < 1e-9, "{q:?}: {g} != {w}");
            }
        }
    }
    // test_speed_monitor.py test_the_datasheet_points_put_the_flange_behind_the_tool
    chain.points(&[0.1, -0.2, 0.3, -0.4, 0.5, -0.6], &mut out);
    let gap = norm3(&[
        out[0][0] - out[1][0],
        out[0][1] - out[1][1],
        out[0][2] - out[1][2],
    ]);
    assert!(0.05 < gap && gap < 1.0);
    // the datasheet's chain in the monitor: a turn of J1 at 1 rad/s trips it
    let mut monitor = SpeedMonitor::new(chain, 0.25, DEFAULT_WINDOW, DEFAULT_CONFIRM).unwrap();
    let mut trip = None;
    for k in 0..10 {
        let q = [0.1 + k as f64 * PERIOD_S, -0.2, 0.3, -0.4, 0.5, -0.6];
        trip = monitor.update(k, &q, PERIOD_S);
    }
    let trip = trip.unwrap();
    assert!(trip.speed_m_s > 1.0 && trip.message().contains("mm/s"));
}
