//! The core stopping the arm (test_can_core.py, continued): the closing frames, the controlled
//! stop's ramp, the standstill monitor, the driver's joint limits, the lifecycle's order and the
//! bus faults that latch.

use super::*;

#[test]
fn core_closing_frames_brake_first_then_hold_the_waiting_cycle() {
    let mut cell = Cell::new(|_| {});
    cell.gateway("teaching");
    cell.cycle(Spec::default());
    let mut out = Vec::new();
    cell.core.closing_frames(&mut out);
    let sent: Vec<Sent> = out.iter().map(decode).collect();
    assert_eq!(sent[0], Sent::Request(HostRequest::Brake as u8));
    let sets = commands(&sent[1..]);
    assert!(sets.len() == 1 && sets[0].all_hold() && sent.len() == 1 + N);
    assert_eq!(cell.core.request_sent, Some(HostRequest::Brake));
}

/// Teach: one command moving every joint at `dq` from Q0; the position it sent.
fn moving(cell: &mut Cell, dq: f64) -> [f64; N] {
    cell.gateway("teaching");
    cell.tick();
    let (js, _) = cell.cycle(Spec::default());
    assert_eq!(cell.command(&js, &Q0, dq).0, Answer::Command);
    Q0
}

/// `cycles` cycles, the gateway announcing `state` each, the measured position the last
/// command sent (a drive following it); the command sets answered at once.
fn follow(
    cell: &mut Cell,
    state: &str,
    cycles: usize,
    q: [f64; N],
    enabling: bool,
    estop_ok: bool,
) -> Vec<Set> {
    let mut q = q;
    let mut sets = Vec::new();
    for _ in 0..cycles {
        cell.t += PERIOD_S;
        cell.gateway_io(state, enabling, estop_ok);
        let (_, frames) = cell.cycle(at(q));
        if let Some(set) = commands(&frames).pop() {
            q.copy_from_slice(&set.q);
            sets.push(set);
        }
    }
    sets
}

#[test]
fn core_releasing_the_enabling_device_ramps_the_command_to_standstill_then_holds() {
    // Stop category 2: the velocity falls linearly to zero in |dq| / deceleration (0.2 rad/s
    // at 1 rad/s²: 0.2 s, 50 cycles of 4 ms) along the last command's path, then a hold at
    // the ramp's end, dq·T/2 = 20 mrad further on.
    let mut cell = Cell::new(|c| {
        c.stop_deceleration_rad_s2 = vec![1.0; N];
        c.hand_guiding_max_speed_m_s = 0.0;
    });
    let q = moving(&mut cell, 0.2);
    let sets = follow(&mut cell, "teaching", 60, q, false, true);
    assert_eq!(sets.len(), 60, "every cycle of the stop answered at once");
    let ramp: Vec<&Set> = sets.iter().filter(|s| s.none_hold()).collect();
    let held: Vec<&Set> = sets.iter().filter(|s| s.all_hold()).collect();
    assert!(ramp.len() == 50 && held.len() == 10 && sets[..50].iter().all(|s| s.none_hold()));
    for (k, s) in ramp.iter().enumerate() {
        assert!((s.dq[0] - 0.2 * (1.0 - k as f64 / 50.0)).abs() < 1e-4);
    }
    let steps: Vec<f64> = ramp
        .windows(2)
        .map(|w| (w[1].q[0] - w[0].q[0]) / 0.004)
        .collect();
    assert!(steps.iter().all(|&s| s > -1e-3), "never reverses");
    assert!(steps.windows(2).all(|w| w[1] - w[0] < 1e-2), "slows down");
    let end = plus(Q0, 0.2 * 0.004 + 0.5 * 0.2 * 0.2);
    assert_close(&held[held.len() - 1].q, &end, 2e-6);
    assert_eq!(cell.health()["ramped"], json!(50));
    assert_eq!(cell.core.desired_request(cell.t), HostRequest::ServoOn);
    assert!(cell
        .core
        .take_notes()
        .iter()
        .any(|(_, k, m)| k == "ramp" && m.contains("ramping to standstill in 200 ms")));
}

