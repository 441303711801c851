//! The CAN driver's cycle, compiled (issue 48): frame in → joint state → zenoh; command from
//! zenoh → checks → frames out, with no Python interpreter on it and no allocation per cycle.
//!
//! The pure logic (frames, codecs, adapters, monitors, the host core) is plain Rust, tested
//! with `cargo test`. The `python` feature adds the extension `drivers.can._rt`: the loop
//! thread, its CAN socket and zenoh session, and the bindings the Python driver process uses to
//! configure, supervise and report it (drivers/can/driver.py).

pub mod adapter;
pub mod bus_errors;
pub mod cia402;
pub mod codec;
pub mod core;
pub mod core_config;
#[cfg(test)]
mod core_tests;
pub mod current_zero;
pub mod frame;
pub mod frame_crc;
pub mod histogram;
pub mod lifecycle;
pub mod lost_cycles;
pub mod ltc_adapter;
mod ltc_base;
mod ltc_enums;
pub mod ltc_fd_adapter;
mod ltc_status;
pub mod plausibility;
pub mod ramp_start;
pub mod speed_monitor;
pub mod stop_ramp;
pub mod window;

/// The bus contract (gateway/rt): the messages, shared with every compiled piece.
pub use bus_rt::messages;

#[cfg(feature = "python")]
pub mod can_socket;
#[cfg(feature = "python")]
pub mod driver_loop;
#[cfg(feature = "python")]
mod py;
