//! Observations, recorded trajectories, outcomes, particles and bodies as Python dicts and
//! numpy arrays.
//!
//! Column layout of a trajectory = the run-file columns of `docs/data-contract.md` (Run files):
//! `EXTRAS` (time, phase, v_com_x/y/z, gate_open, M_expelled, lift_height, W_x/y/z), the 23 `OBS`
//! names of y_t, then `ACTIONS` (F_target, v_cmd).

use numpy::{PyArray1, PyArray2, PyArrayMethods};
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;
use pyo3::types::{PyDict, PyList};
use rmi_robot::controller::Phase;
use rmi_robot::observe::{Observation, NAMES};
use rmi_robot::trial::Outcome;
use rmi_sph::config::Shape;
use rmi_sph::Simulation;

/// Recorded quantities outside y_t, in run-file order.
pub const EXTRAS: [&str; 11] =
    ["time", "phase", "v_com_x", "v_com_y", "v_com_z", "gate_open", "M_expelled", "lift_height", "W_x", "W_y", "W_z"];
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
    d.set_item("W_x", o.wrist_load[0])?;
    d.set_item("W_y", o.wrist_load[1])?;
    d.set_item("W_z", o.wrist_load[2])?;
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
    d.set_item("W_x", f(&|o| o.wrist_load[0]))?;
    d.set_item("W_y", f(&|o| o.wrist_load[1]))?;
    d.set_item("W_z", f(&|o| o.wrist_load[2]))?;
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

/// The particle sets of a simulation, as `particles(kind)` reads them.
#[derive(Clone, Copy, PartialEq, Eq)]
pub enum Kind {
    /// Free and pore water.
    Fluid,
    /// Porous skeletons (the sponges).
    Skeleton,
    /// Boundary particles of the rigid bodies.
    Boundary,
}

/// The kind named `name`, given the names a class uses for fluid, skeleton and boundary
/// particles; a `ValueError` listing them otherwise.
pub fn kind(name: &str, names: [&str; 3]) -> PyResult<Kind> {
    match names.iter().position(|n| *n == name) {
        Some(0) => Ok(Kind::Fluid),
        Some(1) => Ok(Kind::Skeleton),
        Some(2) => Ok(Kind::Boundary),
        _ => Err(PyValueError::new_err(format!(
            "unknown particle kind {name:?}; expected '{}', '{}' or '{}'",
            names[0], names[1], names[2]
        ))),
    }
}

/// Particle data of one kind as a dict of numpy arrays (SI units).
///
/// Fluid: positions (N, 3) m, velocities (N, 3) m/s, mass kg, density kg/m^3, pressure Pa,
/// porosity (local, -), skeleton_cover (-), retained (part inside a sponge's deformed volume,
/// -), id. Skeleton: positions, velocities, mass, density (bulk, dry), pressure, porosity
/// (current local), saturation (-), rest_positions (m), id. Boundary: positions, velocities,
/// volume m^3, body (index into the bodies).
pub fn particles<'py>(py: Python<'py>, sim: &Simulation, kind: Kind) -> PyResult<Bound<'py, PyDict>> {
    let d = PyDict::new(py);
    let p = sim.particles();
    let nf = p.n_fluid;
    let range = match kind {
        Kind::Fluid => 0..nf,
        Kind::Skeleton => nf..p.len(),
        Kind::Boundary => {
            let b = sim.boundary();
            d.set_item("positions", vec3_array(py, &b.x)?)?;
            d.set_item("velocities", vec3_array(py, &b.v)?)?;
            d.set_item("volume", PyArray1::from_vec(py, b.volume.clone()))?;
            d.set_item("body", PyArray1::from_vec(py, b.body.iter().map(|&x| x as i32).collect::<Vec<_>>()))?;
            return Ok(d);
        }
    };
    let f = sim.fields();
    let field = |v: &[f64]| -> Vec<f64> { range.clone().map(|a| v.get(a).copied().unwrap_or(f64::NAN)).collect() };
    let pressure = sim.pressure();
    let density: Vec<f64> = {
        let objects = sim.objects();
        range
            .clone()
            .map(|a| {
                let rho0 = if a < nf {
                    sim.config().fluid.density
                } else {
                    (p.material[a] as usize)
                        .checked_sub(1)
                        .and_then(|k| objects.get(k))
                        .map_or(f64::NAN, |o| o.material.dry_density)
                };
                rho0 * f.rho_ratio.get(a).copied().unwrap_or(f64::NAN)
            })
            .collect()
    };
    d.set_item("positions", vec3_array(py, &p.x[range.clone()])?)?;
    d.set_item("velocities", vec3_array(py, &p.v[range.clone()])?)?;
    d.set_item("mass", PyArray1::from_vec(py, p.mass[range.clone()].to_vec()))?;
    d.set_item("density", PyArray1::from_vec(py, density))?;
    d.set_item("pressure", PyArray1::from_vec(py, field(&pressure)))?;
    d.set_item("porosity", PyArray1::from_vec(py, field(&f.porosity)))?;
    if kind == Kind::Fluid {
        d.set_item("skeleton_cover", PyArray1::from_vec(py, field(&f.skeleton_cover)))?;
        let mut inside = sim.retained();
        inside.resize(nf, 0.0);
        d.set_item("retained", PyArray1::from_vec(py, inside))?;
    } else {
        d.set_item("saturation", PyArray1::from_vec(py, field(&f.saturation)))?;
        d.set_item("rest_positions", vec3_array(py, &sim.rest().x0)?)?;
    }
    d.set_item("id", PyArray1::from_vec(py, p.id[range].to_vec()))?;
    Ok(d)
}

/// The rigid bodies as a list of dicts: name, shape (`"box"` or `"container"`), half_extents
/// (m), position (m), rotation (unit quaternion `(w, x, y, z)`), velocity (m/s), kinematic
/// (bool), force (N, from the last step).
pub fn bodies<'py>(py: Python<'py>, sim: &Simulation) -> PyResult<Bound<'py, PyList>> {
    let out = PyList::empty(py);
    for b in &sim.boundary().bodies {
        let d = PyDict::new(py);
        let (shape, he) = match &b.shape {
            Shape::Box { half_extents } => ("box", half_extents),
            Shape::Container { half_extents } => ("container", half_extents),
        };
        let s = &b.state;
        let q = s.rotation.quaternion();
        d.set_item("name", &b.name)?;
        d.set_item("shape", shape)?;
        d.set_item("half_extents", (he[0], he[1], he[2]))?;
        d.set_item("position", (s.position[0], s.position[1], s.position[2]))?;
        d.set_item("rotation", (q.w, q.i, q.j, q.k))?;
        d.set_item("velocity", (s.velocity[0], s.velocity[1], s.velocity[2]))?;
        d.set_item("kinematic", b.kinematic)?;
        d.set_item("force", (b.force[0], b.force[1], b.force[2]))?;
        out.append(d)?;
    }
    Ok(out)
}
