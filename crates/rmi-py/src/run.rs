//! `rmi_sph.run_trial` and `rmi_sph.run_squeeze_group`: whole scripted trials in Rust with the
//! GIL released.

use crate::config;
use crate::convert::{columns, outcome_dict};
use crate::panic::{catch, into_py};
use pyo3::prelude::*;
use pyo3::types::{PyDict, PyList};

/// Recorded rows between two checks for Ctrl-C.
const SIGNAL_ROWS: usize = 8;

/// Runs the scripted grasp-lift-squeeze trial to its end and returns its trajectory.
pub fn run_trial<'py>(
    py: Python<'py>,
    config: &Bound<'py, PyAny>,
    num_threads: Option<usize>,
    record_every: Option<u32>,
) -> PyResult<Bound<'py, PyDict>> {
    let cfg = with_record_every(config::extract(config)?, record_every)?;
    let mut interrupt: Option<PyErr> = None;
    let result = py.detach(|| {
        let keep_going = signal_check(&mut interrupt);
        catch(|| rmi_robot::trial::run_trial_with(cfg, num_threads, keep_going))
    });
    if let Some(e) = interrupt {
        return Err(e);
    }
    result_dict(py, &into_py(result)?)
}

/// Runs the scripted trial once per squeeze force from one shared prefix
/// ([`rmi_robot::run_squeeze_group`]) and returns the trajectories in the forces' order.
pub fn run_squeeze_group<'py>(
    py: Python<'py>,
    config: &Bound<'py, PyAny>,
    squeeze_forces: Vec<f64>,
    num_threads: Option<usize>,
    record_every: Option<u32>,
) -> PyResult<Bound<'py, PyList>> {
    let cfg = with_record_every(config::extract(config)?, record_every)?;
    let mut interrupt: Option<PyErr> = None;
    let result = py.detach(|| {
        let keep_going = signal_check(&mut interrupt);
        catch(|| rmi_robot::squeeze_group::run_squeeze_group_with(cfg, &squeeze_forces, num_threads, keep_going))
    });
    if let Some(e) = interrupt {
        return Err(e);
    }
    let results = into_py(result)?;
    let out = PyList::empty(py);
    for r in &results {
        out.append(result_dict(py, r)?)?;
    }
    Ok(out)
}

/// The config with `record_every` replaced where given (validated).
fn with_record_every(mut cfg: rmi_robot::TrialConfig, record_every: Option<u32>) -> PyResult<rmi_robot::TrialConfig> {
    if let Some(every) = record_every {
        cfg.record_every = every;
        cfg.validate().map_err(crate::errors::to_pyerr)?;
    }
    Ok(cfg)
}

/// A row callback that checks for Ctrl-C every [`SIGNAL_ROWS`] rows; the interrupt lands in
/// `slot` and stops the run.
fn signal_check(slot: &mut Option<PyErr>) -> impl FnMut(&rmi_robot::observe::Observation) -> bool + '_ {
    let mut rows = 0usize;
    move |_| {
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
    }
}

/// `{"columns", "outcome"}` of a finished trial.
fn result_dict<'py>(py: Python<'py>, result: &rmi_robot::trial::TrialResult) -> PyResult<Bound<'py, PyDict>> {
    let out = PyDict::new(py);
    out.set_item("columns", columns(py, &result.records)?)?;
    out.set_item("outcome", outcome_dict(py, &result.outcome)?)?;
    Ok(out)
}
