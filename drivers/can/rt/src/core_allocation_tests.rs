//! The core's allocations (core_tests.rs): a global allocator that counts each thread's, and
//! the forwarding path and a blocked cell allocating nothing per cycle.

use super::*;
use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell as StdCell;

/// The system allocator, counting the allocations each thread makes.
struct CountingAlloc;

thread_local! {
    static ALLOCATIONS: StdCell<u64> = const { StdCell::new(0) };
}

unsafe impl GlobalAlloc for CountingAlloc {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        let _ = ALLOCATIONS.try_with(|n| n.set(n.get() + 1));
        System.alloc(layout)
    }

    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        System.dealloc(ptr, layout)
    }

    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        let _ = ALLOCATIONS.try_with(|n| n.set(n.get() + 1));
        System.realloc(ptr, layout, new_size)
    }
}

#[global_allocator]
static COUNTING_ALLOC: CountingAlloc = CountingAlloc;

fn allocations() -> u64 {
    ALLOCATIONS.with(|n| n.get())
}

#[test]
fn core_the_allocation_counter_counts() {
    let before = allocations();
    let probe: Vec<u64> = std::hint::black_box(Vec::with_capacity(4));
    assert!(allocations() > before);
    drop(probe);
}

#[test]
fn core_the_forwarding_path_does_not_allocate() {
    let mut cell = Cell::new(|_| {});
    cell.gateway("teaching");
    cell.tick();
    let mut commands_in: Vec<Vec<u8>> = Vec::new();
    let mut frames_in: Vec<Vec<Frame>> = Vec::new();
    for k in 0..300 {
        frames_in.push(cell.frames(Spec::default()));
        commands_in.push(command_payload(
            k + 1,
            T0 + (k + 1) as f64 * PERIOD_S,
            0.0,
            &Q0,
            &[0.0; N],
        ));
    }
    // warm up: one cycle through every path the loop below takes
    let mut t = T0;
    let before = cell.core.forwarded;
    let run = |cell: &mut Cell, frames: &[Frame], cmd: &[u8], t: f64| {
        for f in frames {
            cell.out.clear();
            cell.core
                .on_frame(f, t, &mut cell.out, &mut cell.state, &mut cell.window);
        }
        cell.out.clear();
        cell.core.on_command(cmd, t + 0.001, &mut cell.out);
        cell.out.clear();
        cell.core.on_tick(t + 0.0015, &mut cell.out);
    };
    let refresh = |cell: &mut Cell, t: f64| {
        cell.seq += 1;
        let lc = lifecycle_payload("teaching", cell.seq, t);
        let io = io_payload(t, true, true);
        (lc, io)
    };
    for k in 0..5 {
        t += PERIOD_S;
        run(&mut cell, &frames_in[k], &commands_in[k], t);
    }
    let mut counted = 0;
    for k in 5..300 {
        t += PERIOD_S;
        if k % 25 == 0 {
            // the gateway's 20 Hz (its JSON decode is not on the cycle)
            let (lc, io) = refresh(&mut cell, t);
            cell.core.on_lifecycle(&lc, t);
            cell.core.on_io(&io, t);
        }
        let start = allocations();
        run(&mut cell, &frames_in[k], &commands_in[k], t);
        counted += allocations() - start;
    }
    assert_eq!(cell.core.forwarded - before, 300, "every command forwarded");
    assert_eq!(counted, 0, "allocations on the forwarding path");
}

#[test]
fn core_a_blocked_cell_does_not_allocate_per_cycle() {
    // READY for minutes: every cycle held at once, every command rejected (blocked); after
    // the first notes, the rate limit keeps the rest unbuilt
    let mut cell = Cell::new(|_| {});
    cell.gateway("ready");
    cell.tick();
    let frames_in: Vec<Vec<Frame>> = (0..220).map(|_| cell.frames(Spec::default())).collect();
    let commands_in: Vec<Vec<u8>> = (0..220u32)
        .map(|k| command_payload(k + 1, T0, 0.0, &Q0, &[0.0; N]))
        .collect();
    let mut counted = 0;
    for k in 0..220 {
        let t = T0 + k as f64 * PERIOD_S;
        if k % 25 == 0 {
            // the gateway's 20 Hz (its JSON decode is not on the cycle)
            cell.seq += 1;
            let lc = lifecycle_payload("ready", cell.seq, t);
            cell.core.on_lifecycle(&lc, t);
            cell.core.on_io(&io_payload(t, true, true), t);
        }
        let start = allocations();
        for f in &frames_in[k] {
            cell.out.clear();
            cell.core
                .on_frame(f, t, &mut cell.out, &mut cell.state, &mut cell.window);
        }
        cell.out.clear();
        let outcome = cell
            .core
            .on_command(&commands_in[k], t + 0.001, &mut cell.out);
        assert_eq!(outcome.answer, Answer::None);
        cell.out.clear();
        cell.core.on_tick(t + 0.0015, &mut cell.out);
        if k >= 10 {
            counted += allocations() - start;
        }
    }
    assert_eq!(cell.core.rejected_for("blocked_lifecycle"), 220);
    assert_eq!(cell.core.held, 220);
    assert_eq!(counted, 0, "allocations while blocked");
    let notes = cell.core.take_notes();
    assert_eq!(
        notes.iter().filter(|n| n.1 == "blocked_lifecycle").count(),
        1
    );
}
