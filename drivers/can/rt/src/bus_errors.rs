//! CAN bus errors as the interface reports them, and the fault they latch
//! (drivers/can/bus_errors.py, issue 10).
//!
//! SocketCAN delivers the CAN controller's problems as *error frames*
//! (`linux/can/error.h`): the frame's id holds the error class bits, its data the details
//! ([`Frame::error`] set, the class in [`Frame::id`]). [`BusErrors`] reads them:
//!
//! - **bus-off** ([`CAN_ERR_BUSOFF`]): the host's CAN controller has taken itself off the bus;
//!   the kernel restarts the interface after `restart-ms` and reports [`CAN_ERR_RESTARTED`].
//!   A bus-off latches a fault;
//! - **a burst of bus errors**: `[can] bus_error_limit` error frames of any class within
//!   `bus_error_window_s` latch a fault (a wiring or termination problem);
//! - **error passive** ([`CAN_ERR_CRTL`] with [`CAN_ERR_CRTL_RX_PASSIVE`] /
//!   [`CAN_ERR_CRTL_TX_PASSIVE`]): counted and reported, the warning before bus-off.
//!
//! The latched fault blocks forwarding (`blocked_bus`), makes the driver ask for the brakes,
//! goes to the gateway in the health (`bus_fault`) and faults the cell. It clears only when
//! both hold: the bus works again (no error frame for `bus_error_window_s` and a complete
//! cycle received since the last), and the gateway has stopped the cell.

use serde_json::{Map, Value};

use crate::frame::Frame;
use crate::lost_cycles::RecentTimes;
use crate::messages::fmt_g;

/// Error class bits of an error frame's id (linux/can/error.h).
pub const CAN_ERR_TX_TIMEOUT: u32 = 0x001;
pub const CAN_ERR_LOSTARB: u32 = 0x002;
pub const CAN_ERR_CRTL: u32 = 0x004;
pub const CAN_ERR_PROT: u32 = 0x008;
pub const CAN_ERR_TRX: u32 = 0x010;
pub const CAN_ERR_ACK: u32 = 0x020;
pub const CAN_ERR_BUSOFF: u32 = 0x040;
pub const CAN_ERR_BUSERROR: u32 = 0x080;
pub const CAN_ERR_RESTARTED: u32 = 0x100;
/// data[1] of a CAN_ERR_CRTL frame: the receive error counter passed 127.
pub const CAN_ERR_CRTL_RX_PASSIVE: u8 = 0x10;
/// data[1] of a CAN_ERR_CRTL frame: the transmit error counter passed 127.
pub const CAN_ERR_CRTL_TX_PASSIVE: u8 = 0x20;

const NAMES: [(u32, &str); 9] = [
    (CAN_ERR_TX_TIMEOUT, "tx timeout"),
    (CAN_ERR_LOSTARB, "lost arbitration"),
    (CAN_ERR_CRTL, "controller problem"),
    (CAN_ERR_PROT, "protocol violation"),
    (CAN_ERR_TRX, "transceiver problem"),
    (CAN_ERR_ACK, "no acknowledge"),
    (CAN_ERR_BUSOFF, "bus-off"),
    (CAN_ERR_BUSERROR, "bus error"),
    (CAN_ERR_RESTARTED, "restarted"),
];

/// The error classes set in `error_class`, in words ("bus-off, restarted").
pub fn describe(error_class: u32) -> String {
    let names: Vec<&str> = NAMES
        .iter()
        .filter(|(bit, _)| error_class & bit != 0)
        .map(|(_, name)| *name)
        .collect();
    if names.is_empty() {
        format!("class 0x{error_class:X}")
    } else {
        names.join(", ")
    }
}

/// The error frames seen and the fault they latched (module docs). Allocates its window of
/// error times at construction; a frame allocates only the text of a fault it latches.
#[derive(Clone, Debug)]
pub struct BusErrors {
    /// error frames within the window that latch a fault
    pub limit: i64,
    /// the window of the burst rule [s]
    pub window_s: f64,
    /// the latched fault, in words
    pub fault: Option<String>,
    /// error frames seen (monotonic)
    pub error_frames: u64,
    /// bus-offs seen
    pub bus_off: u64,
    /// interface restarts seen
    pub restarts: u64,
    /// error-passive reports seen
    pub error_passive: u64,
    recent: RecentTimes,
    last_error_s: f64,
    cycle_since_error: bool,
}

impl BusErrors {
    /// `limit` error frames within `window_s` [s] latch a fault.
    pub fn new(limit: i64, window_s: f64) -> BusErrors {
        BusErrors {
            limit,
            window_s,
            fault: None,
            error_frames: 0,
            bus_off: 0,
            restarts: 0,
            error_passive: 0,
            recent: RecentTimes::new(limit.max(1) as usize),
            last_error_s: f64::NEG_INFINITY,
            cycle_since_error: true,
        }
    }

