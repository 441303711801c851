//! The core as the CAN driver's logic (the core's part of test_can_driver_logic.py and
//! test_cia402_cycle.py): deadlines, forwarding, holds, the servo request, resets, the counter,
//! the health message, and a host-clocked link's clock frames.

use super::*;

#[test]
fn core_clocks_a_host_clocked_link_and_its_exit_brake_ends_with_the_clock_frame() {
    // The core sends the adapter's clock frames (CANopen: SYNC) on its period and, on exit,
    // the BRAKE then one clock frame: a host-clocked cycle's frames take effect at the next.
    let period = 0.002;
    let mut cell = Cell::with(config(|c| c.heartbeat_period_s = 0.02), Some(period));
    let mut syncs = 0;
    for k in 0..5 {
        let now = 100.0 + k as f64 * period;
        assert!(cell.core.next_tick_s() <= now + 1e-9);
        cell.t = now;
        syncs += cell.tick().iter().filter(|s| **s == Sent::Sync).count();
    }
    assert_eq!(syncs, 5);
    assert!((cell.core.next_tick_s() - (100.0 + 5.0 * period)).abs() < 1e-9);
    cell.cycle(Spec::default());
    let mut out = Vec::new();
    cell.core.closing_frames(&mut out);
    let sent: Vec<Sent> = out.iter().map(decode).collect();
    assert_eq!(sent[0], Sent::Request(HostRequest::Brake as u8));
    assert_eq!(sent.last(), Some(&Sent::Sync));
    assert_eq!(sent.iter().filter(|s| **s == Sent::Sync).count(), 1);
    assert!(commands(&sent[1..sent.len() - 1])[0].all_hold());
}

#[test]
fn core_an_unanswered_cycle_is_held_at_the_deadline_or_before_the_next_cycle() {
    for (period_us, answer_by_s) in [(20000, 0.010), (4000, 0.002)] {
        let mut cell = teaching(|_| {});
        cell.cycle(Spec {
            period_us,
            ..Spec::default()
        });
        cell.t += answer_by_s - 1e-4;
        assert!(commands(&cell.tick()).is_empty());
        cell.t += 2e-4;
        let hold = commands(&cell.tick());
        assert_eq!(hold.len(), 1);
        assert!(hold[0].all_hold() && hold[0].dq.iter().all(|&v| v == 0.0));
        assert!(hold[0].counters.iter().all(|&c| c == cell.counter));
        assert_close(&hold[0].q, &Q0, 1e-6);
        cell.t += 0.05;
        assert!(
            commands(&cell.tick()).is_empty(),
            "a cycle is answered once"
        );
    }
}

#[test]
fn core_forwarded_command_and_the_joint_state_echo() {
    let mut cell = teaching(|_| {});
    let (js, _) = cell.cycle(slow(Q0));
    assert_close(&js.q_cmd, &Q0, 1e-6); // measured q before any command
    cell.t += 0.002;
    let (answer, sets) = cell.command(&js, &plus(Q0, 0.01), 0.2);
    assert!(answer == Answer::Command && sets.len() == 1);
    assert!(sets[0].none_hold() && sets[0].counters.iter().all(|&c| c == cell.counter));
    assert_close(&sets[0].q, &plus(Q0, 0.01), 1e-6);
    assert_close(&sets[0].dq, &[0.2; N], 1e-4);
    let (nxt, _) = cell.cycle(slow(Q0));
    assert_close(&nxt.q_cmd, &plus(Q0, 0.01), 1e-12);
    assert_close(&nxt.dq_cmd, &[0.2; N], 1e-12);
    cell.command(&js, &Q0, 0.0); // a second command for an answered cycle is late
    assert_eq!(cell.core.rejected_for("late_cycle"), 1);
}

#[test]
fn core_age_counts_from_the_driver_stamp_even_if_the_command_claims_fresh() {
    let mut cell = teaching(|_| {});
    let (js, _) = cell.cycle(slow(Q0));
    cell.t += 0.011;
    let t = cell.t;
    let (answer, sets) = cell.command_stamped(js.cycle, t, &Q0, 0.0); // lies about its age
    assert_eq!(cell.core.rejected_for("stale"), 1);
    assert!(answer == Answer::Hold && sets[0].all_hold());
}

