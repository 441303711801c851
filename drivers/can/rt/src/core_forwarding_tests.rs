//! The core forwarding commands (test_can_core.py): a cycle becomes one JointState, a fresh
//! command is forwarded once and echoed, a late one coasts or holds, a bad one is refused and
//! its cycle held.

use super::*;

#[test]
fn core_a_cycle_becomes_one_joint_state_with_the_feedback_and_the_echo() {
    let mut cell = Cell::new(|_| {});
    let (js, _) = cell.cycle(Spec::default());
    assert_eq!(js.cycle, cell.counter);
    assert_eq!(js.stamp_s, T0);
    assert_eq!(js.period_s, 0.004);
    assert_eq!(js.controller_state, ControllerState::External as u8);
    assert_close(&js.q, &Q0, 1e-6);
    assert_close(&js.dq, &[0.0, 0.01, 0.02, 0.03, 0.04, 0.05], 1e-4);
    assert_close(&js.current, &[1.5; N], 1e-9);
    assert_close(&js.q_cmd, &js.q, 0.0); // nothing sent yet: the measurement
    assert_close(&js.dq_cmd, &[0.0; N], 0.0);
    assert!(js.flags & SERVO_POWER != 0 && js.flags & ESTOP == 0);
    assert_eq!(cell.core.cycles, 1);
    assert_eq!(cell.core.pending_cycle(), Some(1));
}

#[test]
fn core_the_first_state_closes_a_window_and_then_one_per_period_or_on_a_change() {
    let mut cell = Cell::new(|c| c.state_window_s = 0.02);
    let mut closed = Vec::new();
    for k in 0..12 {
        let spec = if k == 8 {
            Spec {
                state: ControllerState::Hold,
                ..Spec::default()
            }
        } else {
            Spec::default()
        };
        let frames = cell.frames(spec);
        let mut window = false;
        for f in &frames {
            cell.out.clear();
            let r = cell
                .core
                .on_frame(f, cell.t, &mut cell.out, &mut cell.state, &mut cell.window);
            window |= r.window;
            if r.window {
                assert_eq!(&cell.window[..4], b"LTSW");
                assert_eq!(
                    &cell.window[cell.window.len() - cell.state.len()..],
                    &cell.state[..],
                    "the newest state whole"
                );
            }
        }
        closed.push(window);
        cell.t += PERIOD_S;
    }
    // the first state; then on the 20 ms grid (5 cycles of 4 ms), and at once when the
    // controller's state changes (to HOLD and back), the grid going on
    assert_eq!(
        closed
            .iter()
            .enumerate()
            .filter(|(_, &c)| c)
            .map(|(k, _)| k)
            .collect::<Vec<_>>(),
        vec![0, 5, 8, 9]
    );
}

#[test]
fn core_currents_are_published_less_the_zero_measured_with_the_servo_power_off() {
    let mut cell = Cell::new(|c| {
        c.current_zero_cycles = 4;
        c.current_zero_settle_cycles = 2;
    });
    let zero = [0.07, -0.21, 0.15, 0.02, -0.01, 0.0];
    let (js, _) = cell.cycle(Spec {
        current: plus(zero, 2.0),
        ..Spec::default()
    }); // powered: nothing measured yet
    assert_close(&js.current, &plus(zero, 2.0), 6e-3);
    let mut js = js;
    for k in 0..8 {
        // the power goes off; the first 2 cycles still hold powered ticks
        let current = plus(zero, if k < 2 { 1.0 } else { 0.0 });
        js = cell
            .cycle(Spec {
                state: ControllerState::Braked,
                current,
                power: false,
                ..Spec::default()
            })
            .0;
    }
    assert_close(&js.current, &[0.0; N], 6e-3);
    let health = cell.health();
    let measured: Vec<f64> = health["current_zero_a"]
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v.as_f64().unwrap())
        .collect();
    assert_close(&measured, &zero, 6e-3);
    assert_eq!(health["current_zero_samples"], json!(4));
    assert_eq!(health["current_zero_source"], json!("measured"));
    let (js, _) = cell.cycle(Spec {
        current: plus(zero, 3.0),
        ..Spec::default()
    }); // powered again: the zero stays
    assert_close(&js.current, &[3.0; N], 6e-3);
}

