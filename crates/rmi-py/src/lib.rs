//! Python binding of the rmi SPH engine, imported as `rmi_sph._rmi_sph`.
//!
//! Kept thin on purpose: physics, validation and error texts live in the `rmi-sph` crate, and
//! this crate only converts types and errors (one module per concern: `config` for configs
//! from Python, `convert` for observations/columns/outcomes/particles, `trial` for the
//! `Trial` class, `engine` for the submodule `rmi_sph.engine` with the engine's own
//! `Simulation`, `held` for what both classes share (fork safety, state, stepping), `run` for
//! `run_trial`, `panic` keeps Rust panics out of Python, `errors` maps the core's errors to
//! exceptions). The Python package `rmi_sph` re-exports it.

mod config;
mod convert;
mod engine;
mod errors;
mod held;
mod panic;
mod run;
mod trial;
mod wm;

use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;
use pyo3::types::{PyDict, PyList, PyTuple};
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
/// ``kind`` is one of ``"config"``, ``"unstable"``, ``"state"``, ``"io"``, ``"panic"``.
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
        "panic" => return panic::into_py(panic::catch(|| -> rmi_sph::Result<()> { panic!("deliberate test panic") })),
        other => {
            return Err(PyValueError::new_err(format!(
                "unknown error kind {other:?}; expected config, unstable, state, io or panic"
            )))
        }
    };
    Err(errors::to_pyerr(error))
}

/// Runs the scripted grasp-lift-squeeze trial to its end in Rust (GIL released, Ctrl-C
/// honoured every few recorded rows) and returns its trajectory.
///
/// Parameters
/// ----------
/// config : dict | str | os.PathLike
///     Trial configuration (see ``Trial``).
/// num_threads : int, optional
///     Worker threads (results do not depend on it).
/// record_every : int, optional
///     Simulator steps per recorded row (default: the config's ``record_every``, 5).
///
/// Returns
/// -------
/// dict
///     ``columns``: run-file columns, name -> 1-D numpy array (``time`` s, ``phase`` str,
///     ``v_com_x/y/z`` m/s, ``gate_open`` bool, ``M_expelled`` kg, ``lift_height`` m,
///     ``W_x/y/z`` N (wrist load), the 23 y_t channels of ``OBSERVATION_NAMES``, ``F_target`` N, ``v_cmd`` m/s); one row at the
///     start, one every ``record_every`` steps and one at the end, loads averaged over each
///     interval. ``outcome``: dict as ``Trial.outcome()``.
///
/// Raises
/// ------
/// ConfigError, SimulationUnstableError, StateError (trial exceeded its time limit),
/// KeyboardInterrupt.
#[pyfunction]
#[pyo3(signature = (config, *, num_threads=None, record_every=None))]
fn run_trial<'py>(
    py: Python<'py>,
    config: &Bound<'py, PyAny>,
    #[pyo3(from_py_with = errors::any_int_opt)] num_threads: Option<i128>,
    #[pyo3(from_py_with = errors::any_int_opt)] record_every: Option<i128>,
) -> PyResult<Bound<'py, PyDict>> {
    let record_every =
        record_every.map(|v| errors::int_arg(v, "record_every", "an integer in [1, 1000000]")).transpose()?;
    run::run_trial(py, config, errors::threads(num_threads)?, record_every)
}

/// Runs the scripted trial once per squeeze force from one shared prefix: everything before
/// the squeeze, which does not depend on the squeeze force, is simulated once, and each
/// member continues from the saved state where the squeeze begins. Each member's result has
/// the bits of ``run_trial`` with that squeeze force (the config's own ``squeeze_force`` is
/// not run), but for its ``outcome["wall_s"]``: the prefix's time split evenly over the
/// group plus its own squeeze. A trial that ends before the squeeze ends so for every member.
///
/// Parameters
/// ----------
/// config : dict | str | os.PathLike
///     Trial configuration (see ``Trial``); perturbed force targets
///     (``controller.perturbation.enabled``) are refused: they depend on the squeeze force.
/// squeeze_forces : sequence of float
///     Squeeze force targets (N, each in [0, ``FORCE_LIMIT_N``]; a bad one is named
///     ``squeeze_forces[i]``).
/// num_threads : int, optional
///     Worker threads (results do not depend on it).
/// record_every : int, optional
///     Simulator steps per recorded row (default: the config's ``record_every``, 5).
///
/// Returns
/// -------
/// list of dict
///     One ``run_trial`` result per squeeze force, in their order.
///
/// Raises
/// ------
/// ConfigError, SimulationUnstableError, StateError, KeyboardInterrupt, as ``run_trial``.
#[pyfunction]
#[pyo3(signature = (config, squeeze_forces, *, num_threads=None, record_every=None))]
fn run_squeeze_group<'py>(
    py: Python<'py>,
    config: &Bound<'py, PyAny>,
    squeeze_forces: Vec<f64>,
    #[pyo3(from_py_with = errors::any_int_opt)] num_threads: Option<i128>,
    #[pyo3(from_py_with = errors::any_int_opt)] record_every: Option<i128>,
) -> PyResult<Bound<'py, PyList>> {
    let record_every =
        record_every.map(|v| errors::int_arg(v, "record_every", "an integer in [1, 1000000]")).transpose()?;
    run::run_squeeze_group(py, config, squeeze_forces, errors::threads(num_threads)?, record_every)
}