#[test]
fn core_following_error_and_velocity_limits_are_per_joint() {
    let mut cell = teaching(|c| c.max_following_error_rad = vec![0.05, 0.05, 0.05, 0.2, 0.2, 0.2]);
    let (js, _) = cell.cycle(slow(Q0));
    let mut q = Q0;
    q[4] += 0.15; // within joint 5's 0.2 rad
    assert_eq!(cell.command(&js, &q, 0.0).1.len(), 1);
    let (js, _) = cell.cycle(slow(Q0));
    let mut q = Q0;
    q[1] += 0.06; // beyond joint 2's 0.05 rad
    let (_, sets) = cell.command(&js, &q, 0.0);
    assert_eq!(cell.core.rejected_for("out_of_range"), 1);
    assert!(sets[0].all_hold(), "rejected: held at once");
    let (js, _) = cell.cycle(slow(Q0));
    cell.command(&js, &Q0, 1.01);
    assert_eq!(cell.core.rejected_for("out_of_range"), 2);
}

#[test]
fn core_hold_latches_the_last_forwarded_command_and_ignores_sag() {
    let mut cell = teaching(|_| {});
    let (js, _) = cell.cycle(slow(Q0));
    cell.command(&js, &plus(Q0, 0.02), 0.0);
    let mut q = Q0;
    for _ in 0..5 {
        // commands stop; the arm sags 5 mrad per cycle (fast enough for the speed monitor:
        // once it trips, the cycle is held at once, not at its deadline; as in Python's test,
        // the frames of both count)
        q = plus(q, -0.005);
        let (_, mut sent) = cell.cycle(slow(q));
        cell.t += 0.011;
        sent.extend(cell.tick());
        let sets = commands(&sent);
        assert_eq!(sets.len(), 1);
        assert_close(&sets[0].q, &plus(Q0, 0.02), 1e-6);
    }
}

#[test]
fn core_hold_latches_the_measured_position_if_the_last_command_is_too_far() {
    let mut cell = teaching(|_| {});
    let (js, _) = cell.cycle(slow(Q0));
    cell.command(&js, &plus(Q0, 0.04), 0.0);
    let q_then = plus(Q0, -0.02); // 0.06 rad from the last command: beyond the 0.05 rad limit
    let (_, mut sent) = cell.cycle(slow(q_then));
    cell.t += 0.011;
    sent.extend(cell.tick());
    let hold = commands(&sent);
    assert!(hold.len() == 1 && hold[0].all_hold());
    assert_close(&hold[0].q, &q_then, 1e-6);
    let (_, mut sent) = cell.cycle(slow(plus(q_then, -0.01))); // not re-sampled while holding
    cell.t += 0.011;
    sent.extend(cell.tick());
    let hold = commands(&sent);
    assert_eq!(hold.len(), 1);
    assert_close(&hold[0].q, &q_then, 1e-6);
}

#[test]
fn core_on_brakes_the_hold_follows_the_measured_position() {
    let mut cell = rig(|_| {}); // STOPPED: only holds, controller BRAKED
    for k in 0..3 {
        let q = plus(Q0, 0.01 * k as f64);
        let (_, sent) = cell.cycle(Spec {
            state: ControllerState::Braked,
            ..slow(q)
        });
        let holds = commands(&sent);
        assert_eq!(holds.len(), 1, "blocked cycles are held at once");
        assert_close(&holds[0].q, &q, 1e-6);
    }
}

#[test]
fn core_blocked_reasons() {
    let mut cell = rig(|_| {});
    let mut sets = Vec::new();
    cell.gateway_io("teaching", false, true);
    let (js, sent) = cell.cycle(slow(Q0));
    sets.extend(commands(&sent));
    cell.command(&js, &Q0, 0.0);
    cell.gateway("ready");
    let (js, sent) = cell.cycle(slow(Q0));
    sets.extend(commands(&sent));
    cell.command(&js, &Q0, 0.0);
    cell.gateway("teaching");
    let (js, sent) = cell.cycle(Spec {
        state: ControllerState::Braked,
        ..slow(Q0)
    });
    sets.extend(commands(&sent));
    cell.command(&js, &Q0, 0.0);
    let c = &cell.core;
    assert_eq!(
        (
            c.rejected_for("blocked_enabling"),
            c.rejected_for("blocked_lifecycle"),
            c.rejected_for("blocked_controller")
        ),
        (1, 1, 1)
    );
    assert!(sets.len() == 3 && sets.iter().all(|s| s.all_hold()));
}