#[test]
fn core_the_first_servo_on_waits_until_the_current_zero_is_measured() {
    let mut cell = Cell::new(|c| {
        c.current_zero_cycles = 3;
        c.current_zero_settle_cycles = 0;
    });
    let off = Spec {
        state: ControllerState::Braked,
        current: [0.1; N],
        power: false,
        ..Spec::default()
    };
    cell.gateway("ready");
    assert_eq!(cell.core.desired_request(cell.t), HostRequest::Brake); // nothing measured yet
    assert_eq!(requests(&cell.tick()), vec![HostRequest::Brake]);
    let notes = cell.core.take_notes();
    assert!(
        notes
            .iter()
            .any(|(level, key, m)| *level == 20 && key == "zero" && m.contains("0 of 3 cycles")),
        "{notes:?}"
    );
    for _ in 0..2 {
        cell.cycle(off);
    }
    assert_eq!(cell.core.desired_request(cell.t), HostRequest::Brake);
    cell.cycle(off);
    assert_eq!(cell.core.desired_request(cell.t), HostRequest::ServoOn);
    cell.cycle(Spec {
        current: [2.0; N],
        ..Spec::default()
    }); // powered, then off again: no new wait
    cell.cycle(off);
    assert_eq!(cell.core.desired_request(cell.t), HostRequest::ServoOn);
}

#[test]
fn core_a_blocked_cycle_is_held_at_once_and_flagged_in_the_next_state() {
    let mut cell = Cell::new(|_| {}); // no lifecycle: blocked
    let (_, sent) = cell.cycle(Spec::default());
    let hold = commands(&sent);
    assert_eq!(hold.len(), 1);
    assert!(hold[0].all_hold() && hold[0].counters.iter().all(|&c| c == cell.counter));
    assert_eq!(cell.answer(), Answer::Hold);
    let (js, _) = cell.cycle(Spec::default());
    assert!(js.flags & PREV_HOLD != 0);
}

#[test]
fn core_a_fresh_command_is_forwarded_once_and_echoed() {
    let mut cell = Cell::new(|_| {});
    cell.gateway("teaching");
    let (js, sent) = cell.cycle(Spec::default());
    assert!(commands(&sent).is_empty());
    cell.t += 0.001;
    let (answer, sets) = cell.command(&js, &plus(Q0, 0.01), 0.2);
    assert_eq!(answer, Answer::Command);
    assert_eq!(sets.len(), 1);
    assert!(sets[0].counters.iter().all(|&c| c == cell.counter) && sets[0].none_hold());
    assert_close(&sets[0].q, &plus(Q0, 0.01), 1e-6);
    let (again, frames) = cell.command(&js, &Q0, 0.0);
    assert_eq!((again, frames.len()), (Answer::None, 0));
    assert_eq!(cell.core.rejected_for("late_cycle"), 1);
    let (nxt, _) = cell.cycle(Spec::default());
    assert_close(&nxt.q_cmd, &plus(Q0, 0.01), 0.0);
    assert!(nxt.flags & (PREV_HOLD | PREV_COAST) == 0);
    assert_eq!(cell.core.forwarded, 1);
}

#[test]
fn core_the_next_deadline_is_the_answer_time_of_an_unanswered_cycle() {
    let mut cell = Cell::new(|c| {
        c.deadline_s = 0.010;
        c.answer_by_period_fraction = 0.5;
    });
    cell.gateway("teaching");
    cell.tick(); // first heartbeat and request go out
    cell.cycle(Spec::default());
    assert!((cell.core.next_tick_s() - (T0 + 0.002)).abs() < 1e-9); // 0.5 × 4 ms < 10 ms
    cell.t += 0.0019;
    assert!(commands(&cell.tick()).is_empty());
    cell.t += 0.0002;
    let hold = commands(&cell.tick());
    assert!(hold.len() == 1 && hold[0].all_hold());
    assert!((cell.core.next_tick_s() - (T0 + 0.1)).abs() < 1e-9); // next heartbeat
}