#[test]
fn core_a_fault_during_the_ramp_holds_at_once_where_the_ramp_had_got_to() {
    let mut cell = Cell::new(|c| {
        c.stop_deceleration_rad_s2 = vec![1.0; N];
        c.hand_guiding_max_speed_m_s = 0.0;
    });
    let q = moving(&mut cell, 0.2);
    let sets = follow(&mut cell, "teaching", 10, q, false, true);
    assert_eq!(cell.answer(), Answer::Ramp);
    let mut reached = [0.0; N];
    reached.copy_from_slice(&sets[sets.len() - 1].q);
    let after = follow(&mut cell, "teaching", 3, reached, false, false);
    assert!(
        after.iter().all(|s| s.all_hold()),
        "the e-stop chain opened: no more ramp"
    );
    // held where the ramp was on the cycle the fault was seen
    assert_close(&after[0].q, &plus(reached, 0.004 * 0.2 * 0.8), 2e-5);
}

#[test]
fn core_the_operators_stop_keeps_the_servo_on_through_the_ramp_then_brakes() {
    // Stop category 1: STOPPED while the arm moves ramps it to standstill under power.
    let mut cell = Cell::new(|c| {
        c.stop_deceleration_rad_s2 = vec![2.0; N];
        c.hand_guiding_max_speed_m_s = 0.0;
    });
    let q = moving(&mut cell, 0.2);
    follow(&mut cell, "stopped", 5, q, true, true);
    assert_eq!(cell.answer(), Answer::Ramp);
    assert_eq!(cell.core.desired_request(cell.t), HostRequest::ServoOn);
    follow(&mut cell, "stopped", 25, q, true, true); // 0.1 s: the ramp has ended
    assert_eq!(cell.answer(), Answer::Hold);
    assert_eq!(cell.core.desired_request(cell.t), HostRequest::Brake);
}

#[test]
fn core_the_operators_stop_between_two_cycles_waits_for_the_ramp_not_the_brakes() {
    // The stop arrives, and the driver decides its servo request, before the next cycle
    // starts the ramp: the servo stays on.
    let mut cell = Cell::new(|c| {
        c.stop_deceleration_rad_s2 = vec![2.0; N];
        c.hand_guiding_max_speed_m_s = 0.0;
    });
    let q = moving(&mut cell, 0.2);
    cell.t += 0.001;
    cell.gateway("stopped");
    let sent = cell.tick();
    assert!(
        requests(&sent).iter().all(|&r| r == HostRequest::ServoOn),
        "{sent:?}"
    );
    assert_eq!(cell.core.desired_request(cell.t), HostRequest::ServoOn);
    follow(&mut cell, "stopped", 1, q, true, true);
    assert_eq!(cell.answer(), Answer::Ramp);
    cell.t += 1.0; // long after: a stop that never ramped would not keep the servo on
    cell.gateway("stopped");
    follow(&mut cell, "stopped", 40, q, true, true);
    assert_eq!(cell.core.desired_request(cell.t), HostRequest::Brake);
}

#[test]
fn core_a_hold_the_drives_do_not_keep_trips_the_standstill_monitor_and_the_brakes() {
    let mut cell = Cell::new(|c| {
        c.standstill_settle_s = 0.1;
        c.standstill_band_rad = 0.02;
        c.standstill_confirm_cycles = 3;
    });
    cell.gateway("ready");
    cell.tick();
    follow(&mut cell, "ready", 40, Q0, true, true); // held where it was: within the band
    assert!(cell.core.standstill.trip.is_none());
    let mut q = Q0;
    for _ in 0..10 {
        // the arm sags 5 mrad per cycle under a hold set
        q[1] -= 0.005;
        cell.t += 0.004;
        cell.gateway("ready");
        cell.cycle(at(q));
    }
    let trip = cell.health()["standstill_trip"]
        .as_str()
        .unwrap_or_default()
        .to_string();
    assert!(trip.contains("joint 2"), "{trip}");
    assert_eq!(cell.core.desired_request(cell.t), HostRequest::Brake);
    for _ in 0..2 {
        // the gateway has stopped the cell, the arm on its brakes: cleared
        cell.t += 0.004;
        cell.gateway("fault");
        cell.cycle(at(q));
    }
    assert_eq!(cell.health()["standstill_trip"], json!(null));
}

