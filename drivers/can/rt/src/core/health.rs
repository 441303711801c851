//! The core's health message (core.rs): Python's `HostCore.health()` keys and value types, the
//! current zero's part of it, and the adapter's own entries.

use serde_json::{Map, Value};

use super::notes::WARNING;
use super::{HostCore, REJECT_REASONS};
use crate::adapter::ControllerState;

/// `round(x, digits)` for the health message.
fn round_to(x: f64, digits: i32) -> f64 {
    let scale = 10f64.powi(digits);
    (x * scale).round() / scale
}

fn rounded(values: &[f64], digits: i32) -> Value {
    Value::Array(
        values
            .iter()
            .map(|&v| Value::from(round_to(v, digits)))
            .collect(),
    )
}

impl HostCore {
    /// The current zero's part of the health (current_zero.rs), and a warning when the fresh
    /// zero has drifted from the commissioning's.
    fn zero_health(&mut self, now: f64, h: &mut Map<String, Value>) {
        let zero = &self.current_zero;
        let noise = zero.noise_a();
        let drift = zero.drift_a();
        if let Some(d) = drift.as_ref() {
            if zero.drift_significant(Some(&noise)) {
                self.notes.note(WARNING, "zero-drift", now, || {
                    let rounded: Vec<f64> = d.iter().map(|&v| round_to(v, 4)).collect();
                    format!(
                        "the current sensors' zero measured now differs from the commissioning's by \
                         {rounded:?} A, more than noise explains: commission again (`leadthrough identify`)"
                    )
                });
            }
        }
        let zero = &self.current_zero;
        h.insert(
            "current_zero_a".into(),
            rounded(&zero.offset_a[..self.n], 4),
        );
        h.insert("current_zero_source".into(), Value::from(zero.source()));
        h.insert(
            "current_zero_samples".into(),
            Value::from(zero.samples as u64),
        );
        h.insert("current_zero_ready".into(), Value::from(zero.ready));
        h.insert(
            "current_zero_measured_a".into(),
            rounded(&zero.measured_a[..self.n], 4),
        );
        h.insert("current_zero_noise_a".into(), rounded(&noise, 5));
        h.insert(
            "current_zero_drift_a".into(),
            drift.map_or(Value::Null, |d| rounded(&d, 4)),
        );
    }

    /// The health message's entries (Python's `HostCore.health()`: the same keys and value
    /// types), then the adapter's own entries (a key the core has keeps the core's value).
    pub fn health(&mut self, now: f64) -> Map<String, Value> {
        self.last_now = now;
        let mut h = Map::new();
        let fb = self.feedback;
        let (bad_frames, incomplete_cycles, corrupt_cycles) = {
            let s = self.adapter.stats();
            (s.bad_frames, s.incomplete_cycles, s.corrupt_cycles)
        };
        let opt_str = |s: Option<String>| s.map_or(Value::Null, Value::from);
        h.insert(
            "controller_state".into(),
            fb.map_or(Value::Null, |f| Value::from(f.controller_state.name())),
        );
        h.insert(
            "controller_fault".into(),
            fb.map_or(Value::Null, |f| Value::from(f.fault)),
        );
        // the operator's reason for a FAULT: the adapter's words, else the fault's kind
        let faulted = fb.filter(|f| f.controller_state == ControllerState::Fault);
        h.insert(
            "controller_fault_text".into(),
            faulted.map_or(Value::Null, |f| {
                Value::from(self.adapter.fault_detail().unwrap_or(f.fault))
            }),
        );
        h.insert("link_ok".into(), Value::from(self.link_ok(now)));
        h.insert(
            "servo_request".into(),
            self.request_sent
                .map_or(Value::Null, |r| Value::from(r.name())),
        );
        h.insert("cycles".into(), Value::from(self.cycles));
        h.insert("forwarded".into(), Value::from(self.forwarded));
        h.insert("held".into(), Value::from(self.held));
        h.insert("ramped".into(), Value::from(self.ramped));
        h.insert(
            "standstill_trip".into(),
            opt_str(self.standstill.trip.as_ref().map(|t| t.message())),
        );
        h.insert("lost_cycles".into(), Value::from(self.lost.lost as u64));
        h.insert(
            "lost_cycles_trip".into(),
            opt_str(self.lost.trip.as_ref().map(|t| t.message())),
        );
        h.insert("coasted".into(), Value::from(self.coasted));
        h.insert("unanswered".into(), Value::from(self.unanswered));
        let mut rejected = Map::new();
        for (reason, count) in REJECT_REASONS.iter().zip(self.rejected) {
            rejected.insert((*reason).into(), Value::from(count));
        }
        h.insert("rejected".into(), Value::Object(rejected));
        h.insert("bad_frames".into(), Value::from(bad_frames));
        // frames of ids the protocol does not define: ignored, counted (the fuzz tests read it)
        h.insert(
            "unknown_frames".into(),
            Value::from(self.adapter.stats().unknown_frames),
        );
        h.insert(
            "implausible_cycles".into(),
            Value::from(self.plausibility.dropped),
        );
        h.insert("incomplete_cycles".into(), Value::from(incomplete_cycles));
        h.insert("corrupt_cycles".into(), Value::from(corrupt_cycles));
        h.insert("bad_inputs".into(), Value::from(self.bad_inputs));
        h.insert(
            "lifecycle_dropped".into(),
            Value::Object(self.lifecycle_order.dropped()),
        );
        match self.speed.as_ref() {
            None => {
                h.insert("speed_trip".into(), Value::Null);
                h.insert("speed_peak_m_s".into(), Value::Null);
            }
            Some(monitor) => {
                h.insert(
                    "speed_trip".into(),
                    opt_str(monitor.trip.as_ref().map(|t| t.message())),
                );
                h.insert(
                    "speed_peak_m_s".into(),
                    Value::from(round_to(monitor.peak_m_s, 4)),
                );
            }
        }
        for (k, v) in self.bus.health() {
            h.insert(k, v);
        }
        self.zero_health(now, &mut h);
        for (k, v) in self.adapter.health(now) {
            h.entry(k).or_insert(v);
        }
        h
    }
}
