//! `rmi_sph.run_trial`: the whole scripted trial in Rust with the GIL released.

use crate::config;
use crate::convert::{columns, outcome_dict};
use crate::panic::{catch, into_py};
use pyo3::prelude::*;
use pyo3::types::PyDict;

/// Recorded rows between two checks for Ctrl-C.
const SIGNAL_ROWS: usize = 8;

/// Runs the scripted grasp-lift-squeeze trial to its end and returns its trajectory.
pub fn run_trial<'py>(
    py: Python<'py>,
    config: &Bound<'py, PyAny>,
    num_threads: Option<usize>,
    record_every: Option<u32>,
) -> PyResult<Bound<'py, PyDict>> {
    let mut cfg = config::extract(config)?;
    if let Some(every) = record_every {
        cfg.record_every = every;
        cfg.validate().map_err(crate::errors::to_pyerr)?;
    }
    let mut interrupt: Option<PyErr> = None;
    let mut rows = 0usize;
    let slot = &mut interrupt;
    let result = py.detach(|| {
        catch(|| {
            rmi_robot::trial::run_trial_with(cfg, num_threads, |_| {
                rows += 1;
                if !rows.is_multiple_of(SIGNAL_ROWS) {
                    return true;
                }
                match Python::attach(|py| py.check_signals()) {
                    Ok(()) => true,
                    Err(e) => {
                        *slot = Some(e);
                        false
                    }
                }
            })
        })
    });
    if let Some(e) = interrupt {
        return Err(e);
    }
    let result = into_py(result)?;
    let out = PyDict::new(py);
    out.set_item("columns", columns(py, &result.records)?)?;
    out.set_item("outcome", outcome_dict(py, &result.outcome)?)?;
    Ok(out)
}
