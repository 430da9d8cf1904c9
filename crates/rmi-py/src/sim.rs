//! `rmi_sph.Simulation`: one grasp-lift-squeeze trial (the porous simulation, the pads and
//! the robot layer) stepped from Python.

use crate::config;
use crate::convert::{columns, observation_dict, outcome_dict, vec3_array};
use crate::errors::StateError;
use crate::panic::{catch, into_py, panic_err};
use numpy::PyArray1;
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;
use pyo3::types::{PyBytes, PyDict, PyList, PyTuple};
use rmi_robot::controller::Action;
use rmi_robot::observe::Observation;
use rmi_robot::Trial;
use std::time::{Duration, Instant};

/// Longest stretch of stepping between two checks for Ctrl-C.
const SIGNAL_INTERVAL: Duration = Duration::from_millis(50);

/// Rows recorded while stepping, at the cadence of `run_trial`.
struct Recorder {
    every: u64,
    rows: Vec<Observation>,
}

/// A grasp-lift-squeeze trial stepped from Python.
///
/// Parameters
/// ----------
/// config : dict | str | os.PathLike
///     A trial configuration: a dict (missing fields take their defaults, see
///     ``default_config()``), JSON text, or the path of a JSON file.
/// num_threads : int, optional
///     Worker threads of this simulation's own pool (default: ``$RMI_NUM_THREADS``, else
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
/// rebuilds the thread pool from the state on its next call.
#[pyclass(module = "rmi_sph._rmi_sph", name = "Simulation")]
pub struct PySimulation {
    trial: Option<Trial>,
    threads: Option<usize>,
    pid: u32,
    recorder: Option<Recorder>,
    wall: f64,
}

impl PySimulation {
    fn wrap(trial: Trial, threads: Option<usize>, record: bool) -> Self {
        let mut sim = PySimulation { trial: Some(trial), threads, pid: std::process::id(), recorder: None, wall: 0.0 };
        if record {
            sim.start_recording();
        }
        sim
    }

    fn start_recording(&mut self) {
        if let Some(t) = self.trial.as_mut() {
            let every = t.config().record_every as u64;
            self.recorder = Some(Recorder { every, rows: vec![t.take_record()] });
        }
    }

    /// The trial, rebuilt from its state in a forked child (the parent's worker threads do
    /// not exist there).
    fn trial_mut(&mut self) -> PyResult<&mut Trial> {
        let Some(t) = self.trial.as_mut() else {
            return Err(StateError::new_err(
                "this simulation has no valid state after an internal error; restore one with set_state() or load()",
            ));
        };
        if self.pid != std::process::id() {
            let threads = self.threads;
            let fresh = into_py(catch(|| Trial::from_bytes(&t.to_bytes(), threads)))?;
            // The old pool's threads are gone in this process: leak it rather than touch it.
            std::mem::forget(self.trial.replace(fresh));
            self.pid = std::process::id();
        }
        Ok(self.trial.as_mut().expect("trial present"))
    }

    fn trial(&mut self) -> PyResult<&Trial> {
        self.trial_mut().map(|t| &*t)
    }

    fn replace(&mut self, trial: Trial) {
        self.trial = Some(trial);
        self.pid = std::process::id();
        if self.recorder.is_some() {
            self.start_recording();
        }
    }
}

fn state_bytes(state: &Bound<'_, PyAny>) -> PyResult<Vec<u8>> {
    state.extract::<Vec<u8>>().map_err(|_| StateError::new_err("a state must be bytes (from get_state())"))
}

