//! The control law's per-cycle model, compiled (issue 48): the rigid-body chain, friction,
//! the identified effects and the cylinders, evaluated for one state with no allocation.
//!
//! The pure arithmetic is plain Rust, tested with `cargo test`; the `python` feature adds the
//! extension `control._rt` the control process calls (control/rt_tables.py builds its tables).

pub mod chain;
pub mod cylinders;
pub mod effects;
pub mod friction;
pub mod law;
pub mod point_model;
pub mod spatial;
pub mod table;

#[cfg(feature = "python")]
mod py;
#[cfg(feature = "python")]
mod py_admittance;
#[cfg(feature = "python")]
mod py_admittance_cycle;
#[cfg(feature = "python")]
mod py_args;
#[cfg(feature = "python")]
mod py_cycle_law;
#[cfg(feature = "python")]
mod py_cycle_loop;
#[cfg(feature = "python")]
mod py_delay;
#[cfg(feature = "python")]
mod py_guided_friction;
#[cfg(feature = "python")]
mod py_inner_estimate;
#[cfg(feature = "python")]
mod py_module;
#[cfg(feature = "python")]
mod py_outer_loop;
#[cfg(feature = "python")]
mod py_plan_play;
#[cfg(feature = "python")]
mod py_rest_hold;
#[cfg(feature = "python")]
mod py_zero_moment;
