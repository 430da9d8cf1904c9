//! Configurations from Python: dicts, JSON text or JSON files, converted to JSON values and
//! handed to the core. Trial configs are built and checked by `rmi_robot::config` (errors
//! name the dotted field); engine configs (`SimConfig`) go through the engine's own JSON
//! parser.
//!
//! Conversion only: defaults, field checks and ranges are the core's.

use crate::errors::to_pyerr;
use pyo3::exceptions::PyTypeError;
use pyo3::prelude::*;
use pyo3::types::{PyBool, PyDict, PyFloat, PyInt, PyList, PyString, PyTuple};
use rmi_robot::config::{field_path, PaperTrial, TrialConfig};
use rmi_sph::{RmiError, SimConfig};
use serde_json::{Map, Number, Value};

/// Deepest nesting of lists and tables a config value may have: real configs nest at most
/// four levels; the limit keeps a self-referencing or absurdly deep value from exhausting the
/// stack.
pub const MAX_DEPTH: usize = 64;

/// Converts a Python object (dict, list, tuple, number, bool, str, None, numpy scalar or
/// array) into JSON; `path` names it in errors. Nesting deeper than [`MAX_DEPTH`] and
/// containers that contain themselves are `ConfigError`s naming the path.
pub fn to_value(obj: &Bound<'_, PyAny>, path: &str) -> PyResult<Value> {
    to_value_at(obj, path, &mut Vec::new())
}

/// [`to_value`] with the containers on the path from the root (their object addresses).
fn to_value_at(obj: &Bound<'_, PyAny>, path: &str, open: &mut Vec<usize>) -> PyResult<Value> {
    if obj.is_none() {
        return Ok(Value::Null);
    }
    if obj.is_instance_of::<PyBool>() {
        return Ok(Value::Bool(obj.extract()?));
    }
    if obj.is_instance_of::<PyInt>() {
        if let Ok(v) = obj.extract::<i64>() {
            return Ok(Value::Number(v.into()));
        }
        if let Ok(v) = obj.extract::<u64>() {
            return Ok(Value::Number(v.into()));
        }
        return Err(to_pyerr(RmiError::config(path, obj.to_string(), "an integer that fits in 64 bits")));
    }
    if obj.is_instance_of::<PyFloat>() {
        let v: f64 = obj.extract()?;
        return Number::from_f64(v)
            .map(Value::Number)
            .ok_or_else(|| to_pyerr(RmiError::config(path, v, "a finite number")));
    }
    if let Ok(s) = obj.cast::<PyString>() {
        return Ok(Value::String(s.to_str()?.to_owned()));
    }
    let is_dict = obj.is_instance_of::<PyDict>();
    let is_list = obj.is_instance_of::<PyList>() || obj.is_instance_of::<PyTuple>();
    let has_tolist = !is_dict && !is_list && obj.hasattr("tolist")?;
    if !(is_dict || is_list || has_tolist) {
        return Err(PyTypeError::new_err(format!(
            "config field `{}` has unsupported type {}; use numbers, bools, strings, lists and dicts",
            shown(path),
            obj.get_type().name()?
        )));
    }
    let id = obj.as_ptr() as usize;
    if open.contains(&id) {
        return Err(to_pyerr(RmiError::config(
            shown(path),
            "(a container that contains itself)",
            "a value without cycles",
        )));
    }
    if open.len() >= MAX_DEPTH {
        return Err(to_pyerr(RmiError::config(
            shown(path),
            "(nesting deeper than 64)",
            format!("lists and tables nested at most {MAX_DEPTH} deep"),
        )));
    }
    open.push(id);
    let out = nested(obj, path, open, is_dict, is_list);
    open.pop();
    out
}

/// The JSON of a dict, list, tuple or object with `tolist()` (numpy), one level below `open`.
fn nested(obj: &Bound<'_, PyAny>, path: &str, open: &mut Vec<usize>, is_dict: bool, is_list: bool) -> PyResult<Value> {
    if is_dict {
        let mut map = Map::new();
        for (k, v) in obj.cast::<PyDict>()?.iter() {
            let key: String = k
                .extract()
                .map_err(|_| to_pyerr(RmiError::config(shown(path), k.to_string(), "a table with string keys")))?;
            let sub = field_path(path, &key);
            map.insert(key, to_value_at(&v, &sub, open)?);
        }
        return Ok(Value::Object(map));
    }
    if is_list {
        let mut out = Vec::new();
        for (i, v) in obj.try_iter()?.enumerate() {
            out.push(to_value_at(&v?, &format!("{path}[{i}]"), open)?);
        }
        return Ok(Value::Array(out));
    }
    // numpy scalars and arrays (and anything else with the same protocol); an object whose
    // `tolist()` returns another such object counts one level deeper each time.
    let plain = obj.call_method0("tolist")?;
    if plain.is(obj) {
        return Err(PyTypeError::new_err(format!(
            "config field `{}` has unsupported type {} (its tolist() returns itself)",
            shown(path),
            obj.get_type().name()?
        )));
    }
    to_value_at(&plain, path, open)
}

