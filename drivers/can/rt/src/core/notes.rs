//! The core's notes (core.rs): conditions worth a log line, rate-limited per key and queued in
//! a bounded queue for the shell to drain, their text built only when a note is kept.

use std::collections::VecDeque;
use std::fmt::Write as _;

use crate::messages::fmt_g;

/// Log levels of notes (Python's logging levels).
pub const DEBUG: u8 = 10;
pub const INFO: u8 = 20;
pub const WARNING: u8 = 30;
pub const ERROR: u8 = 40;

/// At most one note per key per this long; the next says how many were held back [s]
/// (driver.py LOG_PERIOD_S).
pub const NOTE_PERIOD_S: f64 = 1.0;
/// Notes kept until the shell drains them; more are counted and dropped.
pub const NOTE_QUEUE: usize = 64;

/// The rate-limited, bounded note queue (gateway/ratelog.py RateLimitedLog, per key).
pub(super) struct Notes {
    queue: VecDeque<(u8, String, String)>,
    /// (key, when its last note was kept [s], notes held back since)
    keys: Vec<(&'static str, f64, u64)>,
    /// notes that found the queue full
    dropped: u64,
}

impl Notes {
    pub(super) fn new() -> Notes {
        Notes {
            queue: VecDeque::with_capacity(NOTE_QUEUE),
            keys: Vec::with_capacity(64),
            dropped: 0,
        }
    }

    /// At most one note per `key` and [`NOTE_PERIOD_S`]; `message` runs only for a kept one.
    pub(super) fn note(
        &mut self,
        level: u8,
        key: &'static str,
        now: f64,
        message: impl FnOnce() -> String,
    ) {
        let suppressed = match self.keys.iter_mut().find(|e| e.0 == key) {
            Some(entry) => {
                if now - entry.1 < NOTE_PERIOD_S {
                    entry.2 += 1;
                    return;
                }
                entry.1 = now;
                std::mem::take(&mut entry.2)
            }
            None => {
                self.keys.push((key, now, 0));
                0
            }
        };
        self.push(level, key, suppressed, message);
    }

    /// A note that is not rate-limited (Python logged these directly: each happens once per
    /// change of state).
    pub(super) fn always(
        &mut self,
        level: u8,
        key: &'static str,
        message: impl FnOnce() -> String,
    ) {
        self.push(level, key, 0, message);
    }

    fn push(
        &mut self,
        level: u8,
        key: &'static str,
        suppressed: u64,
        message: impl FnOnce() -> String,
    ) {
        if self.queue.len() >= NOTE_QUEUE {
            self.dropped += 1;
            return;
        }
        let mut text = message();
        if suppressed > 0 {
            let _ = write!(
                text,
                " (+{suppressed} similar in the last {} s)",
                fmt_g(NOTE_PERIOD_S)
            );
        }
        self.queue.push_back((level, key.to_string(), text));
    }

    pub(super) fn take(&mut self) -> Vec<(u8, String, String)> {
        let mut out: Vec<_> = self.queue.drain(..).collect();
        if self.dropped > 0 {
            out.push((
                WARNING,
                "notes".to_string(),
                format!(
                    "{} notes dropped: the queue of {NOTE_QUEUE} was full",
                    self.dropped
                ),
            ));
            self.dropped = 0;
        }
        out
    }
}
