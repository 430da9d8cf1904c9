//! `rmi_sph.engine`: the engine's own simulation (`rmi_sph::Simulation`, no robot layer), its
//! configuration (`SimConfig`) and the ready-made scenes of `rmi_sph::presets`, as a submodule
//! of the native module. Conversion and error mapping only, as in the rest of the binding.

use crate::config;
use crate::convert;
use crate::errors::{int_arg, threads};
use crate::held::{self, Held, Stateful};
use crate::panic::{catch, into_py};
use pyo3::prelude::*;
use pyo3::types::{PyBytes, PyDict, PyList, PyTuple};
use rmi_sph::simulation::Snapshot;
use rmi_sph::{presets, RmiError, SimConfig, Simulation};
use std::path::{Path, PathBuf};

/// Import path of the submodule (and the `__module__` of what it holds).
const MODULE: &str = "rmi_sph.engine";

const DOC: &str = "The porous SPH engine without the robot: ``Simulation`` runs any scene of an \
    engine configuration (``SimConfig``: water blocks, porous blocks, rigid bodies), e.g. a \
    preset's (``dam_break``, ``sponge``, ``water_column``). Units are SI.";

/// Names `particles(kind)` accepts, for water, skeleton and boundary particles.
const KINDS: [&str; 3] = ["fluid", "porous", "boundary"];

impl Stateful for Simulation {
    const NAME: &'static str = "simulation";
    fn to_bytes(&self) -> Vec<u8> {
        self.snapshot().to_bytes()
    }
    fn from_bytes(bytes: &[u8], threads: Option<usize>) -> rmi_sph::Result<Self> {
        let mut sim = Simulation::from_snapshot(Snapshot::from_bytes(bytes)?, threads)?;
        sim.update_fields();
        Ok(sim)
    }
    fn save(&self, path: &Path) -> rmi_sph::Result<()> {
        Simulation::save(self, path)
    }
    fn load(path: &Path, threads: Option<usize>) -> rmi_sph::Result<Self> {
        let mut sim = Simulation::load(path, threads)?;
        sim.update_fields();
        Ok(sim)
    }
    fn config_json(&self) -> String {
        self.config().to_json()
    }
}

/// A simulation of the porous SPH engine: water, porous skeletons and rigid bodies, without
/// the robot (see ``rmi_sph.Trial`` for the grasp-lift-squeeze trial).
///
/// Parameters
/// ----------
/// config : dict | str | os.PathLike
///     An engine configuration: a dict (missing fields take their defaults, see
///     ``default_config()``; presets such as ``dam_break()`` return one), JSON text, or the
///     path of a JSON file.
/// num_threads : int, optional
///     Worker threads of this simulation's own pool (default: ``$RMI_NUM_THREADS``, else
///     ``$RAYON_NUM_THREADS``, else the core count). Results do not depend on it.
///
/// Raises
/// ------
/// ConfigError
///     A field is unknown, has the wrong type or is out of range (``err.field`` names it).
///
/// Notes
/// -----
/// Units are SI (m, s, kg, N, Pa). Building the scene soaks the pore water of porous blocks
/// for ``config["scene"]["soak_time"]`` (s) first. The object survives ``os.fork``: a child
/// process rebuilds the thread pool from the state on its next call.
#[pyclass(module = "rmi_sph.engine", name = "Simulation")]
pub struct PySimulation {
    held: Held<Simulation>,
}

impl PySimulation {
    fn sim(&mut self) -> PyResult<&Simulation> {
        self.held.get()
    }
}

