//! The virtual I/O module: the cell's pressure transmitters, valves, enabling device, e-stop
//! chain and mark button behind a Modbus TCP server (the register table is documented in
//! `sim_bridge/modbus_server.py`, the module's manual).

pub mod encoding;
pub mod image;
pub mod pdu;
pub mod server;

pub use image::{Inputs, Module};
pub use server::Server;
