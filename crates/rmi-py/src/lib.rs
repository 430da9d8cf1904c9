//! Python binding of the rmi SPH engine, imported as `rmi_sph._rmi_sph`.
//!
//! Kept thin on purpose: physics, validation and error texts live in the `rmi-sph` crate, and
//! this crate only converts types and errors. The Python package `rmi_sph` re-exports it.

mod errors;

use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;
use pyo3::types::PyDict;
use rmi_sph::RmiError as CoreError;

/// Same version as the Rust crates (one workspace version) and the Python distribution, which
/// maturin derives from Cargo.toml.
const VERSION: &str = env!("CARGO_PKG_VERSION");

/// Build facts of the engine, as a dict of strings.
///
/// Keys: ``version`` (package version), ``kernel`` (SPH smoothing kernel and its support
/// radius H relative to the particle radius r), ``float`` (floating-point type of the state).
#[pyfunction]
fn engine_info(py: Python<'_>) -> PyResult<Bound<'_, PyDict>> {
    let info = PyDict::new(py);
    info.set_item("version", VERSION)?;
    info.set_item("kernel", "cubic spline, H = 4r")?;
    info.set_item("float", "f64")?;
    Ok(info)
}

/// Raises the exception that a core error of the given kind maps to (for testing the mapping).
///
/// ``kind`` is one of ``"config"``, ``"unstable"``, ``"state"``, ``"io"``.
#[pyfunction]
fn _raise_error(kind: &str) -> PyResult<()> {
    let error = match kind {
        "config" => CoreError::InvalidConfig {
            field: "solver.dt".to_owned(),
            value: "0.5".to_owned(),
            expected: "a time step in (0, 0.01] s".to_owned(),
        },
        "unstable" => CoreError::Unstable {
            step: 42,
            time: 0.021,
            max_velocity: f64::INFINITY,
            reason: "particle speed exceeded the CFL limit".to_owned(),
        },
        "state" => CoreError::State("particle count 10 does not match 12".to_owned()),
        "io" => CoreError::Io(std::io::Error::new(std::io::ErrorKind::NotFound, "snapshot.bin not found")),
        other => {
            return Err(PyValueError::new_err(format!(
                "unknown error kind {other:?}; expected config, unstable, state or io"
            )))
        }
    };
    Err(errors::to_pyerr(error))
}

#[pymodule]
fn _rmi_sph(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add("__version__", VERSION)?;
    m.add_function(wrap_pyfunction!(engine_info, m)?)?;
    m.add_function(wrap_pyfunction!(_raise_error, m)?)?;
    errors::register(m)?;
    Ok(())
}
