//! Python exception classes of `rmi_sph` and the mapping from the core's `RmiError`.
//!
//! The tree, as Python sees it:
//!
//! ```text
//! Exception
//! └── RmiError
//!     ├── ConfigError              (also a ValueError)
//!     ├── SimulationUnstableError
//!     └── StateError
//! ```
//!
//! `ConfigError` also derives from `ValueError` so that code written against plain Python
//! conventions (`except ValueError`) still catches a bad parameter. `create_exception!` takes a
//! single base, so that one class is built with Python's `type()` instead.

use pyo3::create_exception;
use pyo3::exceptions::{PyException, PyValueError};
use pyo3::prelude::*;
use pyo3::sync::PyOnceLock;
use pyo3::types::{PyDict, PyTuple, PyType};
use pyo3::IntoPyObjectExt;
use rmi_sph::RmiError as CoreError;

/// Module path the classes report in `__module__` (and tracebacks); it is where they live.
const MODULE: &str = "rmi_sph._rmi_sph";

create_exception!(rmi_sph._rmi_sph, RmiError, PyException, "Base class of every error raised by the rmi engine.");
create_exception!(
    rmi_sph._rmi_sph,
    SimulationUnstableError,
    RmiError,
    "The simulation diverged; the state is left at the last good step.\n\n\
     Attributes: ``step`` (int), ``time`` (float, s), ``max_velocity`` (float, m/s), \
     ``reason`` (str)."
);
create_exception!(
    rmi_sph._rmi_sph,
    StateError,
    RmiError,
    "A snapshot or state dictionary does not fit this simulation."
);

const CONFIG_ERROR_DOC: &str = "A configuration value is outside its accepted range.\n\n\
     Also a ValueError. Attributes: ``field`` (dotted path of the field), ``value`` (the \
     offending value, as text), ``expected`` (the accepted range or form, with units).";

/// The `ConfigError` class, created on first use and then shared.
pub fn config_error_type(py: Python<'_>) -> PyResult<&Bound<'_, PyType>> {
    static CONFIG_ERROR: PyOnceLock<Py<PyType>> = PyOnceLock::new();
    CONFIG_ERROR
        .get_or_try_init(py, || {
            let bases = PyTuple::new(py, [py.get_type::<RmiError>(), py.get_type::<PyValueError>()])?;
            let namespace = PyDict::new(py);
            namespace.set_item("__module__", MODULE)?;
            namespace.set_item("__doc__", CONFIG_ERROR_DOC)?;
            let class = py.import("builtins")?.getattr("type")?.call1(("ConfigError", bases, namespace))?;
            Ok::<_, PyErr>(class.cast_into::<PyType>()?.unbind())
        })
        .map(|class| class.bind(py))
}

/// Adds the exception classes to the module.
pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    let py = m.py();
    m.add("RmiError", py.get_type::<RmiError>())?;
    m.add("ConfigError", config_error_type(py)?)?;
    m.add("SimulationUnstableError", py.get_type::<SimulationUnstableError>())?;
    m.add("StateError", py.get_type::<StateError>())?;
    Ok(())
}

/// Converts a core error into the matching Python exception.
///
/// The message is the core's `Display` text; the structured fields are also set as attributes
/// so callers can react to them (e.g. retry with a smaller time step) without parsing text.
/// A free function rather than `From<RmiError> for PyErr`: both types are foreign to this crate
/// (orphan rule), so use `.map_err(to_pyerr)`.
pub fn to_pyerr(e: CoreError) -> PyErr {
    // If building the exception itself fails, raise that failure rather than panic.
    Python::attach(|py| build_pyerr(py, e).unwrap_or_else(|failure| failure))
}