#[test]
fn core_at_ltc1s_8_ms_one_late_command_coasts_and_a_second_in_a_row_holds() {
    // The coast's bound is one cycle, whatever the period: at 8 ms the command of the cycle
    // before is 12 ms old when the late cycle is answered (past deadline_s, 10 ms), and still
    // coasts; the next late cycle holds.
    let mut cell = Cell::new(|c| c.deadline_s = 0.010);
    let slow = Spec {
        period_us: 8000,
        ..Spec::default()
    };
    cell.gateway("teaching");
    cell.tick();
    let (js, _) = cell.cycle(slow);
    assert_eq!(cell.command(&js, &plus(Q0, 0.001), 0.2).0, Answer::Command);
    let coasted = plus(Q0, 0.001 + 0.2 * 0.008);
    for answer in [Answer::Coast, Answer::Hold] {
        // the hold keeps the coast's place
        cell.t += 0.008;
        cell.gateway("teaching");
        cell.cycle(slow);
        cell.t += 0.0041; // past the answer deadline, half the period
        let sent = commands(&cell.tick());
        assert_eq!(cell.answer(), answer);
        assert_eq!(sent.len(), 1);
        assert!(sent[0].hold.iter().all(|&h| h == (answer == Answer::Hold)));
        assert_close(&sent[0].q, &coasted, 2e-6);
        cell.t -= 0.0041;
    }
}

#[test]
fn core_against_a_lock_step_controller_waits_for_a_late_command_then_holds() {
    // A lock-step virtual controller starts its next cycle only once this one is answered:
    // a command 150 ms late at an 8 ms period is forwarded, not held, and the link stays up;
    // past the wait the cycle is held as at any controller.
    let mut cell = Cell::new(|c| c.lockstep_answer_wait_s = 0.2);
    let slow = Spec {
        period_us: 8000,
        ..Spec::default()
    };
    cell.gateway("teaching");
    cell.tick();
    let (js, _) = cell.cycle(slow);
    cell.t += 0.15;
    cell.gateway("teaching");
    assert!(commands(&cell.tick()).is_empty());
    assert!(cell.core.link_ok(cell.t));
    assert_eq!(cell.command(&js, &plus(Q0, 0.001), 0.2).0, Answer::Command);
    cell.gateway("teaching");
    cell.cycle(slow);
    cell.t += 0.19;
    assert!(commands(&cell.tick()).is_empty());
    cell.t += 0.011;
    let late = commands(&cell.tick());
    assert!(late.len() == 1 && cell.answer() != Answer::Command);
    assert!(!cell.core.link_ok(cell.t + 0.1)); // 0.1 s controller timeout + the 0.2 s wait
}

#[test]
fn core_a_late_command_coasts_then_the_next_late_one_holds_where_the_coast_went() {
    let mut cell = Cell::new(|c| c.deadline_s = 0.010);
    cell.gateway("teaching");
    cell.tick(); // servo on requested: a new servo-on period begins
    let (js, _) = cell.cycle(Spec::default());
    assert_eq!(cell.command(&js, &plus(Q0, 0.001), 0.2).0, Answer::Command);
    cell.t += 0.004;
    cell.gateway("teaching");
    cell.cycle(Spec::default());
    cell.t += 0.0021;
    let coast = commands(&cell.tick());
    assert!(cell.answer() == Answer::Coast && coast[0].none_hold());
    assert_close(&coast[0].q, &plus(Q0, 0.001 + 0.2 * 0.004), 2e-6);
    cell.t += 0.010; // the next cycle is late too: two cycles after the forwarded command
    cell.gateway("teaching");
    let (js, _) = cell.cycle(Spec::default());
    assert!(js.flags & PREV_COAST != 0);
    cell.t += 0.0021;
    let hold = commands(&cell.tick());
    assert!(hold[0].all_hold() && cell.answer() == Answer::Hold);
    // where the controller was sent last: a hold at the forwarded command would pull it back
    assert_close(&hold[0].q, &plus(Q0, 0.001 + 0.2 * 0.004), 2e-6);
}