/// A path as errors show it (`<root>` for the whole value).
fn shown(path: &str) -> &str {
    if path.is_empty() {
        "<root>"
    } else {
        path
    }
}

/// Where a config comes from: a dict, as JSON, or JSON text (given, or read from a file).
enum Source {
    Value(Value),
    Text(String),
}

/// A dict, a JSON file path (str or os.PathLike) or JSON text (a str starting with `{`).
fn source(obj: &Bound<'_, PyAny>) -> PyResult<Source> {
    if obj.is_instance_of::<PyDict>() {
        return Ok(Source::Value(to_value(obj, "")?));
    }
    let text = if let Ok(s) = obj.cast::<PyString>() {
        let s = s.to_str()?;
        if s.trim_start().starts_with('{') {
            s.to_owned()
        } else {
            read(s)?
        }
    } else if obj.hasattr("__fspath__")? {
        let p: String = obj.call_method0("__fspath__")?.extract()?;
        read(&p)?
    } else {
        return Err(PyTypeError::new_err(format!(
            "config must be a dict, a JSON string or a path to a JSON file, not {}",
            obj.get_type().name()?
        )));
    };
    Ok(Source::Text(text))
}

/// A trial config from a dict, a JSON file path (str or os.PathLike) or JSON text.
pub fn extract(obj: &Bound<'_, PyAny>) -> PyResult<TrialConfig> {
    let value = match source(obj)? {
        Source::Value(v) => v,
        Source::Text(text) => serde_json::from_str(&text)
            .map_err(|e| to_pyerr(RmiError::config("trial", e.to_string(), "valid JSON text of a TrialConfig")))?,
    };
    TrialConfig::from_json_value(&value).map_err(to_pyerr)
}

/// An engine config from a dict, a JSON file path or JSON text, parsed and validated by
/// `SimConfig::from_json` (so errors name the field exactly as in Rust).
pub fn extract_sim(obj: &Bound<'_, PyAny>) -> PyResult<SimConfig> {
    let text = match source(obj)? {
        Source::Value(v) => v.to_string(),
        Source::Text(text) => text,
    };
    SimConfig::from_json(&text).map_err(to_pyerr)
}

/// Longest config file read (bytes): real ones are a few kB.
const MAX_CONFIG_BYTES: u64 = 4 << 20;

/// The text of a config file: a regular file of at most [`MAX_CONFIG_BYTES`] in UTF-8.
fn read(path: &str) -> PyResult<String> {
    let at = |e: std::io::Error| to_pyerr(RmiError::Io(std::io::Error::new(e.kind(), format!("{path}: {e}"))));
    let bytes = rmi_sph::simulation::read_limited(std::path::Path::new(path), MAX_CONFIG_BYTES, "config file")
        .map_err(|e| match e {
            RmiError::Io(err) if err.to_string().contains(path) => to_pyerr(RmiError::Io(err)),
            RmiError::Io(err) => at(err),
            other => to_pyerr(other),
        })?;
    String::from_utf8(bytes).map_err(|e| at(std::io::Error::new(std::io::ErrorKind::InvalidData, e)))
}

/// JSON text as Python objects (floats round-trip exactly).
fn json_dict<'py>(py: Python<'py>, text: &str) -> PyResult<Bound<'py, PyAny>> {
    py.import("json")?.call_method1("loads", (text,))
}

/// A trial config as a Python dict (through JSON, so it round-trips exactly).
pub fn to_dict<'py>(py: Python<'py>, cfg: &TrialConfig) -> PyResult<Bound<'py, PyAny>> {
    json_dict(py, &cfg.to_json())
}

/// An engine config as a Python dict (through JSON, so it round-trips exactly).
pub fn sim_to_dict<'py>(py: Python<'py>, cfg: &SimConfig) -> PyResult<Bound<'py, PyAny>> {
    json_dict(py, &cfg.to_json())
}

/// `trial_config`: a paper sponge (size 8, 10 or 12 cm) with overrides, each converted in
/// the order given and handed to [`PaperTrial`].
pub fn trial_config(
    size_cm: f64,
    porosity: f64,
    hold_force: f64,
    squeeze_force: f64,
    radius: f64,
    seed: u64,
    overrides: Option<&Bound<'_, PyDict>>,
) -> PyResult<TrialConfig> {
    let mut trial = PaperTrial::new(size_cm, porosity, hold_force, squeeze_force, radius, seed).map_err(to_pyerr)?;
    if let Some(o) = overrides {
        for (k, v) in o.iter() {
            let key: String = k.extract()?;
            let value = to_value(&v, &key)?;
            trial.set(&key, value).map_err(to_pyerr)?;
        }
    }
    trial.build().map_err(to_pyerr)
}