fn build_pyerr(py: Python<'_>, e: CoreError) -> PyResult<PyErr> {
    let message = e.to_string();
    Ok(match e {
        CoreError::InvalidConfig { field, value, expected } => {
            let err = PyErr::from_type(config_error_type(py)?.clone(), message);
            set_attrs(
                py,
                &err,
                [
                    ("field", field.into_bound_py_any(py)?),
                    ("value", value.into_bound_py_any(py)?),
                    ("expected", expected.into_bound_py_any(py)?),
                ],
            )?;
            err
        }
        CoreError::Unstable { step, time, max_velocity, reason } => {
            let err = SimulationUnstableError::new_err(message);
            set_attrs(
                py,
                &err,
                [
                    ("step", step.into_bound_py_any(py)?),
                    ("time", time.into_bound_py_any(py)?),
                    ("max_velocity", max_velocity.into_bound_py_any(py)?),
                    ("reason", reason.into_bound_py_any(py)?),
                ],
            )?;
            err
        }
        CoreError::State(_) => StateError::new_err(message),
        // pyo3 maps the io::ErrorKind to the matching OSError subclass (FileNotFoundError, ...).
        CoreError::Io(err) => err.into(),
    })
}

/// A Python integer of any size, clamped to the 128-bit range (for `from_py_with`, so that
/// a huge value reaches the range check of [`int_arg`] instead of raising `OverflowError`).
pub fn any_int(value: &Bound<'_, PyAny>) -> PyResult<i128> {
    match value.extract::<i128>() {
        Ok(v) => Ok(v),
        Err(e) if e.is_instance_of::<pyo3::exceptions::PyOverflowError>(value.py()) => {
            Ok(if value.lt(0)? { i128::MIN } else { i128::MAX })
        }
        Err(e) => Err(e),
    }
}

/// [`any_int`] for an optional argument.
pub fn any_int_opt(value: &Bound<'_, PyAny>) -> PyResult<Option<i128>> {
    if value.is_none() {
        return Ok(None);
    }
    any_int(value).map(Some)
}

/// An integer argument as the type `T`, or a `ConfigError` naming `field` with the
/// `expected` range.
pub fn int_arg<T: TryFrom<i128>>(value: i128, field: &str, expected: &str) -> PyResult<T> {
    T::try_from(value).map_err(|_| to_pyerr(CoreError::config(field, shown(value), expected)))
}

/// An integer as errors show it (a clamped one as beyond the 128-bit range).
fn shown(value: i128) -> String {
    match value {
        i128::MAX => "(an integer of 127 bits or more)".to_owned(),
        i128::MIN => "(a negative integer of 127 bits or more)".to_owned(),
        v => v.to_string(),
    }
}

/// A `num_threads` argument: `None` keeps the default; one outside 1 to the engine's
/// maximum is the engine's own `num_threads` error, whatever its size.
pub fn threads(value: Option<i128>) -> PyResult<Option<usize>> {
    value
        .map(|v| {
            usize::try_from(v)
                .ok()
                .filter(|n| rmi_sph::simulation::check_threads(*n).is_ok())
                .ok_or_else(|| to_pyerr(rmi_sph::simulation::threads_error(shown(v))))
        })
        .transpose()
}

/// The Python error of an engine call that read or wrote `path`: an I/O failure becomes the
/// matching `OSError` subclass with the path as its `filename` (so its text names the file);
/// other errors map as in [`to_pyerr`].
pub fn at_path(e: CoreError, path: &std::path::Path) -> PyErr {
    match e {
        CoreError::Io(err) => match err.raw_os_error() {
            // OSError(errno, strerror, filename) picks the subclass (FileNotFoundError, ...).
            Some(code) => {
                let text = std::io::Error::from_raw_os_error(code).to_string();
                let strerror = text.trim_end_matches(&format!(" (os error {code})")).to_owned();
                pyo3::exceptions::PyOSError::new_err((code, strerror, path.display().to_string()))
            }
            // The engine's own texts may name the path already.
            None if err.to_string().contains(&*path.to_string_lossy()) => {
                pyo3::exceptions::PyOSError::new_err(err.to_string())
            }
            None => pyo3::exceptions::PyOSError::new_err(format!("{}: {err}", path.display())),
        },
        other => to_pyerr(other),
    }
}

fn set_attrs<const N: usize>(py: Python<'_>, err: &PyErr, attrs: [(&str, Bound<'_, PyAny>); N]) -> PyResult<()> {
    let instance = err.value(py);
    for (name, attr) in attrs {
        instance.setattr(name, attr)?;
    }
    Ok(())
}
