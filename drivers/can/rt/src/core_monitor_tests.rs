//! The core's monitors (the core's part of test_lost_cycles.py and test_speed_monitor.py): lost
//! command cycles hold and latch, hand guiding's speed brakes.

use super::*;

fn teach(cell: &mut Cell, dq: f64) -> [f64; N] {
    cell.gateway("teaching");
    cell.tick();
    let (js, _) = cell.cycle(Spec::default());
    assert_eq!(cell.command(&js, &Q0, dq).0, Answer::Command);
    Q0
}

/// One cycle whose command never comes: the driver answers at the deadline; its answer.
fn miss(cell: &mut Cell, q: [f64; N], enabling: bool) -> Answer {
    cell.t += PERIOD_S;
    cell.gateway_io("teaching", enabling, true);
    cell.cycle(at(q));
    cell.t += 0.0021; // past the answer deadline, half the period
    cell.tick();
    cell.t -= 0.0021;
    cell.answer()
}

#[test]
fn core_the_driver_holds_and_latches_after_n_lost_cycles_until_the_cell_is_stopped() {
    let mut cell = Cell::new(|c| {
        c.lost_cycles_max_consecutive = 5;
        c.hand_guiding_max_speed_m_s = 0.0;
    });
    let q = teach(&mut cell, 0.0);
    let answers: Vec<Answer> = (0..5).map(|_| miss(&mut cell, q, true)).collect();
    assert!(answers[0] == Answer::Coast && answers[4] == Answer::Hold);
    let health = cell.health();
    assert_eq!(health["lost_cycles"], json!(5));
    assert_eq!(
        health["lost_cycles_trip"],
        json!("5 command cycles lost in a row")
    );
    assert!(cell.core.take_notes().iter().any(|(l, k, m)| *l == 40
        && k == "lost"
        && m.contains("5 command cycles lost in a row; stopping the arm")));
    cell.t += PERIOD_S;
    cell.gateway("teaching");
    let (js, frames) = cell.cycle(at(q));
    assert!(
        commands(&frames).len() == 1 && commands(&frames)[0].all_hold(),
        "held at once, no longer waiting"
    );
    assert!(
        cell.command(&js, &Q0, 0.0).0 == Answer::None
            && cell.core.rejected_for("blocked_lost") == 1
    );
    cell.t += PERIOD_S;
    cell.gateway("fault"); // the gateway faults on the trip: the cell is stopped
    cell.cycle(at(q));
    assert_eq!(cell.health()["lost_cycles_trip"], json!(null));
}

#[test]
fn core_a_link_losing_every_other_cycle_trips_the_window_rule_and_the_arm_ramps_to_rest() {
    let mut cell = Cell::new(|c| {
        c.lost_cycles_max_consecutive = 5;
        c.lost_cycles_max_per_window = 4;
        c.lost_cycles_window_s = 1.0;
        c.hand_guiding_max_speed_m_s = 0.0;
        c.stop_deceleration_rad_s2 = vec![1.0; N];
    });
    // the commands move along their path at their 0.2 rad/s (the ramp, after the lost
    // cycles, starts at the path's speed: ramp_start.rs)
    let mut q = teach(&mut cell, 0.2);
    for _ in 0..4 {
        q = plus(q, 0.2 * PERIOD_S);
        assert_eq!(miss(&mut cell, q, true), Answer::Coast);
        q = plus(q, 0.2 * PERIOD_S);
        cell.t += PERIOD_S;
        cell.gateway("teaching");
        let (js, _) = cell.cycle(at(q));
        if cell.core.lost.trip.is_none() {
            assert_eq!(cell.command(&js, &q, 0.2).0, Answer::Command);
        }
    }
    let trip = cell.health()["lost_cycles_trip"]
        .as_str()
        .unwrap()
        .to_string();
    assert!(trip.contains("4 command cycles lost within 1 s"), "{trip}");
    assert_eq!(
        cell.answer(),
        Answer::Ramp,
        "stopped as for a released enabling device"
    );
}

