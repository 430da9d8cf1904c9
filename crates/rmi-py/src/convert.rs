//! Observations, recorded trajectories and outcomes as Python dicts and numpy arrays.
//!
//! Column layout of a trajectory = the run-file columns of `python/rmi_learn/CONTRACT.md`:
//! `EXTRAS` (time, phase, v_com_x/y/z, gate_open, M_expelled, lift_height), the 23 `OBS`
//! names of y_t, then `ACTIONS` (F_target, v_cmd).

use numpy::{PyArray1, PyArray2, PyArrayMethods};
use pyo3::prelude::*;
use pyo3::types::{PyDict, PyList};
use rmi_robot::controller::Phase;
use rmi_robot::observe::{Observation, NAMES};
use rmi_robot::trial::Outcome;

/// Recorded quantities outside y_t, in run-file order.
pub const EXTRAS: [&str; 8] =
    ["time", "phase", "v_com_x", "v_com_y", "v_com_z", "gate_open", "M_expelled", "lift_height"];
/// Action channels.
pub const ACTIONS: [&str; 2] = ["F_target", "v_cmd"];

/// Phase name of an observation (`settle` before the first step).
pub fn phase_name(o: &Observation) -> &'static str {
    o.phase.unwrap_or(Phase::Settle).name()
}

/// One observation as a dict: the 23 y_t values (floats; v_res NaN without contact), then the
/// extras and the applied action.
pub fn observation_dict<'py>(py: Python<'py>, o: &Observation) -> PyResult<Bound<'py, PyDict>> {
    let d = PyDict::new(py);
    for (name, v) in NAMES.iter().zip(o.values()) {
        d.set_item(*name, v)?;
    }
    d.set_item("time", o.time)?;
    d.set_item("phase", phase_name(o))?;
    d.set_item("v_com_x", o.v_com[0])?;
    d.set_item("v_com_y", o.v_com[1])?;
    d.set_item("v_com_z", o.v_com[2])?;
    d.set_item("gate_open", o.gate_open)?;
    d.set_item("M_expelled", o.m_expelled)?;
    d.set_item("lift_height", o.lift_height)?;
    d.set_item("F_target", o.f_target)?;
    d.set_item("v_cmd", o.v_cmd)?;
    Ok(d)
}

/// Columns of a recorded trajectory: name -> 1-D numpy array (phase: numpy str array,
/// gate_open: bool array, the rest float64), in run-file order.
pub fn columns<'py>(py: Python<'py>, rows: &[Observation]) -> PyResult<Bound<'py, PyDict>> {
    let n = rows.len();
    let mut obs: Vec<Vec<f64>> = vec![Vec::with_capacity(n); NAMES.len()];
    for r in rows {
        for (col, v) in obs.iter_mut().zip(r.values()) {
            col.push(v);
        }
    }
    let f = |g: &dyn Fn(&Observation) -> f64| -> Bound<'py, PyArray1<f64>> {
        PyArray1::from_vec(py, rows.iter().map(g).collect())
    };
    let d = PyDict::new(py);
    d.set_item("time", f(&|o| o.time))?;
    let phases = PyList::new(py, rows.iter().map(phase_name))?;
    d.set_item("phase", py.import("numpy")?.call_method1("asarray", (phases, "str"))?)?;
    d.set_item("v_com_x", f(&|o| o.v_com[0]))?;
    d.set_item("v_com_y", f(&|o| o.v_com[1]))?;
    d.set_item("v_com_z", f(&|o| o.v_com[2]))?;
    d.set_item("gate_open", PyArray1::from_vec(py, rows.iter().map(|o| o.gate_open).collect::<Vec<bool>>()))?;
    d.set_item("M_expelled", f(&|o| o.m_expelled))?;
    d.set_item("lift_height", f(&|o| o.lift_height))?;
    for (name, col) in NAMES.iter().zip(obs) {
        d.set_item(*name, PyArray1::from_vec(py, col))?;
    }
    d.set_item("F_target", f(&|o| o.f_target))?;
    d.set_item("v_cmd", f(&|o| o.v_cmd))?;
    Ok(d)
}

/// The outcome as a dict; `water_removed` is {phase: kg} in phase order.
pub fn outcome_dict<'py>(py: Python<'py>, o: &Outcome) -> PyResult<Bound<'py, PyDict>> {
    let d = PyDict::new(py);
    d.set_item("lift_success", o.lift_success)?;
    d.set_item("stable_squeeze", o.stable_squeeze)?;
    d.set_item("failure", o.failure.clone())?;
    d.set_item("gate_opened_at", o.gate_opened_at)?;
    let removed = PyDict::new(py);
    for (phase, kg) in &o.water_removed {
        removed.set_item(phase, kg)?;
    }
    d.set_item("water_removed", removed)?;
    d.set_item("initial_water", o.initial_water)?;
    d.set_item("final_water", o.final_water)?;
    d.set_item("total_water", o.total_water)?;
    d.set_item("sim_time", o.sim_time)?;
    d.set_item("steps", o.steps)?;
    d.set_item("wall_s", o.wall_s)?;
    d.set_item("n_fluid", o.n_fluid)?;
    d.set_item("n_solid", o.n_solid)?;
    Ok(d)
}

/// An (n, 3) float64 array from 3-vectors (one copy out of the simulation's storage; the
/// vector is moved into numpy without another).
pub fn vec3_array<'py, V>(py: Python<'py>, v: &[V]) -> PyResult<Bound<'py, PyArray2<f64>>>
where
    V: std::ops::Index<usize, Output = f64>,
{
    let flat: Vec<f64> = v.iter().flat_map(|x| [x[0], x[1], x[2]]).collect();
    PyArray1::from_vec(py, flat).reshape([v.len(), 3])
}