/// A trial config (dict) of one of the paper's sponges.
///
/// Parameters
/// ----------
/// size_cm : int
///     Sponge size: 8, 10 or 12 (cm), i.e. 8x8x18, 10x10x20 or 12x12x22 cm.
/// porosity : float
///     Porosity phi of the skeleton (-).
/// hold_force, squeeze_force : float
///     Holding and squeeze force targets (N).
/// radius : float, default 0.005
///     Particle radius r (m).
/// seed : int, default 0
///     Seed of the initial pore-water jitter, in [0, ``SEED_MAX``] (2^63 - 1).
/// **overrides
///     TrialConfig fields (``dt``, ``jitter``, ``record_every``, ``saturated``, and tables
///     ``material``, ``gripper``, ``friction``, ``gate``, ``controller``, ``pressure``,
///     merged into the defaults) or ControllerParams fields (``settle_time``,
///     ``ramp_time``, ``hold_time``, ``wait_time``, ...), which go under ``controller``.
///
/// Raises
/// ------
/// ConfigError
///     Unknown override, wrong type or value out of range; ``err.field`` names it.
#[pyfunction]
#[pyo3(signature = (size_cm, porosity, hold_force, squeeze_force, radius=0.005, seed=0, **overrides))]
#[allow(clippy::too_many_arguments)]
fn trial_config<'py>(
    py: Python<'py>,
    size_cm: f64,
    porosity: f64,
    hold_force: f64,
    squeeze_force: f64,
    radius: f64,
    #[pyo3(from_py_with = errors::any_int)] seed: i128,
    overrides: Option<&Bound<'py, PyDict>>,
) -> PyResult<Bound<'py, PyAny>> {
    let seed = errors::int_arg(seed, "seed", &rmi_sph::config::seed_range())?;
    let cfg = config::trial_config(size_cm, porosity, hold_force, squeeze_force, radius, seed, overrides)?;
    config::to_dict(py, &cfg)
}

/// The default trial configuration as a dict (every field, SI units).
#[pyfunction]
fn default_config(py: Python<'_>) -> PyResult<Bound<'_, PyAny>> {
    config::to_dict(py, &rmi_robot::TrialConfig::default())
}

/// Checks a trial configuration and returns it complete (defaults filled in) as a dict.
///
/// Raises ConfigError naming the first bad field.
#[pyfunction]
fn validate_config<'py>(py: Python<'py>, config: &Bound<'py, PyAny>) -> PyResult<Bound<'py, PyAny>> {
    let cfg = config::extract(config)?;
    config::to_dict(py, &cfg)
}

#[pymodule]
fn _rmi_sph(m: &Bound<'_, PyModule>) -> PyResult<()> {
    let py = m.py();
    m.add("__version__", VERSION)?;
    m.add("OBSERVATION_NAMES", PyTuple::new(py, rmi_robot::observe::NAMES)?)?;
    m.add("EXTRA_NAMES", PyTuple::new(py, convert::EXTRAS)?)?;
    m.add("ACTION_NAMES", PyTuple::new(py, convert::ACTIONS)?)?;
    // The robot's physical limits and the paper's sponges, so Python never restates them.
    m.add("FORCE_LIMIT_N", rmi_robot::gripper::FORCE_LIMIT)?;
    m.add("SEED_MAX", rmi_sph::config::SEED_MAX)?;
    let sizes: Vec<(f64, f64, f64)> = rmi_sph::presets::SPONGE_SIZES.iter().map(|s| (s[0], s[1], s[2])).collect();
    m.add("SPONGE_SIZES_M", PyTuple::new(py, sizes)?)?;
    m.add_function(wrap_pyfunction!(engine_info, m)?)?;
    m.add_function(wrap_pyfunction!(_raise_error, m)?)?;
    m.add_function(wrap_pyfunction!(run_trial, m)?)?;
    m.add_function(wrap_pyfunction!(run_squeeze_group, m)?)?;
    m.add_function(wrap_pyfunction!(trial_config, m)?)?;
    m.add_function(wrap_pyfunction!(default_config, m)?)?;
    m.add_function(wrap_pyfunction!(validate_config, m)?)?;
    m.add_class::<trial::PyTrial>()?;
    // The trial's previous name, outside `__all__`: pickles of that version name the class
    // `rmi_sph._rmi_sph.Simulation`, and the package's deprecated `rmi_sph.Simulation` is this.
    m.setattr("Simulation", py.get_type::<trial::PyTrial>())?;
    engine::register(m)?;
    m.add_class::<wm::PyGruForecaster>()?;
    errors::register(m)?;
    Ok(())
}
