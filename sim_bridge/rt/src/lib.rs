//! The virtual cell's compiled pieces (issue 45: the virtual cell's own CPU counts on a slow
//! machine that runs it beside the product).
//!
//! The virtual I/O module ([`io_module`]) answers the Modbus driver's polls on native threads
//! that never take Python's GIL: the simulator's loop and the module no longer share an
//! interpreter, so neither a child process nor pymodbus's event loop is needed to keep its
//! replies in time. The `python` feature adds the extension `sim_bridge._rt`.

pub mod io_module;

#[cfg(feature = "python")]
mod py_io_module;