#[pymethods]
impl PySimulation {
    #[new]
    #[pyo3(signature = (config, *, num_threads=None, record=false))]
    fn new(py: Python<'_>, config: &Bound<'_, PyAny>, num_threads: Option<i64>, record: bool) -> PyResult<Self> {
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
    fn step(&mut self, py: Python<'_>, n: i64, stop_at_finish: bool) -> PyResult<u64> {
        let n: u64 = crate::errors::unsigned("n", n, "a non-negative integer (steps)")?;
        self.trial_mut()?;
        let mut done = 0u64;
        while done < n {
            let start = Instant::now();
            let PySimulation { trial, recorder, .. } = self;
            let trial = trial.as_mut().expect("checked above");
            let caught = py.detach(|| {
                catch(|| {
                    let mut k = 0u64;
                    while done + k < n {
                        let was_finished = trial.finished();
                        if was_finished && stop_at_finish {
                            return Ok((k, true));
                        }
                        trial.step()?;
                        k += 1;
                        if let Some(r) = recorder.as_mut() {
                            let steps = trial.simulation().step_count();
                            if !was_finished && (steps % r.every == 0 || trial.finished()) {
                                r.rows.push(trial.take_record());
                            }
                        }
                        if start.elapsed() >= SIGNAL_INTERVAL {
                            break;
                        }
                    }
                    Ok((k, stop_at_finish && trial.finished()))
                })
            });
            self.wall += start.elapsed().as_secs_f64();
            match caught {
                Ok(Ok((k, stop))) => {
                    done += k;
                    if stop {
                        return Ok(done);
                    }
                }
                Ok(Err(e)) => return Err(crate::errors::to_pyerr(e)),
                Err(msg) => {
                    self.trial = None;
                    return Err(panic_err(&msg));
                }
            }
            py.check_signals()?;
        }
        Ok(done)
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

    /// Worker threads of this simulation's pool.
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
    /// (m/s), ``gate_open`` (bool), ``M_expelled`` (kg), ``lift_height`` (m), ``F_target``
    /// (N) and ``v_cmd`` (m/s) of the last command. Pad loads are those of the last step.
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
    /// Raises StateError on a simulation created with ``record=True`` (its recorder owns the
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
            return Err(StateError::new_err("this simulation does not record; create it with record=True"));
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
    /// pressure Pa, porosity (local, -), skeleton_cover (-), retained (bool: inside the
    /// sponge's deformed volume, what ``M_L`` sums), id.
    /// ``"solid"`` (the sponge skeleton): positions, velocities, mass, density (bulk, dry),
    /// pressure (skeleton pressure unknown times its density, Pa), porosity (current local),
    /// saturation (-), rest_positions, id.
    /// ``"boundary"`` (floor and pads): positions, velocities, volume m^3, body (int index
    /// into ``bodies()``).
    fn particles<'py>(&mut self, py: Python<'py>, kind: &str) -> PyResult<Bound<'py, PyDict>> {
        let sim = self.trial()?.simulation();
        let d = PyDict::new(py);
        let p = sim.particles();
        let nf = p.n_fluid;
        let range = match kind {
            "fluid" => 0..nf,
            "solid" => nf..p.len(),
            "boundary" => {
                let b = sim.boundary();
                d.set_item("positions", vec3_array(py, &b.x)?)?;
                d.set_item("velocities", vec3_array(py, &b.v)?)?;
                d.set_item("volume", PyArray1::from_vec(py, b.volume.clone()))?;
                d.set_item("body", PyArray1::from_vec(py, b.body.iter().map(|&x| x as i32).collect::<Vec<_>>()))?;
                return Ok(d);
            }
            other => {
                return Err(PyValueError::new_err(format!(
                    "unknown particle kind {other:?}; expected 'fluid', 'solid' or 'boundary'"
                )))
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
        if kind == "fluid" {
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

    /// Rigid bodies (floor, pads) as a list of dicts: name, shape (``"box"`` or
    /// ``"container"``), half_extents (m), position (m), rotation (unit quaternion
    /// ``(w, x, y, z)``), velocity (m/s), kinematic (bool), force (N, from the last step).
    fn bodies<'py>(&mut self, py: Python<'py>) -> PyResult<Bound<'py, PyList>> {
        let sim = self.trial()?.simulation();
        let out = PyList::empty(py);
        for b in &sim.boundary().bodies {
            let d = PyDict::new(py);
            let (shape, he) = match &b.shape {
                rmi_sph::config::Shape::Box { half_extents } => ("box", half_extents),
                rmi_sph::config::Shape::Container { half_extents } => ("container", half_extents),
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
        let wall = self.wall;
        outcome_dict(py, &self.trial()?.outcome(wall))
    }

    /// The full state (simulation and robot layer) as bytes, for a bit-identical
    /// continuation with ``set_state`` or ``Simulation.from_state``.
    fn get_state<'py>(&mut self, py: Python<'py>) -> PyResult<Bound<'py, PyBytes>> {
        let t = self.trial()?;
        let bytes = py.detach(|| catch(|| Ok(t.to_bytes())));
        Ok(PyBytes::new(py, &into_py(bytes)?))
    }

    /// Replaces the whole state (its config included) with one from ``get_state``. Recorded
    /// rows are dropped. Raises StateError for bytes that are not a state.
    fn set_state(&mut self, py: Python<'_>, state: &Bound<'_, PyAny>) -> PyResult<()> {
        let bytes = state_bytes(state)?;
        let threads = self.threads;
        let t = into_py(py.detach(|| catch(|| Trial::from_bytes(&bytes, threads))))?;
        self.replace(t);
        Ok(())
    }

    /// A simulation continuing from ``state`` (bytes of ``get_state``).
    #[staticmethod]
    #[pyo3(signature = (state, num_threads=None))]
    fn from_state(py: Python<'_>, state: &Bound<'_, PyAny>, num_threads: Option<i64>) -> PyResult<Self> {
        let num_threads = crate::errors::threads(num_threads)?;
        let bytes = state_bytes(state)?;
        let t = into_py(py.detach(|| catch(|| Trial::from_bytes(&bytes, num_threads))))?;
        Ok(Self::wrap(t, num_threads, false))
    }

    /// Writes the state to ``path`` atomically (temporary name, then rename).
    fn save(&mut self, py: Python<'_>, path: std::path::PathBuf) -> PyResult<()> {
        let t = self.trial()?;
        crate::panic::into_py_at(py.detach(|| catch(|| t.save(&path))), &path)
    }

    /// A simulation continuing from a state file written by ``save``.
    #[staticmethod]
    #[pyo3(signature = (path, num_threads=None))]
    fn load(py: Python<'_>, path: std::path::PathBuf, num_threads: Option<i64>) -> PyResult<Self> {
        let num_threads = crate::errors::threads(num_threads)?;
        let t = crate::panic::into_py_at(py.detach(|| catch(|| Trial::load(&path, num_threads))), &path)?;
        Ok(Self::wrap(t, num_threads, false))
    }

    /// Pickling: the state bytes (recorded rows are not included).
    fn __reduce__<'py>(slf: &Bound<'py, Self>) -> PyResult<Bound<'py, PyTuple>> {
        let py = slf.py();
        let state = slf.borrow_mut().get_state(py)?;
        let threads = slf.borrow().threads;
        let ctor = slf.get_type().getattr("from_state")?;
        PyTuple::new(
            py,
            [ctor, PyTuple::new(py, [state.into_any(), threads.into_pyobject(py)?.into_any()])?.into_any()],
        )
    }

    fn __repr__(&mut self) -> String {
        match self.trial() {
            Ok(t) => {
                let s = t.simulation();
                format!(
                    "Simulation(phase={:?}, time={:.4} s, fluid={}, solid={}, threads={})",
                    t.phase().name(),
                    s.time(),
                    s.particles().n_fluid,
                    s.particles().n_solid(),
                    s.threads()
                )
            }
            Err(_) => "Simulation(<no valid state>)".to_owned(),
        }
    }
}