    /// Take one error frame at `now` [s]; the fault it latches (once), else None.
    pub fn on_error_frame(&mut self, msg: &Frame, now: f64) -> Option<String> {
        let cls = msg.id;
        self.error_frames += 1;
        self.last_error_s = now;
        self.cycle_since_error = false;
        self.recent.push_and_prune(now, self.window_s);
        let data = msg.payload();
        let passive = CAN_ERR_CRTL_RX_PASSIVE | CAN_ERR_CRTL_TX_PASSIVE;
        if cls & CAN_ERR_CRTL != 0 && data.len() > 1 && data[1] & passive != 0 {
            self.error_passive += 1;
        }
        if cls & CAN_ERR_RESTARTED != 0 {
            self.restarts += 1;
        }
        if self.fault.is_some() {
            return None;
        }
        if cls & CAN_ERR_BUSOFF != 0 {
            self.bus_off += 1;
            self.fault =
                Some("the CAN interface went bus-off (the host's controller left the bus)".into());
        } else if self.recent.len() as i64 >= self.limit {
            self.fault = Some(format!(
                "{} CAN error frames within {} s (last: {})",
                self.recent.len(),
                fmt_g(self.window_s),
                describe(cls)
            ));
        }
        self.fault.clone()
    }

    /// A complete controller cycle arrived: the bus carries frames again.
    pub fn on_cycle(&mut self) {
        self.cycle_since_error = true;
    }

    /// The bus works again: no error frame for the window, a cycle since the last.
    pub fn recovered(&self, now: f64) -> bool {
        self.cycle_since_error && now - self.last_error_s >= self.window_s
    }

    /// Clear the fault if the bus has recovered (the caller knows the cell is stopped); true
    /// if it was cleared.
    pub fn clear(&mut self, now: f64) -> bool {
        if self.fault.is_none() || !self.recovered(now) {
            return false;
        }
        self.fault = None;
        true
    }

    /// The health entries: bus_fault, bus_error_frames, bus_off, bus_restarts,
    /// bus_error_passive.
    pub fn health(&self) -> Map<String, Value> {
        let mut h = Map::new();
        h.insert(
            "bus_fault".into(),
            self.fault.clone().map_or(Value::Null, Value::from),
        );
        h.insert("bus_error_frames".into(), Value::from(self.error_frames));
        h.insert("bus_off".into(), Value::from(self.bus_off));
        h.insert("bus_restarts".into(), Value::from(self.restarts));
        h.insert("bus_error_passive".into(), Value::from(self.error_passive));
        h
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// An error frame of class `cls` (test_can_core.py `error_frame`).
    fn error_frame(cls: u32, data: &[u8]) -> Frame {
        let mut f = Frame::classic(cls, data);
        f.error = true;
        f
    }

    #[test]
    fn a_bus_off_latches_until_the_bus_works_again() {
        // test_can_core.py test_a_bus_off_latches_a_bus_fault_until_the_bus_works_and_the_
        // cell_is_stopped, the BusErrors part
        let mut bus = BusErrors::new(10, 0.5);
        let mut t = 500.0;
        let passive = error_frame(CAN_ERR_CRTL, &[0, 0x20, 0, 0, 0, 0, 0, 0]);
        assert_eq!(bus.on_error_frame(&passive, t), None);
        assert_eq!((bus.fault.as_deref(), bus.error_passive), (None, 1));
        let fault = bus.on_error_frame(&error_frame(CAN_ERR_BUSOFF, &[0; 8]), t);
        assert!(fault.unwrap().contains("bus-off"));
        let h = bus.health();
        assert!(h["bus_fault"].as_str().unwrap().contains("bus-off"));
        assert_eq!(h["bus_off"], 1);
        t += 0.1; // the kernel restarts the interface (restart-ms)
        assert_eq!(
            bus.on_error_frame(&error_frame(CAN_ERR_RESTARTED, &[0; 8]), t),
            None,
            "latched once"
        );
        assert!(!bus.clear(t + 0.8), "no cycle since the last error frame");
        bus.on_cycle();
        assert!(!bus.clear(t + 0.4), "an error frame within the window");
        assert!(bus.fault.is_some());
        assert!(bus.clear(t + 0.5));
        let h = bus.health();
        assert_eq!(h["bus_fault"], Value::Null);
        assert_eq!(
            (
                &h["bus_restarts"],
                &h["bus_error_frames"],
                &h["bus_error_passive"]
            ),
            (&Value::from(1), &Value::from(3), &Value::from(1))
        );
        assert_eq!(h.len(), 5);
    }

    #[test]
    fn a_burst_of_bus_errors_latches_a_fault_and_scattered_ones_do_not() {
        // test_can_core.py test_a_burst_of_bus_errors_latches_a_fault_and_scattered_ones_do_not
        let mut bus = BusErrors::new(5, 1.0);
        let mut t = 500.0;
        for _ in 0..8 {
            // one every 0.3 s: never 5 within a second
            t += 0.3;
            assert_eq!(
                bus.on_error_frame(&error_frame(CAN_ERR_PROT, &[0; 8]), t),
                None
            );
        }
        assert!(bus.fault.is_none());
        assert_eq!(bus.error_frames, 8);
        let mut latched = None;
        for _ in 0..5 {
            t += 0.01;
            latched = latched.or(bus.on_error_frame(&error_frame(CAN_ERR_PROT, &[0; 8]), t));
        }
        let fault = bus.fault.clone().unwrap();
        assert_eq!(latched, Some(fault.clone()));
        assert!(fault.contains("5 CAN error frames within 1 s"));
        assert!(fault.contains("protocol violation"));
    }

    #[test]
    fn error_classes_in_words() {
        assert_eq!(
            describe(CAN_ERR_BUSOFF | CAN_ERR_RESTARTED),
            "bus-off, restarted"
        );
        assert_eq!(describe(0x200), "class 0x200");
    }
}
