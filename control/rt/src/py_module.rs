//! The extension module `control._rt` (the `python` feature): every compiled class the
//! control process and the tests use, each registered by its own binding file.

use pyo3::prelude::*;

#[pymodule]
fn _rt(m: &Bound<'_, PyModule>) -> PyResult<()> {
    crate::py::register(m)?;
    crate::py_inner_estimate::register(m)?;
    crate::py_delay::register(m)?;
    crate::py_guided_friction::register(m)?;
    crate::py_rest_hold::register(m)?;
    crate::py_outer_loop::register(m)?;
    crate::py_admittance::register(m)?;
    crate::py_admittance_cycle::register(m)?;
    crate::py_zero_moment::register(m)?;
    crate::py_plan_play::register(m)?;
    crate::py_cycle_loop::register(m)?;
    Ok(())
}
