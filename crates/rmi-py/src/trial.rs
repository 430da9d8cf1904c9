//! `rmi_sph.Trial`: one grasp-lift-squeeze trial (the porous simulation, the pads and the
//! robot layer) stepped from Python. Its previous name `rmi_sph.Simulation` stays an alias for
//! one release (a deprecated one in the Python package; unpickling old objects resolves it).

use crate::config;
use crate::convert::{self, columns, observation_dict, outcome_dict};
use crate::errors::StateError;
use crate::held::{self, Held, Stateful};
use crate::panic::{catch, into_py};
use numpy::PyArray1;
use pyo3::prelude::*;
use pyo3::types::{PyBytes, PyDict, PyList, PyTuple};
use rmi_robot::controller::Action;
use rmi_robot::observe::Observation;
use rmi_robot::Trial;
use std::path::{Path, PathBuf};

/// Rows recorded while stepping, at the cadence of `run_trial`.
struct Recorder {
    every: u64,
    rows: Vec<Observation>,
}

impl Stateful for Trial {
    const NAME: &'static str = "trial";
    fn to_bytes(&self) -> Vec<u8> {
        Trial::to_bytes(self)
    }
    fn from_bytes(bytes: &[u8], threads: Option<usize>) -> rmi_sph::Result<Self> {
        Trial::from_bytes(bytes, threads)
    }
    fn save(&self, path: &Path) -> rmi_sph::Result<()> {
        Trial::save(self, path)
    }
    fn load(path: &Path, threads: Option<usize>) -> rmi_sph::Result<Self> {
        Trial::load(path, threads)
    }
    fn config_json(&self) -> String {
        self.config().to_json()
    }
}

/// A grasp-lift-squeeze trial stepped from Python.
///
/// Parameters
/// ----------
/// config : dict | str | os.PathLike
///     A trial configuration: a dict (missing fields take their defaults, see
///     ``default_config()``), JSON text, or the path of a JSON file.
/// num_threads : int, optional
///     Worker threads of this trial's own pool (default: ``$RMI_NUM_THREADS``, else
///     ``$RAYON_NUM_THREADS``, else the core count). Results do not depend on it.
/// record : bool, default False
///     Record one row every ``config["record_every"]`` steps while stepping, exactly as
///     ``run_trial`` does (loads averaged over the interval); read them with ``records()``.
///
/// Raises
/// ------
/// ConfigError
///     A field is unknown, has the wrong type or is out of range (``err.field`` names it).
///
/// Notes
/// -----
/// Units are SI (m, s, kg, N, Pa). The object survives ``os.fork``: a child process
/// rebuilds the thread pool from the state on its next call. The class was called
/// ``Simulation`` before; that name stays a deprecated alias for one release.
/// ``rmi_sph.engine.Simulation`` is the engine's own simulation, without the robot.
#[pyclass(module = "rmi_sph._rmi_sph", name = "Trial")]
pub struct PyTrial {
    held: Held<Trial>,
    recorder: Option<Recorder>,
}

impl PyTrial {
    fn wrap(trial: Trial, threads: Option<usize>, record: bool) -> Self {
        let mut t = PyTrial { held: Held::new(trial, threads), recorder: None };
        if record {
            t.start_recording();
        }
        t
    }

    fn start_recording(&mut self) {
        if let Ok(t) = self.held.get_mut() {
            let every = t.config().record_every as u64;
            self.recorder = Some(Recorder { every, rows: vec![t.take_record()] });
        }
    }

    fn trial_mut(&mut self) -> PyResult<&mut Trial> {
        self.held.get_mut()
    }

    fn trial(&mut self) -> PyResult<&Trial> {
        self.held.get()
    }
}