#[test]
fn core_a_command_past_the_drivers_joint_limits_is_refused_and_the_cycle_held() {
    // The driver's own joint limits (the description's less joint_limit_margin_rad), behind
    // the control law's soft walls.
    let upper = 60.0 * DEG;
    let mut cell = Cell::new(|_| {});
    let mut q = Q0;
    q[2] = upper - 0.02; // inside the driver's range, near the top of joint 3
    cell.gateway("teaching");
    let (js, _) = cell.cycle(at(q));
    assert_eq!(cell.command(&js, &q, 0.0).0, Answer::Command);
    let mut beyond = q;
    beyond[2] = upper - 0.005; // within 0.01 rad of the limit (and 0.015 from q)
    cell.t += 0.004;
    cell.gateway("teaching");
    let (js, _) = cell.cycle(at(q));
    let (answer, held) = cell.command(&js, &beyond, 0.0);
    assert!(answer == Answer::Hold && cell.core.rejected_for("out_of_range") == 1);
    assert!(held.len() == 1 && held[0].all_hold());
    assert!((held[0].q[2] - q[2]).abs() < 1e-5);
    let notes = cell.core.take_notes();
    assert!(
        notes.iter().any(|(_, _, m)| m.contains(
            "joint 3: q_cmd = 1.0422 rad outside the driver's limits [-0.7754, 1.0372] rad"
        )),
        "{notes:?}"
    );
}

#[test]
fn core_an_older_or_conflicting_lifecycle_message_is_dropped_and_counted() {
    // A late "teaching" (lower seq, or the same seq with an older stamp) must not undo a
    // "stopped"; the same seq naming another state is not what the gateway sends.
    let mut cell = Cell::new(|_| {});
    cell.gateway("teaching");
    let (js, _) = cell.cycle(Spec::default());
    assert_eq!(cell.command(&js, &Q0, 0.0).0, Answer::Command);
    cell.t += 0.004;
    let t = cell.t;
    cell.core
        .on_lifecycle(&lifecycle_payload("stopped", 7, t), t);
    cell.core
        .on_lifecycle(&lifecycle_payload("teaching", 6, t), t); // sent before the stop
    cell.core
        .on_lifecycle(&lifecycle_payload("stopped", 7, t - 0.01), t);
    cell.core
        .on_lifecycle(&lifecycle_payload("teaching", 7, t), t);
    cell.core
        .on_lifecycle(&lifecycle_payload("stopped", 7, t + 0.05), t);
    let (js, sent) = cell.cycle(Spec::default());
    assert!(commands(&sent).iter().all(|s| s.all_hold()) && !sent.is_empty()); // still stopped: held at once
    assert_ne!(cell.command(&js, &Q0, 0.0).0, Answer::Command);
    assert_eq!(
        cell.health()["lifecycle_dropped"],
        json!({"out_of_order": 2, "conflicting": 1})
    );
    let notes = cell.core.take_notes();
    assert!(
        notes.iter().any(|(_, k, m)| k == "lifecycle_out_of_order"
            && m.contains("seq 6 TEACHING after seq 7 STOPPED")),
        "{notes:?}"
    );
}

#[test]
fn core_a_bus_off_latches_a_bus_fault_until_the_bus_works_and_the_cell_is_stopped() {
    let mut cell = Cell::new(|c| c.bus_error_window_s = 0.5);
    cell.gateway("teaching");
    cell.tick();
    let (js, _) = cell.cycle(Spec::default());
    assert_eq!(cell.command(&js, &Q0, 0.0).0, Answer::Command);
    let (mut out, mut s, mut w) = (Vec::new(), Vec::new(), Vec::new());
    cell.core.on_frame(
        &error_frame(ERR_CRTL, &[0, 0x20, 0, 0, 0, 0, 0, 0]),
        cell.t,
        &mut out,
        &mut s,
        &mut w,
    );
    assert!(cell.core.bus.fault.is_none() && cell.core.bus.error_passive == 1);
    cell.core.on_frame(
        &error_frame(ERR_BUSOFF, &[0; 8]),
        cell.t,
        &mut out,
        &mut s,
        &mut w,
    );
    let health = cell.health();
    assert!(
        health["bus_fault"].as_str().unwrap().contains("bus-off") && health["bus_off"] == json!(1)
    );
    assert_eq!(cell.core.desired_request(cell.t), HostRequest::Brake);
    cell.t += 0.1; // the kernel restarts the interface (restart-ms) and frames flow again
    cell.core.on_frame(
        &error_frame(ERR_RESTARTED, &[0; 8]),
        cell.t,
        &mut out,
        &mut s,
        &mut w,
    );
    let (js, _) = cell.try_cycle(Spec::default());
    assert!(
        js.is_none(),
        "the cycle an error frame came in is dropped (the adapter's rule)"
    );
    let sets = follow(&mut cell, "teaching", 200, Q0, true, true); // 0.8 s of cycles, still teaching
    let (js, _) = cell.cycle(Spec::default());
    let (answer, _) = cell.command(&js, &Q0, 0.0);
    assert!(answer == Answer::None && cell.core.rejected_for("blocked_bus") == 1);
    assert!(
        sets.len() == 200 && sets.iter().all(|s| s.all_hold()),
        "held while the fault is latched"
    );
    assert!(
        cell.core.bus.fault.is_some(),
        "the bus alone never re-arms the cell"
    );
    follow(&mut cell, "fault", 2, Q0, true, true); // the gateway has stopped the cell: cleared
    let health = cell.health();
    assert_eq!(health["bus_fault"], json!(null));
    assert_eq!(health["bus_restarts"], json!(1));
}

