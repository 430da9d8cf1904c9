//! Keeps Rust panics from crossing into Python: every engine call runs inside
//! [`catch`], and a caught panic becomes an `RmiError` ("internal error") instead of pyo3's
//! `PanicException` (a `BaseException` that `except Exception` would not catch).

use crate::errors::{to_pyerr, RmiError};
use pyo3::PyErr;
use std::panic::{catch_unwind, AssertUnwindSafe};

/// What an engine call produced: its result, or the text of a panic.
pub type Caught<T> = Result<rmi_sph::Result<T>, String>;

/// Runs `f`, catching a panic (safe to call with the GIL released: no Python objects).
pub fn catch<T>(f: impl FnOnce() -> rmi_sph::Result<T>) -> Caught<T> {
    catch_unwind(AssertUnwindSafe(f)).map_err(|payload| {
        payload
            .downcast_ref::<&str>()
            .map(|s| (*s).to_owned())
            .or_else(|| payload.downcast_ref::<String>().cloned())
            .unwrap_or_else(|| "unknown panic payload".to_owned())
    })
}

/// The Python error for a caught panic.
pub fn panic_err(message: &str) -> PyErr {
    RmiError::new_err(format!("internal error in the rmi engine (Rust panic: {message}); please report it"))
}

/// [`into_py`] for a call that read or wrote `path` (see [`crate::errors::at_path`]).
pub fn into_py_at<T>(c: Caught<T>, path: &std::path::Path) -> Result<T, PyErr> {
    into_py_with(c, |e| crate::errors::at_path(e, path))
}

/// Converts a caught result into a Python result.
pub fn into_py<T>(c: Caught<T>) -> Result<T, PyErr> {
    into_py_with(c, to_pyerr)
}

/// A caught result as a Python result, engine errors mapped by `map`.
fn into_py_with<T>(c: Caught<T>, map: impl FnOnce(rmi_sph::RmiError) -> PyErr) -> Result<T, PyErr> {
    match c {
        Ok(Ok(v)) => Ok(v),
        Ok(Err(e)) => Err(map(e)),
        Err(msg) => Err(panic_err(&msg)),
    }
}
