//! What the Python classes `Trial` and `engine.Simulation` share: the engine object they own,
//! rebuilt from its state in a forked child, its state as bytes and files, pickling, and
//! stepping in chunks with the GIL released and Ctrl-C checked between chunks.

use crate::errors::{to_pyerr, StateError};
use crate::panic::{catch, into_py, into_py_at, panic_err};
use pyo3::prelude::*;
use pyo3::types::{PyBytes, PyTuple, PyType};
use std::path::Path;
use std::time::{Duration, Instant};

/// Longest stretch of stepping between two checks for Ctrl-C.
const SIGNAL_INTERVAL: Duration = Duration::from_millis(50);

/// An engine object whose whole state serialises to bytes.
pub trait Stateful: Sized + Send + Sync {
    /// What the object is called in messages ("trial", "simulation").
    const NAME: &'static str;
    /// The full state, for a bit-identical continuation.
    fn to_bytes(&self) -> Vec<u8>;
    /// A new object continuing from `bytes` with `threads` workers (None: the default).
    fn from_bytes(bytes: &[u8], threads: Option<usize>) -> rmi_sph::Result<Self>;
    /// Writes the state to `path` atomically.
    fn save(&self, path: &Path) -> rmi_sph::Result<()>;
    /// The configuration as JSON (what `set_state` compares).
    fn config_json(&self) -> String;
    /// A new object continuing from a file written by [`Stateful::save`].
    fn load(path: &Path, threads: Option<usize>) -> rmi_sph::Result<Self>;
}

/// The engine object a Python class owns.
pub struct Held<T> {
    /// None after a panic inside the engine left no valid state.
    value: Option<T>,
    /// Worker threads asked for (None: the engine's default); kept for rebuilds and pickles.
    pub threads: Option<usize>,
    /// Process that built the object's thread pool.
    pid: u32,
    /// Wall-clock seconds spent stepping (s).
    pub wall: f64,
}

impl<T: Stateful> Held<T> {
    /// Holds `value`, built with `threads` workers.
    pub fn new(value: T, threads: Option<usize>) -> Self {
        Held { value: Some(value), threads, pid: std::process::id(), wall: 0.0 }
    }

    /// The object, rebuilt from its state in a forked child (the parent's worker threads do
    /// not exist there).
    pub fn get_mut(&mut self) -> PyResult<&mut T> {
        let Some(v) = self.value.as_mut() else {
            return Err(StateError::new_err(format!(
                "this {} has no valid state after an internal error; restore one with set_state() or load()",
                T::NAME
            )));
        };
        if self.pid != std::process::id() {
            let threads = self.threads;
            let fresh = into_py(catch(|| T::from_bytes(&v.to_bytes(), threads)))?;
            // The old pool's threads are gone in this process: leak it rather than touch it.
            std::mem::forget(self.value.replace(fresh));
            self.pid = std::process::id();
        }
        Ok(self.value.as_mut().expect("value present"))
    }

    /// [`Held::get_mut`], read only.
    pub fn get(&mut self) -> PyResult<&T> {
        self.get_mut().map(|v| &*v)
    }