/// Figures of one implicit solve as a dict: iterations and the final relative residual.
fn cg_dict(py: Python<'_>, iterations: u32, residual: f64) -> PyResult<Bound<'_, PyDict>> {
    let d = PyDict::new(py);
    d.set_item("iterations", iterations)?;
    d.set_item("residual", residual)?;
    Ok(d)
}

#[pymethods]
impl PySimulation {
    #[new]
    #[pyo3(signature = (config, *, num_threads=None))]
    fn new(
        py: Python<'_>,
        config: &Bound<'_, PyAny>,
        #[pyo3(from_py_with = crate::errors::any_int_opt)] num_threads: Option<i128>,
    ) -> PyResult<Self> {
        let num_threads = threads(num_threads)?;
        let cfg = config::extract_sim(config)?;
        let sim = py.detach(|| {
            catch(|| {
                let mut sim = Simulation::new(cfg, num_threads)?;
                // Fields at the initial positions, so that `particles()` has them before a step.
                sim.update_fields();
                Ok(sim)
            })
        });
        Ok(PySimulation { held: Held::new(into_py(sim)?, num_threads) })
    }

    /// Advances ``n`` time steps of ``dt`` (GIL released; Ctrl-C is honoured between steps,
    /// at least every 50 ms) and returns the number of steps taken.
    ///
    /// Raises
    /// ------
    /// SimulationUnstableError
    ///     The step diverged; the state stays at the last good step.
    #[pyo3(signature = (n=1))]
    fn step(&mut self, py: Python<'_>, #[pyo3(from_py_with = crate::errors::any_int)] n: i128) -> PyResult<u64> {
        let n: u64 = int_arg(n, "n", "a non-negative integer (steps)")?;
        self.held.step(py, n, |sim| sim.step().map(|_| true))
    }

    /// Simulated time (s).
    #[getter]
    fn time(&mut self) -> PyResult<f64> {
        Ok(self.sim()?.time())
    }

    /// Time step (s).
    #[getter]
    fn dt(&mut self) -> PyResult<f64> {
        Ok(self.sim()?.dt())
    }

    /// Completed time steps.
    #[getter]
    fn step_count(&mut self) -> PyResult<u64> {
        Ok(self.sim()?.step_count())
    }

    /// Worker threads of this simulation's pool.
    #[getter]
    fn num_threads(&mut self) -> PyResult<usize> {
        Ok(self.sim()?.threads())
    }

    /// The configuration as a dict (every field; JSON-compatible; rebuilds this scene).
    #[getter]
    fn config<'py>(&mut self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        config::sim_to_dict(py, self.sim()?.config())
    }

    /// Particle data of one kind as a dict of numpy arrays (SI units).
    ///
    /// ``"fluid"`` (free and pore water): positions (N, 3) m, velocities (N, 3) m/s, mass kg,
    /// density kg/m^3, pressure Pa, porosity (local, -), skeleton_cover (-), retained (part in
    /// [0, 1] inside a porous block's deformed volume), id.
    /// ``"porous"`` (the skeletons of the porous blocks): positions, velocities, mass, density
    /// (bulk, dry), pressure (skeleton pressure unknown times its density, Pa), porosity
    /// (current local, -), saturation (-), rest_positions (m), id.
    /// ``"boundary"`` (the rigid bodies' particles): positions, velocities, volume m^3, body
    /// (int index into ``bodies()``).
    ///
    /// Densities, porosity and saturation are those of the last step's start (before the
    /// first step: of the initial positions).
    ///
    /// Raises ValueError for another kind.
    fn particles<'py>(&mut self, py: Python<'py>, kind: &str) -> PyResult<Bound<'py, PyDict>> {
        let kind = convert::kind(kind, KINDS)?;
        convert::particles(py, self.sim()?, kind)
    }

    /// The rigid bodies as a list of dicts: name, shape (``"box"`` or ``"container"``),
    /// half_extents (m), position (m), rotation (unit quaternion ``(w, x, y, z)``), velocity
    /// (m/s), kinematic (bool), force (N, exerted by the particles in the last step).
    fn bodies<'py>(&mut self, py: Python<'py>) -> PyResult<Bound<'py, PyList>> {
        convert::bodies(py, self.sim()?)
    }

    /// Sets the linear velocity (m/s) and angular velocity (rad/s, default none) of kinematic
    /// body ``body`` (an index into ``bodies()``); it moves with them from the next step on.
    ///
    /// Raises ConfigError for a body that does not exist or is not kinematic, or velocities
    /// that are not finite.
    #[pyo3(signature = (body, velocity, angular_velocity=None))]
    fn set_body_velocity(
        &mut self,
        #[pyo3(from_py_with = crate::errors::any_int)] body: i128,
        velocity: (f64, f64, f64),
        angular_velocity: Option<(f64, f64, f64)>,
    ) -> PyResult<()> {
        let body: usize = int_arg(body, "body", "an existing body index")?;
        let v = [velocity.0, velocity.1, velocity.2];
        let w = angular_velocity.map_or([0.0; 3], |w| [w.0, w.1, w.2]);
        let sim = self.held.get_mut()?;
        into_py(catch(|| sim.set_body_velocity(body, v.into(), w.into())))
    }

    /// Figures of the last step as a dict: ``pressure`` (``iterations``, ``error``: final
    /// mean compression per material, fluid first, then each porous block), ``cg`` (implicit
    /// non-pressure solve), ``pressure_response`` and ``slip_response`` (``iterations``,
    /// ``residual``: final relative residual), ``neighbour_pairs``, ``contacts`` and
    /// ``seconds`` (wall-clock s per phase: ``neighbours``, ``fields``, ``implicit``,
    /// ``pressure``, ``pressure_response``, ``rest``).
    fn stats<'py>(&mut self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        let s = self.sim()?.stats();
        let d = PyDict::new(py);
        let pressure = PyDict::new(py);
        pressure.set_item("iterations", s.pressure.iterations)?;
        pressure.set_item("error", s.pressure.error.clone())?;
        d.set_item("pressure", pressure)?;
        d.set_item("cg", cg_dict(py, s.cg.iterations, s.cg.residual)?)?;
        let r = &s.pressure_response;
        d.set_item("pressure_response", cg_dict(py, r.iterations, r.residual)?)?;
        let r = &s.slip_response;
        d.set_item("slip_response", cg_dict(py, r.iterations, r.residual)?)?;
        d.set_item("neighbour_pairs", s.neighbour_pairs)?;
        d.set_item("contacts", s.contacts)?;
        let seconds = PyDict::new(py);
        for (name, t) in
            ["neighbours", "fields", "implicit", "pressure", "pressure_response", "rest"].iter().zip(s.seconds)
        {
            seconds.set_item(*name, t)?;
        }
        d.set_item("seconds", seconds)?;
        Ok(d)
    }

    /// The water the pores of porous block ``block`` hold (kg): the water's rest density times
    /// the block's current pore volume times its saturation (of the last step).
    ///
    /// Raises ConfigError for a block that does not exist.
    fn pore_water(&mut self, #[pyo3(from_py_with = crate::errors::any_int)] block: i128) -> PyResult<f64> {
        let sim = self.sim()?;
        let n = sim.objects().len();
        let expected = || format!("an index of the scene's porous blocks (it has {n})");
        let k: usize = int_arg(block, "block", &expected())?;
        if k >= n {
            return Err(crate::errors::to_pyerr(RmiError::config("block", k, expected())));
        }
        Ok(sim.pore_water(k))
    }

    /// The full state as bytes, for a bit-identical continuation with ``set_state`` or
    /// ``Simulation.from_state``.
    fn get_state<'py>(&mut self, py: Python<'py>) -> PyResult<Bound<'py, PyBytes>> {
        self.held.state(py)
    }

    /// Replaces the whole state with one from ``get_state`` of a simulation of the same
    /// config. Raises StateError for bytes that are not a state or a state of another config
    /// (``Simulation.from_state`` makes a simulation of any state); the simulation is
    /// unchanged then.
    fn set_state(&mut self, py: Python<'_>, state: &Bound<'_, PyAny>) -> PyResult<()> {
        self.held.set_state(py, state)
    }

    /// A simulation continuing from ``state`` (bytes of ``get_state``).
    #[staticmethod]
    #[pyo3(signature = (state, num_threads=None))]
    fn from_state(
        py: Python<'_>,
        state: &Bound<'_, PyAny>,
        #[pyo3(from_py_with = crate::errors::any_int_opt)] num_threads: Option<i128>,
    ) -> PyResult<Self> {
        let num_threads = threads(num_threads)?;
        Ok(PySimulation { held: Held::new(held::from_state(py, state, num_threads)?, num_threads) })
    }

    /// Writes the state to ``path`` atomically (temporary name, then rename).
    fn save(&mut self, py: Python<'_>, path: PathBuf) -> PyResult<()> {
        self.held.save(py, &path)
    }

    /// A simulation continuing from a state file written by ``save``.
    #[staticmethod]
    #[pyo3(signature = (path, num_threads=None))]
    fn load(
        py: Python<'_>,
        path: PathBuf,
        #[pyo3(from_py_with = crate::errors::any_int_opt)] num_threads: Option<i128>,
    ) -> PyResult<Self> {
        let num_threads = threads(num_threads)?;
        Ok(PySimulation { held: Held::new(held::load(py, &path, num_threads)?, num_threads) })
    }

    /// Pickling: the state bytes.
    fn __reduce__<'py>(slf: &Bound<'py, Self>) -> PyResult<Bound<'py, PyTuple>> {
        slf.borrow_mut().held.reduce(&slf.get_type())
    }

    fn __repr__(&mut self) -> String {
        match self.sim() {
            Ok(s) => format!(
                "Simulation(time={:.4} s, steps={}, fluid={}, porous={}, boundary={}, threads={})",
                s.time(),
                s.step_count(),
                s.particles().n_fluid,
                s.particles().n_solid(),
                s.boundary().x.len(),
                s.threads()
            ),
            Err(_) => "Simulation(<no valid state>)".to_owned(),
        }
    }
}