#[test]
fn core_the_servo_request_follows_a_fresh_lifecycle() {
    let mut cell = rig(|_| {});
    let first = cell.tick();
    assert!(first.contains(&Sent::Heartbeat) && requests(&first) == vec![HostRequest::Brake]);
    cell.gateway("ready");
    assert_eq!(requests(&cell.tick()), vec![HostRequest::ServoOn]);
    cell.t += 0.05;
    cell.gateway("ready");
    assert!(cell.tick().is_empty(), "no repeat between heartbeats");
    cell.t += 0.051;
    cell.gateway("ready");
    let repeat = cell.tick();
    assert!(repeat.contains(&Sent::Heartbeat) && requests(&repeat) == vec![HostRequest::ServoOn]);
    cell.t += 0.25; // the gateway fell silent
    assert_eq!(requests(&cell.tick()), vec![HostRequest::Brake]);
    let notes = cell.core.take_notes();
    let said: Vec<&str> = notes
        .iter()
        .filter(|n| n.1 == "request")
        .map(|n| n.2.as_str())
        .collect();
    assert_eq!(
        said,
        vec![
            "requesting BRAKE from the controller",
            "requesting SERVO_ON from the controller",
            "requesting BRAKE from the controller"
        ]
    );
}

#[test]
fn core_a_future_stamp_does_not_keep_the_lifecycle_fresh() {
    let mut cell = rig(|_| {});
    let t = cell.t;
    cell.core
        .on_lifecycle(&lifecycle_payload("teaching", 1, t + 3600.0), t);
    cell.core.on_io(&io_payload(t, true, true), t);
    assert_eq!(requests(&cell.tick()), vec![HostRequest::Brake]);
    assert_eq!(cell.core.blocked(t), Some("blocked_lifecycle"));
}

#[test]
fn core_the_operators_reset_is_sent_once_and_only_to_a_faulted_controller() {
    let mut cell = rig(|_| {});
    let mut sent = Vec::new();
    cell.gateway("fault");
    cell.cycle(Spec {
        state: ControllerState::Fault,
        ..slow(Q0)
    });
    sent.extend(cell.tick());
    cell.gateway("stopped");
    assert_eq!(
        cell.core.next_tick_s(),
        f64::NEG_INFINITY,
        "a reset is due at once"
    );
    sent.extend(cell.tick());
    sent.extend(cell.tick());
    assert_eq!(
        requests(&sent),
        vec![
            HostRequest::Brake,
            HostRequest::ResetFault,
            HostRequest::Brake
        ]
    );
    cell.gateway("stopped");
    assert!(!requests(&cell.tick()).contains(&HostRequest::ResetFault));
    cell.gateway("fault");
    cell.cycle(Spec {
        state: ControllerState::Braked,
        ..slow(Q0)
    }); // the controller is not faulted
    cell.gateway("stopped");
    assert!(!requests(&cell.tick()).contains(&HostRequest::ResetFault));
}

#[test]
fn core_a_faulted_controller_is_named_in_the_health_in_the_adapters_words() {
    let mut cell = rig(|_| {});
    cell.gateway("fault");
    cell.cycle(Spec {
        state: ControllerState::Fault,
        ..slow(Q0)
    });
    let health = cell.health();
    // the fake adapter has no words of its own: the fault's kind
    assert_eq!(health["controller_fault_text"], json!("FOLLOWING_ERROR"));
    cell.cycle(Spec {
        state: ControllerState::Braked,
        ..slow(Q0)
    });
    assert_eq!(cell.health()["controller_fault_text"], json!(null));
}

#[test]
fn core_the_cycle_counter_is_widened_across_the_wrap_and_repeats_are_dropped() {
    let mut cell = rig(|_| {});
    for (counter, cycle) in [(65534, 65534), (65535, 65535), (0, 65536), (2, 65538)] {
        // a lost cycle leaves a gap
        assert_eq!(
            cell.cycle(Spec {
                counter: Some(counter),
                ..slow(Q0)
            })
            .0
            .cycle,
            cycle
        );
    }
    let (js, _) = cell.try_cycle(Spec {
        counter: Some(2),
        state: ControllerState::Hold,
        ..Spec::default()
    });
    assert!(js.is_none(), "a repeated cycle is not published twice");
    assert_eq!(cell.core.cycles, 4);
    assert!(cell
        .core
        .take_notes()
        .iter()
        .any(|(l, k, m)| *l == 30 && k == "dup" && m == "controller repeated cycle 2"));
}

