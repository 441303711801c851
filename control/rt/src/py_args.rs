//! Argument checks every binding file shares: a Python sequence of the wrong length is a
//! ValueError naming what it is, before anything is computed.

use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;

/// `v` holds `n` values, or a ValueError naming `what`.
pub(crate) fn check_len(v: &[f64], n: usize, what: &str) -> PyResult<()> {
    if v.len() != n {
        return Err(PyValueError::new_err(format!(
            "{what} needs {n} values, got {}",
            v.len()
        )));
    }
    Ok(())
}