#[test]
fn core_blocked_cycles_are_not_lost_and_hold_answers_never_coast() {
    let mut cell = Cell::new(|c| {
        c.lost_cycles_max_consecutive = 3;
        c.lost_cycle_answer = LostCycleAnswer::Hold;
    });
    let q = teach(&mut cell, 0.2);
    assert_eq!(
        miss(&mut cell, q, true),
        Answer::Hold,
        "no extrapolation asked for"
    );
    for _ in 0..10 {
        // the enabling device released: the driver stops the arm, not lost
        miss(&mut cell, q, false);
    }
    assert!(cell.core.lost.lost == 1 && cell.core.lost.trip.is_none());
}

fn teach_and_turn_j1(cell: &mut Cell, state: &str, speed_rad_s: f64, cycles: usize) -> Vec<Answer> {
    let mut q = Q0;
    let mut answers = Vec::new();
    for _ in 0..cycles {
        cell.gateway(state);
        cell.t += PERIOD_S;
        let (js, _) = cell.cycle(at(q));
        answers.push(cell.command(&js, &q, 0.0).0);
        q[0] += speed_rad_s * PERIOD_S;
    }
    answers
}

#[test]
fn core_the_driver_brakes_once_the_arm_outruns_hand_guiding_and_clears_when_teaching_ends() {
    let mut cell = Cell::new(|_| {});
    assert!(cell.core.speed.is_some());
    let answers = teach_and_turn_j1(&mut cell, "teaching", 0.05, 20); // a slow turn
    assert!(answers.iter().all(|&a| a == Answer::Command));
    let health = cell.health();
    let peak = health["speed_peak_m_s"].as_f64().unwrap();
    assert!(
        health["speed_trip"].is_null() && 0.0 < peak && peak < 0.25,
        "{peak}"
    );
    let answers = teach_and_turn_j1(&mut cell, "teaching", 1.0, 20); // the tool at 1 m/s
    assert!(
        answers[..3].iter().all(|&a| a == Answer::Command)
            && answers[6..].iter().all(|&a| a == Answer::None),
        "{answers:?}"
    );
    assert!(cell.core.rejected_for("blocked_speed") >= 14);
    let mut here = [0.0; N];
    here.copy_from_slice(cell.core.feedback.unwrap().q()); // where the turn has got the arm
    let (_, frames) = cell.cycle(at(here)); // a tripped driver holds every cycle at once
    let held = commands(&frames);
    assert!(held.len() == 1 && held[0].all_hold() && held[0].dq.iter().all(|&v| v == 0.0));
    assert_eq!(cell.answer(), Answer::Hold);
    assert!(cell.health()["speed_trip"]
        .as_str()
        .unwrap()
        .contains("mm/s"));
    // the brakes, not a rigid hold the hand outrunning it would fight into a power cut
    assert_eq!(cell.core.desired_request(cell.t), HostRequest::Brake);
    cell.gateway("fault"); // the gateway faults on the trip...
    cell.cycle(at(here));
    assert_eq!(cell.health()["speed_trip"], json!(null)); // ...which clears it for a reset
}

#[test]
fn core_identification_runs_faster_than_hand_guiding_unmonitored() {
    let mut cell = Cell::new(|_| {});
    let answers = teach_and_turn_j1(&mut cell, "identifying", 1.0, 20);
    assert!(answers.iter().all(|&a| a == Answer::Command));
    assert_eq!(cell.health()["speed_trip"], json!(null));
}

#[test]
fn core_no_monitor_when_the_limit_is_zero_and_a_limit_needs_the_kinematics() {
    assert!(Cell::new(|c| c.hand_guiding_max_speed_m_s = 0.0)
        .core
        .speed
        .is_none());
    let err = HostCore::new(
        CoreConfig::default(),
        Box::new(FakeAdapter::new(N, None)),
        0.1,
        None,
        None,
        limits(),
    )
    .err()
    .unwrap();
    assert!(err.contains("hand_guiding_max_speed_m_s"), "{err}");
}