#[test]
fn core_the_health_message() {
    let mut cell = teaching(|_| {});
    cell.cycle(slow(Q0));
    cell.t += 0.2;
    cell.tick();
    assert!(
        cell.core.health_due(cell.t)
            && !cell.core.health_due(cell.t + 0.05)
            && cell.core.health_due(cell.t + 0.1)
    );
    let health = cell.health();
    assert_eq!(health["link_ok"], json!(false)); // 0.2 s since the last cycle > controller_timeout_s
    assert_eq!(health["controller_state"], json!("EXTERNAL"));
    assert_eq!(health["controller_fault"], json!("NONE"));
    assert_eq!(health["controller_fault_text"], json!(null));
    assert_eq!(health["held"], json!(1));
    assert_eq!(health["servo_request"], json!("SERVO_ON"));
    // Python's keys and value types, then the adapter's own entries
    let python = [
        "controller_state",
        "controller_fault",
        "controller_fault_text", // added by the compiled core: the operator's reason
        "link_ok",
        "servo_request",
        "cycles",
        "forwarded",
        "held",
        "ramped",
        "standstill_trip",
        "lost_cycles",
        "lost_cycles_trip",
        "coasted",
        "unanswered",
        "rejected",
        "bad_frames",
        "unknown_frames", // added by the compiled core: the fuzz tests count ignored ids
        "implausible_cycles",
        "incomplete_cycles",
        "corrupt_cycles",
        "bad_inputs",
        "lifecycle_dropped",
        "speed_trip",
        "speed_peak_m_s",
        "bus_fault",
        "bus_error_frames",
        "bus_off",
        "bus_restarts",
        "bus_error_passive",
        "current_zero_a",
        "current_zero_source",
        "current_zero_samples",
        "current_zero_ready",
        "current_zero_measured_a",
        "current_zero_noise_a",
        "current_zero_drift_a",
    ];
    let mut keys: Vec<&str> = health.keys().map(String::as_str).collect();
    keys.sort();
    let mut want: Vec<&str> = python.iter().copied().chain(["fake_frames"]).collect();
    want.sort();
    assert_eq!(keys, want);
    assert_eq!(
        health["cycles"],
        json!(1),
        "the core's key wins over the adapter's"
    );
    let rejected = health["rejected"].as_object().unwrap();
    assert_eq!(rejected.keys().len(), REJECT_REASONS.len());
    assert!(rejected.values().all(|v| v.is_u64()));
    for key in [
        "cycles",
        "forwarded",
        "held",
        "ramped",
        "lost_cycles",
        "coasted",
        "unanswered",
        "bad_frames",
        "bus_off",
    ] {
        assert!(health[key].is_u64(), "{key}");
    }
    assert!(health["current_zero_ready"].is_boolean() && health["current_zero_drift_a"].is_null());
    assert_eq!(
        health["current_zero_a"],
        json!([0.0, 0.0, 0.0, 0.0, 0.0, 0.0])
    );
    assert!(health["speed_peak_m_s"].is_f64());
}

#[test]
fn core_close_brakes_and_holds() {
    let mut cell = teaching(|_| {});
    cell.cycle(slow(Q0));
    let mut out = Vec::new();
    cell.core.closing_frames(&mut out);
    let sent: Vec<Sent> = out.iter().map(decode).collect();
    assert_eq!(requests(&sent), vec![HostRequest::Brake]);
    assert_eq!(sent[0], Sent::Request(0));
    assert!(commands(&sent[1..])[0].all_hold() && sent.len() == 1 + N);
}

#[test]
fn core_a_late_answer_coasts_on_the_last_command_then_holds_on_the_next() {
    // One late command costs nothing: the driver re-sends the last forwarded command moved on
    // by its velocity; a second late cycle in a row holds, where the coast went.
    let mut cell = teaching(|_| {});
    let (js, _) = cell.cycle(Spec::default());
    let (_, sent) = cell.command(&js, &plus(Q0, 0.001), 0.2);
    assert!(sent[0].none_hold());
    cell.t += PERIOD_S;
    let (late, _) = cell.cycle(Spec::default()); // control is late for this one
    assert_eq!(late.flags & (PREV_COAST | PREV_HOLD), 0); // the last was the command
    cell.t += 0.5 * PERIOD_S + 1e-4;
    let coast = commands(&cell.tick());
    assert!(coast[0].none_hold() && coast[0].counters.iter().all(|&c| c == cell.counter));
    assert_close(&coast[0].q, &plus(Q0, 0.001 + 0.2 * PERIOD_S), 2e-6);
    assert_close(&coast[0].dq, &[0.2; N], 1e-4);
    assert_eq!(cell.core.coasted, 1);
    cell.t += PERIOD_S;
    let (after_coast, _) = cell.cycle(Spec::default()); // late again: two cycles after the command
    assert!(after_coast.flags & PREV_COAST != 0); // the recorder leaves the next cycles out
    cell.t += 0.5 * PERIOD_S + 1e-4;
    let hold = commands(&cell.tick());
    assert!(hold[0].all_hold() && hold[0].dq.iter().all(|&v| v == 0.0));
    assert_close(&hold[0].q, &plus(Q0, 0.001 + 0.2 * PERIOD_S), 2e-6);
    cell.t += PERIOD_S;
    assert!(cell.cycle(Spec::default()).0.flags & PREV_HOLD != 0);
}