#[test]
fn core_coast_max_cycles_lets_that_many_late_cycles_in_a_row_coast() {
    let mut cell = Cell::new(|c| c.coast_max_cycles = 2);
    cell.gateway("teaching");
    cell.tick();
    let (js, _) = cell.cycle(Spec::default());
    assert_eq!(cell.command(&js, &Q0, 0.2).0, Answer::Command);
    let mut answers = Vec::new();
    let mut last_q = Vec::new();
    for _ in 0..3 {
        cell.t += PERIOD_S;
        cell.gateway("teaching");
        cell.cycle(Spec::default());
        cell.t += 0.0021;
        let sets = commands(&cell.tick());
        cell.t -= 0.0021;
        answers.push(cell.answer());
        last_q = sets[0].q.clone();
    }
    assert_eq!(answers, vec![Answer::Coast, Answer::Coast, Answer::Hold]);
    assert_close(&last_q, &plus(Q0, 0.2 * 2.0 * PERIOD_S), 2e-6); // held where the second coast went
    assert_eq!(cell.core.coasted, 2);
}

#[test]
fn core_an_implausible_command_is_refused_and_its_cycle_held() {
    for (q_offset, dq) in [(0.06, 0.0), (0.0, 1.01)] {
        let mut cell = Cell::new(|c| {
            c.max_following_error_rad = vec![0.05; N];
            c.max_velocity_rad_s = vec![1.0; N];
        });
        cell.gateway("teaching");
        let (js, _) = cell.cycle(Spec::default());
        let (answer, sets) = cell.command(&js, &plus(Q0, q_offset), dq);
        assert!(answer == Answer::Hold && sets.len() == 1 && sets[0].all_hold());
        assert_eq!(cell.core.rejected_for("out_of_range"), 1);
        let notes = cell.core.take_notes();
        let want = if dq > 0.0 {
            "|dq_cmd| = 1.0100 rad/s > 1 rad/s"
        } else {
            "|q_cmd - q| = 0.0600 rad > 0.05 rad"
        };
        assert!(
            notes
                .iter()
                .any(|(l, k, m)| *l == 30 && k == "out_of_range" && m.contains(want)),
            "{notes:?}"
        );
    }
}

#[test]
fn core_a_command_the_protocol_cannot_carry_is_out_of_range_and_held() {
    let mut cell = Cell::new(|c| {
        c.max_following_error_rad = vec![1000.0; N];
        c.joint_limit_margin_rad = 0.0;
    });
    // a joint without limits to speak of, so only the protocol refuses
    cell.core = HostCore::new(
        cell.core.config().clone(),
        Box::new(FakeAdapter::new(N, None)),
        0.1,
        None,
        Some(datasheet_chain()),
        (vec![-1e6; N], vec![1e6; N]),
    )
    .unwrap();
    cell.gateway("teaching");
    let (js, _) = cell.cycle(Spec::default());
    let (answer, sets) = cell.command(&js, &plus(Q0, 200.0), 0.0);
    assert!(
        answer == Answer::Hold && sets.len() == 1 && sets[0].all_hold(),
        "nothing of the refused set went out"
    );
    assert_close(&sets[0].q, &Q0, 0.0);
    assert_eq!(cell.core.rejected_for("out_of_range"), 1);
}

#[test]
fn core_a_garbled_command_is_counted_and_answers_nothing() {
    let mut cell = Cell::new(|_| {});
    cell.gateway("teaching");
    cell.cycle(Spec::default());
    let mut out = Vec::new();
    let result = cell.core.on_command(b"LTJC\x02garbage", cell.t, &mut out);
    assert!(out.is_empty() && result.command.is_none() && result.answer == Answer::None);
    assert_eq!(cell.core.rejected_for("bad_message"), 1);
    // a command for another joint count is a bad message too, decoded
    let js = decode_state(&cell.state);
    let payload = command_payload(js.cycle, js.stamp_s, cell.t, &Q0[..5], &[0.0; 5]);
    let result = cell.core.on_command(&payload, cell.t, &mut out);
    assert!(out.is_empty() && result.command.is_some() && result.answer == Answer::None);
    assert_eq!(cell.core.rejected_for("bad_message"), 2);
}