#[test]
fn core_a_burst_of_bus_errors_latches_a_fault_and_scattered_ones_do_not() {
    let mut cell = Cell::new(|c| {
        c.bus_error_limit = 5;
        c.bus_error_window_s = 1.0;
    });
    cell.gateway("ready");
    let (mut out, mut s, mut w) = (Vec::new(), Vec::new(), Vec::new());
    for _ in 0..8 {
        // one every 0.3 s: never 5 within a second
        cell.t += 0.3;
        cell.core.on_frame(
            &error_frame(ERR_PROT, &[0; 8]),
            cell.t,
            &mut out,
            &mut s,
            &mut w,
        );
    }
    assert!(cell.core.bus.fault.is_none() && cell.core.bus.error_frames == 8);
    for _ in 0..5 {
        cell.t += 0.01;
        cell.core.on_frame(
            &error_frame(ERR_PROT, &[0; 8]),
            cell.t,
            &mut out,
            &mut s,
            &mut w,
        );
    }
    let fault = cell.core.bus.fault.clone().unwrap();
    assert!(
        fault.contains("5 CAN error frames within 1 s") && fault.contains("protocol violation"),
        "{fault}"
    );
    assert!(matches!(
        cell.core.blocked(cell.t),
        Some("blocked_bus" | "blocked_lifecycle")
    ));
}

#[test]
fn core_a_release_just_after_an_uncommanded_cycle_ramps_along_the_path_not_the_spring_back() {
    // Teaching at 0.2 rad/s; three cycles go by without a command (the driver coasts, then
    // holds); the law's next command is where the path had got to, with the arm's spring-back
    // (-0.14 rad/s) as its velocity; the enabling device is released. The ramp starts at the
    // path's 0.2 rad/s and never goes back past that command (ramp_start.rs).
    let mut cell = Cell::new(|c| {
        c.stop_deceleration_rad_s2 = vec![1.0; N];
        c.hand_guiding_max_speed_m_s = 0.0;
    });
    cell.gateway("teaching");
    cell.tick();
    let mut q = Q0;
    for _ in 0..10 {
        cell.t += PERIOD_S;
        cell.gateway("teaching");
        let (js, _) = cell.cycle(at(q));
        assert_eq!(cell.command(&js, &q, 0.2).0, Answer::Command);
        q = plus(q, 0.2 * PERIOD_S);
    }
    for _ in 0..3 {
        cell.t += PERIOD_S;
        cell.gateway("teaching");
        cell.cycle(at(q));
        cell.t += 0.0021; // past the answer deadline
        cell.tick();
        cell.t -= 0.0021;
        assert_ne!(cell.answer(), Answer::Command);
        q = plus(q, 0.2 * PERIOD_S);
    }
    cell.t += PERIOD_S;
    cell.gateway("teaching");
    let (js, _) = cell.cycle(at(q));
    assert_eq!(cell.command(&js, &q, -0.14).0, Answer::Command);
    let last = q;
    let sets = follow(&mut cell, "teaching", 60, q, false, true);
    let ramp: Vec<&Set> = sets.iter().filter(|s| s.none_hold()).collect();
    assert!(!ramp.is_empty(), "a ramp");
    assert!(
        (ramp[0].dq[0] - 0.2).abs() < 0.01,
        "the ramp starts at the path's speed: {}",
        ramp[0].dq[0]
    );
    assert!(
        ramp.iter().all(|s| s.q[0] >= last[0] - 1e-9),
        "never back past the last command"
    );
    assert!(cell
        .core
        .take_notes()
        .iter()
        .any(|(_, k, m)| k == "ramp" && m.contains("at the path's speed")));
}