/// A preset's config, validated (bad arguments raise ConfigError naming the config field).
fn preset<'py>(py: Python<'py>, build: impl FnOnce() -> SimConfig) -> PyResult<Bound<'py, PyAny>> {
    let cfg = into_py(catch(|| {
        let cfg = build();
        cfg.validate()?;
        Ok(cfg)
    }))?;
    config::sim_to_dict(py, &cfg)
}

/// The SPlisHSPlasH dam break as an engine config (dict).
///
/// A closed 4 x 1.5 x 3 m tank (x, y, height; z up) with a cubic water column of about 1 m in
/// a corner, sampled at particle radius ``radius_m``; explicit viscosity 0.01 m^2/s, dt = 1 ms.
///
/// Parameters
/// ----------
/// radius_m : float
///     Particle radius r (m): 0.0125 gives 39^3 = 59,319 water particles, 0.05 gives 9^3.
///
/// Raises
/// ------
/// ConfigError
///     The radius is out of range (``err.field`` is ``particle_radius``).
#[pyfunction]
fn dam_break(py: Python<'_>, radius_m: f64) -> PyResult<Bound<'_, PyAny>> {
    preset(py, || presets::dam_break(radius_m))
}

/// A saturated sponge standing on a floor, centred at x = y = 0, as an engine config (dict).
///
/// Each side is the nearest whole number of particle spacings 2r.
///
/// Parameters
/// ----------
/// size_m : tuple of 3 floats
///     Size (x, y, z = height) in m, e.g. one of ``rmi_sph.SPONGE_SIZES_M``.
/// porosity : float
///     Porosity phi of the skeleton (-).
/// radius_m : float
///     Particle radius r (m).
///
/// Raises
/// ------
/// ConfigError
///     An argument is out of range (``err.field`` names the config field).
#[pyfunction]
fn sponge(py: Python<'_>, size_m: (f64, f64, f64), porosity: f64, radius_m: f64) -> PyResult<Bound<'_, PyAny>> {
    preset(py, || presets::sponge([size_m.0, size_m.1, size_m.2], porosity, radius_m))
}

/// A water column of ``width_m`` x ``width_m`` x ``height_m`` in a closed tank twice as tall,
/// as an engine config (dict).
///
/// Parameters
/// ----------
/// radius_m : float
///     Particle radius r (m).
/// width_m, height_m : float
///     Width (x and y) and height (z) of the column (m).
///
/// Raises
/// ------
/// ConfigError
///     An argument is out of range (``err.field`` names the config field).
#[pyfunction]
fn water_column(py: Python<'_>, radius_m: f64, width_m: f64, height_m: f64) -> PyResult<Bound<'_, PyAny>> {
    preset(py, || presets::water_column(radius_m, width_m, height_m))
}

/// The default engine configuration as a dict (every field, SI units; an empty scene).
#[pyfunction]
fn default_config(py: Python<'_>) -> PyResult<Bound<'_, PyAny>> {
    config::sim_to_dict(py, &SimConfig::default())
}

/// Checks an engine configuration and returns it complete (defaults filled in) as a dict.
///
/// Raises ConfigError naming the first bad field.
#[pyfunction]
fn validate_config<'py>(py: Python<'py>, config: &Bound<'py, PyAny>) -> PyResult<Bound<'py, PyAny>> {
    let cfg = config::extract_sim(config)?;
    config::sim_to_dict(py, &cfg)
}

/// Adds the submodule `engine` to the native module and makes it importable as
/// `rmi_sph.engine` (a native submodule is an attribute only, unknown to the import system).
pub fn register(parent: &Bound<'_, PyModule>) -> PyResult<()> {
    let py = parent.py();
    let m = PyModule::new(py, "engine")?;
    // Before adding functions: they take their `__module__` from it.
    m.setattr("__name__", MODULE)?;
    m.setattr("__doc__", DOC)?;
    m.add_class::<PySimulation>()?;
    m.add_function(wrap_pyfunction!(dam_break, &m)?)?;
    m.add_function(wrap_pyfunction!(sponge, &m)?)?;
    m.add_function(wrap_pyfunction!(water_column, &m)?)?;
    m.add_function(wrap_pyfunction!(default_config, &m)?)?;
    m.add_function(wrap_pyfunction!(validate_config, &m)?)?;
    parent.add("engine", &m)?;
    py.import("sys")?.getattr("modules")?.set_item(MODULE, &m)?;
    Ok(())
}