#[pymethods]
impl PyTrial {
    #[new]
    #[pyo3(signature = (config, *, num_threads=None, record=false))]
    fn new(
        py: Python<'_>,
        config: &Bound<'_, PyAny>,
        #[pyo3(from_py_with = crate::errors::any_int_opt)] num_threads: Option<i128>,
        record: bool,
    ) -> PyResult<Self> {
        let num_threads = crate::errors::threads(num_threads)?;
        let cfg = config::extract(config)?;
        let trial = py.detach(|| catch(|| Trial::new(cfg, num_threads)));
        Ok(Self::wrap(into_py(trial)?, num_threads, record))
    }

    /// Advances ``n`` simulator steps of ``dt`` (GIL released; Ctrl-C is honoured between
    /// steps, at least every 50 ms) and returns the number of steps taken.
    ///
    /// With ``stop_at_finish=True`` stepping stops as soon as the trial is finished (phase
    /// ``done``), as ``run_trial`` does. Otherwise a finished trial keeps stepping physically
    /// (the pads hold still) but records no rows.
    ///
    /// Raises
    /// ------
    /// SimulationUnstableError
    ///     The step diverged; the state stays at the last good step.
    #[pyo3(signature = (n=1, *, stop_at_finish=false))]
    fn step(
        &mut self,
        py: Python<'_>,
        #[pyo3(from_py_with = crate::errors::any_int)] n: i128,
        stop_at_finish: bool,
    ) -> PyResult<u64> {
        let n: u64 = crate::errors::int_arg(n, "n", "a non-negative integer (steps)")?;
        let PyTrial { held, recorder } = self;
        held.step(py, n, |trial| {
            let was_finished = trial.finished();
            if was_finished && stop_at_finish {
                return Ok(false);
            }
            trial.step()?;
            if let Some(r) = recorder.as_mut() {
                let steps = trial.simulation().step_count();
                if !was_finished && (steps % r.every == 0 || trial.finished()) {
                    r.rows.push(trial.take_record());
                }
            }
            Ok(true)
        })
    }

    /// Simulated time (s).
    #[getter]
    fn time(&mut self) -> PyResult<f64> {
        Ok(self.trial()?.simulation().time())
    }

    /// Time step (s).
    #[getter]
    fn dt(&mut self) -> PyResult<f64> {
        Ok(self.trial()?.simulation().dt())
    }

    /// Completed simulator steps.
    #[getter]
    fn step_count(&mut self) -> PyResult<u64> {
        Ok(self.trial()?.simulation().step_count())
    }

    /// Worker threads of this trial's pool.
    #[getter]
    fn num_threads(&mut self) -> PyResult<usize> {
        Ok(self.trial()?.simulation().threads())
    }

    /// Simulated time after which ``run_trial`` gives up on an unfinished trial (s).
    #[getter]
    fn time_limit(&mut self) -> PyResult<f64> {
        Ok(self.trial()?.config().time_limit())
    }