    /// The state as Python bytes.
    pub fn state<'py>(&mut self, py: Python<'py>) -> PyResult<Bound<'py, PyBytes>> {
        let v = self.get()?;
        let bytes = py.detach(|| catch(|| Ok(v.to_bytes())));
        Ok(PyBytes::new(py, &into_py(bytes)?))
    }

    /// Replaces the object with one continuing from `state` (bytes of [`Held::state`]) of
    /// the same configuration; a `StateError` naming the first differing field otherwise.
    /// The state is restored into a new object first, so a failure changes nothing.
    pub fn set_state(&mut self, py: Python<'_>, state: &Bound<'_, PyAny>) -> PyResult<()> {
        let value = from_state::<T>(py, state, self.threads)?;
        if let Some(own) = self.value.as_ref() {
            let (mine, theirs) = (own.config_json(), value.config_json());
            if mine != theirs {
                let field = differing_field(&mine, &theirs);
                return Err(StateError::new_err(format!(
                    "the state is of another config (`{field}` differs from this {}'s); \
                     use from_state() for a new {} of that config",
                    T::NAME,
                    T::NAME
                )));
            }
        }
        self.value = Some(value);
        self.pid = std::process::id();
        Ok(())
    }

    /// Writes the state to `path` atomically.
    pub fn save(&mut self, py: Python<'_>, path: &Path) -> PyResult<()> {
        let v = self.get()?;
        into_py_at(py.detach(|| catch(|| v.save(path))), path)
    }

    /// Advances up to `n` steps, `step_one` taking each one: it returns whether it stepped
    /// (false stops here, before that step). Runs with the GIL released in chunks of at most
    /// 50 ms, checking for Ctrl-C between them; returns the steps taken. A panic leaves no
    /// object (see [`Held::get_mut`]).
    pub fn step<F>(&mut self, py: Python<'_>, n: u64, mut step_one: F) -> PyResult<u64>
    where
        F: FnMut(&mut T) -> rmi_sph::Result<bool> + Send,
    {
        self.get_mut()?;
        let mut done = 0u64;
        while done < n {
            let start = Instant::now();
            let value = self.value.as_mut().expect("checked above");
            let step_one = &mut step_one;
            let caught = py.detach(|| {
                catch(|| {
                    let mut k = 0u64;
                    while done + k < n {
                        if !step_one(value)? {
                            return Ok((k, true));
                        }
                        k += 1;
                        if start.elapsed() >= SIGNAL_INTERVAL {
                            break;
                        }
                    }
                    Ok((k, false))
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
                Ok(Err(e)) => return Err(to_pyerr(e)),
                Err(msg) => {
                    self.value = None;
                    return Err(panic_err(&msg));
                }
            }
            py.check_signals()?;
        }
        Ok(done)
    }

    /// Pickling: `(cls.from_state, (state, threads))`.
    pub fn reduce<'py>(&mut self, cls: &Bound<'py, PyType>) -> PyResult<Bound<'py, PyTuple>> {
        let py = cls.py();
        let state = self.state(py)?;
        let ctor = cls.getattr("from_state")?;
        let args = PyTuple::new(py, [state.into_any(), self.threads.into_pyobject(py)?.into_any()])?;
        PyTuple::new(py, [ctor, args.into_any()])
    }
}

/// The dotted path of the first value that differs between two configs as JSON.
fn differing_field(a: &str, b: &str) -> String {
    fn walk(a: &serde_json::Value, b: &serde_json::Value, path: &str) -> Option<String> {
        use serde_json::Value;
        let join = |k: &str| if path.is_empty() { k.to_owned() } else { format!("{path}.{k}") };
        match (a, b) {
            (Value::Object(x), Value::Object(y)) => x.keys().chain(y.keys()).find_map(|k| match (x.get(k), y.get(k)) {
                (Some(p), Some(q)) => walk(p, q, &join(k)),
                _ => Some(join(k)),
            }),
            (Value::Array(x), Value::Array(y)) if x.len() == y.len() => {
                x.iter().zip(y).enumerate().find_map(|(i, (p, q))| walk(p, q, &format!("{path}[{i}]")))
            }
            _ => (a != b).then(|| path.to_owned()),
        }
    }
    let parse = |t: &str| serde_json::from_str::<serde_json::Value>(t).unwrap_or(serde_json::Value::Null);
    walk(&parse(a), &parse(b), "").filter(|p| !p.is_empty()).unwrap_or_else(|| "config".to_owned())
}

fn state_bytes(state: &Bound<'_, PyAny>) -> PyResult<Vec<u8>> {
    state.extract::<Vec<u8>>().map_err(|_| StateError::new_err("a state must be bytes (from get_state())"))
}

/// A new object continuing from `state` (Python bytes of [`Held::state`]).
pub fn from_state<T: Stateful>(py: Python<'_>, state: &Bound<'_, PyAny>, threads: Option<usize>) -> PyResult<T> {
    let bytes = state_bytes(state)?;
    into_py(py.detach(|| catch(|| T::from_bytes(&bytes, threads))))
}

/// A new object continuing from a state file.
pub fn load<T: Stateful>(py: Python<'_>, path: &Path, threads: Option<usize>) -> PyResult<T> {
    into_py_at(py.detach(|| catch(|| T::load(path, threads))), path)
}
