//! What the port adds (core_tests.rs): notes rate-limited and bounded, bad input counted and
//! never a panic, and the construction refusing what does not fit.

use super::*;

#[test]
fn core_notes_are_rate_limited_per_key_and_count_what_they_held_back() {
    let mut cell = Cell::new(|_| {});
    cell.gateway("ready"); // READY: every command is blocked
    let mut notes = Vec::new();
    for k in 0..500 {
        // 2 s of cycles at 4 ms, a command each
        cell.t = T0 + k as f64 * PERIOD_S;
        if k % 25 == 0 {
            cell.gateway("ready");
        }
        let (js, _) = cell.cycle(Spec::default());
        cell.command(&js, &Q0, 0.0);
        notes.extend(cell.core.take_notes());
    }
    let blocked: Vec<&(u8, String, String)> = notes
        .iter()
        .filter(|n| n.1 == "blocked_lifecycle")
        .collect();
    assert_eq!(blocked.len(), 2, "{blocked:?}"); // at 0 s and at 1 s
    assert_eq!(blocked[0].0, 20);
    assert!(blocked[0]
        .2
        .starts_with("JointCommand not forwarded (blocked_lifecycle): cycle 1"));
    assert!(
        blocked[1].2.ends_with(" (+249 similar in the last 1 s)"),
        "{}",
        blocked[1].2
    );
    assert_eq!(cell.core.rejected_for("blocked_lifecycle"), 500);
}

#[test]
fn core_a_full_note_queue_drops_and_says_so() {
    let mut cell = Cell::new(|_| {});
    for k in 0..200 {
        // alternating requests: each change is a note of its own (not rate-limited)
        cell.t = T0 + k as f64 * 0.3;
        cell.gateway("ready");
        cell.tick();
    }
    let notes = cell.core.take_notes();
    assert!(notes.len() <= crate::core::NOTE_QUEUE + 1);
    let mut cell = Cell::new(|_| {});
    for k in 0..100 {
        cell.t = T0 + k as f64 * 0.3;
        cell.gateway(if k % 2 == 0 { "ready" } else { "stopped" });
        cell.tick();
    }
    let notes = cell.core.take_notes();
    assert_eq!(notes.len(), crate::core::NOTE_QUEUE + 1);
    let last = &notes[notes.len() - 1];
    assert!(
        last.1 == "notes" && last.2.contains("notes dropped"),
        "{last:?}"
    );
    assert!(cell.core.take_notes().is_empty());
}

#[test]
fn core_bad_input_is_counted_never_a_panic() {
    let mut cell = Cell::new(|_| {});
    cell.gateway("teaching");
    let (js, _) = cell.cycle(Spec::default());
    let t = cell.t;
    let mut out = Vec::new();
    let (mut s, mut w) = (Vec::new(), Vec::new());
    let mut seed = 0x2545_F491_4F6C_DD1Du64;
    let mut bytes = |len: usize| -> Vec<u8> {
        (0..len)
            .map(|_| {
                seed ^= seed << 13;
                seed ^= seed >> 7;
                seed ^= seed << 17;
                seed as u8
            })
            .collect()
    };
    let mut payloads: Vec<Vec<u8>> = vec![
        vec![],
        b"{".to_vec(),
        b"[]".to_vec(),
        b"{\"state\": \"teaching\"}".to_vec(),
        b"{\"state\": \"teaching\", \"seq\": 1, \"stamp_s\": 1e999}".to_vec(),
        b"LTJC".to_vec(),
        b"LTIO\x01".to_vec(),
        command_payload(js.cycle, js.stamp_s, t, &[f64::NAN; N], &[0.0; N]),
        command_payload(js.cycle, f64::INFINITY, t, &Q0, &[0.0; N]),
        command_payload(js.cycle, js.stamp_s, t, &[0.0; 17], &[0.0; 17]),
        io_payload(f64::NAN, true, true),
    ];
    for len in [1, 5, 12, 34, 48, 130, 200] {
        for _ in 0..20 {
            payloads.push(bytes(len));
        }
    }
    let bad_before = cell.core.bad_inputs;
    for p in &payloads {
        cell.core.on_lifecycle(p, t);
        cell.core.on_io(p, t);
        cell.core.on_command(p, t, &mut out);
    }
    assert!(cell.core.bad_inputs - bad_before >= 2 * payloads.len() as u64 - 2);
    assert!(cell.core.rejected_for("bad_message") >= payloads.len() as u64 - 2);
    for id in [0u32, 0x100, 0x105, 0x106, 0x180, 0x7FF] {
        for len in [0usize, 1, 8, 26, 64] {
            let data = bytes(len);
            let mut f = Frame::fd(id, &data, false);
            f.len = len as u8;
            cell.core.on_frame(&f, t, &mut out, &mut s, &mut w);
            cell.core.on_frame(
                &error_frame(id & 0x1FF, &data[..len.min(8)]),
                t,
                &mut out,
                &mut s,
                &mut w,
            );
        }
    }
    let mut oversized = Frame::empty(0x100);
    oversized.len = 200;
    cell.core.on_frame(&oversized, t, &mut out, &mut s, &mut w);
    cell.try_cycle(Spec {
        q: [f64::NAN; N],
        ..Spec::default()
    }); // implausible: dropped
    cell.core.on_tick(t + 1.0, &mut out);
    cell.core.health(t + 1.0);
    cell.core.closing_frames(&mut out);
    // an adapter that reports a NaN position with the plausibility check off: no panic
    let mut cell = Cell::new(|c| c.feedback_max_joint_speed_rad_s = 0.0);
    cell.gateway("teaching");
    let (js, _) = cell.cycle(Spec::default());
    cell.command(&js, &Q0, 0.1);
    let (js, _) = cell.cycle(Spec {
        q: [f64::NAN; N],
        ..Spec::default()
    });
    assert!(js.q.iter().all(|v| v.is_nan()));
    cell.command(&js, &Q0, 0.0);
    cell.t += 0.01;
    cell.tick();
    cell.health();
    cell.core.closing_frames(&mut out);
}

#[test]
fn core_construction_refuses_what_does_not_fit() {
    let new = |cfg: CoreConfig, joints: usize, limits: (Vec<f64>, Vec<f64>)| {
        HostCore::new(
            cfg,
            Box::new(FakeAdapter::new(joints, None)),
            0.1,
            None,
            Some(datasheet_chain()),
            limits,
        )
        .err()
        .unwrap_or_default()
    };
    assert!(new(CoreConfig::default(), 5, limits()).contains("adapter is built for 5"));
    assert!(new(config(|c| c.heartbeat_period_s = 0.3), N, limits()).contains("heartbeat_period_s"));
    assert!(new(CoreConfig::default(), N, (vec![0.0; 5], vec![1.0; 6])).contains("joint limits"));
    assert!(
        new(config(|c| c.max_velocity_rad_s = vec![1.0; 3]), N, limits())
            .contains("max_velocity_rad_s")
    );
    let stored = Some((vec![0.1; N], 250, vec![0.02; N]));
    let core = HostCore::new(
        CoreConfig::default(),
        Box::new(FakeAdapter::new(N, None)),
        0.1,
        stored,
        Some(datasheet_chain()),
        limits(),
    );
    assert!(
        core.unwrap().current_zero.ready,
        "the commissioning's zero is ready at once"
    );
}