    /// Controller phase: settle, close, ramp, hold, lift, waiting, squeeze or done.
    #[getter]
    fn phase(&mut self) -> PyResult<&'static str> {
        Ok(self.trial()?.phase().name())
    }

    /// Whether the trial is over (phase ``done``).
    #[getter]
    fn finished(&mut self) -> PyResult<bool> {
        Ok(self.trial()?.finished())
    }

    /// Why the trial ended early (no_contact, gate_timeout, dropped, slipped_out), else None.
    #[getter]
    fn failure(&mut self) -> PyResult<Option<&'static str>> {
        Ok(self.trial()?.failure().map(|f| f.name()))
    }

    /// The configuration as a dict (JSON-compatible; reproduces this trial).
    #[getter]
    fn config<'py>(&mut self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        config::to_dict(py, self.trial()?.config())
    }

    /// The external action ``(force_target, velocity_command)`` in force, or None when the
    /// scripted controller drives the pads.
    #[getter]
    fn action(&mut self) -> PyResult<Option<(f64, Option<f64>)>> {
        Ok(self.trial()?.controller().external.map(|a| (a.force_target, a.velocity)))
    }

    /// Latest observation: the 23 values of y_t by name (``OBSERVATION_NAMES``; floats, SI,
    /// ``v_res`` NaN without contact) plus ``time`` (s), ``phase`` (str), ``v_com_x/y/z``
    /// (m/s), ``gate_open`` (bool), ``M_expelled`` (kg), ``lift_height`` (m), ``W_x/y/z`` (N,
    /// wrist load), ``F_target`` (N) and ``v_cmd`` (m/s) of the last command. Pad loads are those of the last step.
    fn observation<'py>(&mut self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        observation_dict(py, self.trial()?.observation())
    }

    /// The 23 values of y_t in schema order as a float64 array of shape (23,).
    fn observation_vector<'py>(&mut self, py: Python<'py>) -> PyResult<Bound<'py, PyArray1<f64>>> {
        Ok(PyArray1::from_vec(py, self.trial()?.observation().values().to_vec()))
    }

    /// Like ``observation()`` but with the pad loads (F_L, F_R, F_meas, alpha_F) averaged
    /// over the steps since the previous call, which starts a new interval.
    ///
    /// Raises StateError on a trial created with ``record=True`` (its recorder owns the
    /// averaging interval).
    fn take_record<'py>(&mut self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        if self.recorder.is_some() {
            return Err(StateError::new_err("take_record() is unavailable while recording (record=True)"));
        }
        let r = self.trial_mut()?.take_record();
        observation_dict(py, &r)
    }

    /// Rows recorded so far (``record=True``) as run-file columns: name -> numpy array
    /// (``phase`` str, ``gate_open`` bool, the rest float64), same layout as ``run_trial``.
    /// ``clear=True`` empties the buffer afterwards.
    #[pyo3(signature = (*, clear=false))]
    fn records<'py>(&mut self, py: Python<'py>, clear: bool) -> PyResult<Bound<'py, PyDict>> {
        let Some(r) = self.recorder.as_mut() else {
            return Err(StateError::new_err("this trial does not record; create it with record=True"));
        };
        let out = columns(py, &r.rows)?;
        if clear {
            r.rows.clear();
        }
        Ok(out)
    }

    /// Particle data of one kind as a dict of numpy arrays (SI units).
    ///
    /// ``"fluid"``: positions (N, 3) m, velocities (N, 3) m/s, mass kg, density kg/m^3,
    /// pressure Pa, porosity (local, -), skeleton_cover (-), retained (part in [0, 1]
    /// inside the sponge's deformed volume), id.
    /// ``"solid"`` (the sponge skeleton): positions, velocities, mass, density (bulk, dry),
    /// pressure (skeleton pressure unknown times its density, Pa), porosity (current local),
    /// saturation (-), rest_positions, id.
    /// ``"boundary"`` (floor and pads): positions, velocities, volume m^3, body (int index
    /// into ``bodies()``).
    fn particles<'py>(&mut self, py: Python<'py>, kind: &str) -> PyResult<Bound<'py, PyDict>> {
        let kind = convert::kind(kind, ["fluid", "solid", "boundary"])?;
        convert::particles(py, self.held.get()?.simulation(), kind)
    }

    /// Rigid bodies (floor, pads) as a list of dicts: name, shape (``"box"`` or
    /// ``"container"``), half_extents (m), position (m), rotation (unit quaternion
    /// ``(w, x, y, z)``), velocity (m/s), kinematic (bool), force (N, from the last step).
    fn bodies<'py>(&mut self, py: Python<'py>) -> PyResult<Bound<'py, PyList>> {
        convert::bodies(py, self.held.get()?.simulation())
    }

    /// Drives the pads with u_t from now on: ``force_target`` (N, in [0, 400]) and, if given,
    /// the closing speed per pad ``velocity_command`` (m/s, in [-1, 1], positive closes;
    /// clipped to the controller's v_open/v_close and the guards). Without a speed the force
    /// regulation of Eq. 5b runs toward the target. Phases, gate and guards keep running.
    ///
    /// Raises ConfigError for values out of range or not finite.
    #[pyo3(signature = (force_target, velocity_command=None))]
    fn set_action(&mut self, force_target: f64, velocity_command: Option<f64>) -> PyResult<()> {
        let a = Action { force_target, velocity: velocity_command };
        let t = self.trial_mut()?;
        into_py(catch(|| t.set_action(Some(a))))
    }

    /// Returns control to the scripted targets.
    fn clear_action(&mut self) -> PyResult<()> {
        let t = self.trial_mut()?;
        into_py(catch(|| t.set_action(None)))
    }

    /// Outcome so far (final once ``finished``): lift_success, stable_squeeze, failure,
    /// gate_opened_at (s or None), water_removed {phase: kg}, initial_water, final_water,
    /// total_water (kg), sim_time (s), steps, wall_s (s spent in ``step``), n_fluid, n_solid.
    fn outcome<'py>(&mut self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        let wall = self.held.wall;
        outcome_dict(py, &self.trial()?.outcome(wall))
    }

    /// The full state (simulation and robot layer) as bytes, for a bit-identical
    /// continuation with ``set_state`` or ``Trial.from_state``.
    fn get_state<'py>(&mut self, py: Python<'py>) -> PyResult<Bound<'py, PyBytes>> {
        self.held.state(py)
    }

    /// Replaces the whole state with one from ``get_state`` of a trial of the same config.
    /// Recorded rows are dropped. Raises StateError for bytes that are not a state or a
    /// state of another config (``Trial.from_state`` makes a trial of any state); the trial
    /// is unchanged then.
    fn set_state(&mut self, py: Python<'_>, state: &Bound<'_, PyAny>) -> PyResult<()> {
        self.held.set_state(py, state)?;
        if self.recorder.is_some() {
            self.start_recording();
        }
        Ok(())
    }

    /// A trial continuing from ``state`` (bytes of ``get_state``).
    #[staticmethod]
    #[pyo3(signature = (state, num_threads=None))]
    fn from_state(
        py: Python<'_>,
        state: &Bound<'_, PyAny>,
        #[pyo3(from_py_with = crate::errors::any_int_opt)] num_threads: Option<i128>,
    ) -> PyResult<Self> {
        let num_threads = crate::errors::threads(num_threads)?;
        Ok(Self::wrap(held::from_state(py, state, num_threads)?, num_threads, false))
    }

    /// Writes the state to ``path`` atomically (temporary name, then rename).
    fn save(&mut self, py: Python<'_>, path: PathBuf) -> PyResult<()> {
        self.held.save(py, &path)
    }

    /// A trial continuing from a state file written by ``save``.
    #[staticmethod]
    #[pyo3(signature = (path, num_threads=None))]
    fn load(
        py: Python<'_>,
        path: PathBuf,
        #[pyo3(from_py_with = crate::errors::any_int_opt)] num_threads: Option<i128>,
    ) -> PyResult<Self> {
        let num_threads = crate::errors::threads(num_threads)?;
        Ok(Self::wrap(held::load(py, &path, num_threads)?, num_threads, false))
    }

    /// Pickling: the state bytes (recorded rows are not included).
    fn __reduce__<'py>(slf: &Bound<'py, Self>) -> PyResult<Bound<'py, PyTuple>> {
        slf.borrow_mut().held.reduce(&slf.get_type())
    }

    fn __repr__(&mut self) -> String {
        match self.trial() {
            Ok(t) => {
                let s = t.simulation();
                format!(
                    "Trial(phase={:?}, time={:.4} s, fluid={}, solid={}, threads={})",
                    t.phase().name(),
                    s.time(),
                    s.particles().n_fluid,
                    s.particles().n_solid(),
                    s.threads()
                )
            }
            Err(_) => "Trial(<no valid state>)".to_owned(),
        }
    }
}
