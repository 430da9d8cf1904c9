//! A JSON value laid over a default of the same shape, checked key by key and type by type,
//! so that a config's errors name the dotted field (`controller.settle_time`,
//! `size[2]`) before serde parses it.

use rmi_sph::RmiError;
use serde_json::{Number, Value};

/// The dotted path of `key` inside the table at `path` (`key` alone at the root, `""`).
pub fn field_path(path: &str, key: &str) -> String {
    if path.is_empty() {
        key.to_owned()
    } else {
        format!("{path}.{key}")
    }
}

/// What a JSON value is, as errors say it.
fn kind(v: &Value) -> &'static str {
    match v {
        Value::Null => "null",
        Value::Bool(_) => "a bool",
        Value::Number(_) => "a number",
        Value::String(_) => "a string",
        Value::Array(_) => "a list",
        Value::Object(_) => "a table",
    }
}

/// Overlays `given` on `default` (same shape), checking every key and type: unknown keys,
/// wrong types and non-integral values of integer fields are errors naming the field
/// (`path` is the dotted path of `given`, `""` at the root). Tables merge key by key, lists
/// must have the default's length, a float field takes any number, an integer field any
/// non-negative integral number (`5.0` becomes `5`), and a field that is null by default
/// takes any value (serde checks it).
pub fn overlay(default: &Value, given: &Value, path: &str) -> Result<Value, RmiError> {
    match (default, given) {
        (Value::Object(d), Value::Object(g)) => {
            let mut out = d.clone();
            for (k, v) in g {
                let sub = field_path(path, k);
                let Some(dv) = d.get(k) else {
                    let known: Vec<&str> = d.keys().map(String::as_str).collect();
                    return Err(RmiError::config(sub, "(unknown field)", format!("one of: {}", known.join(", "))));
                };
                out.insert(k.clone(), overlay(dv, v, &sub)?);
            }
            Ok(Value::Object(out))
        }
        (Value::Object(_), other) => {
            Err(RmiError::config(path, other.to_string(), format!("a table (dict), not {}", kind(other))))
        }
        (Value::Array(d), Value::Array(g)) => {
            if d.len() != g.len() {
                return Err(RmiError::config(path, given.to_string(), format!("a list of {} values", d.len())));
            }
            let items: Result<Vec<_>, _> =
                d.iter().zip(g).enumerate().map(|(i, (dv, gv))| overlay(dv, gv, &format!("{path}[{i}]"))).collect();
            Ok(Value::Array(items?))
        }
        (Value::Array(d), other) => {
            Err(RmiError::config(path, other.to_string(), format!("a list of {} values", d.len())))
        }
        (Value::Number(dn), Value::Number(gn)) => number(dn, gn, given, path),
        (Value::Number(_), other) => {
            Err(RmiError::config(path, other.to_string(), format!("a number, not {}", kind(other))))
        }
        (Value::Bool(_), Value::Bool(_)) => Ok(given.clone()),
        (Value::Bool(_), other) => Err(RmiError::config(path, other.to_string(), "true or false")),
        (Value::String(_), Value::String(_)) => Ok(given.clone()),
        (Value::String(_), other) => Err(RmiError::config(path, other.to_string(), "a string")),
        // Optional fields (null by default) take whatever serde accepts.
        (Value::Null, _) => Ok(given.clone()),
    }
}

/// The number `gn` (`given`) in place of the default `dn`: a float field takes it as a
/// float, an integer field only as a non-negative integer.
fn number(dn: &Number, gn: &Number, given: &Value, path: &str) -> Result<Value, RmiError> {
    if dn.is_f64() {
        return Ok(Value::Number(Number::from_f64(gn.as_f64().unwrap_or(f64::NAN)).unwrap_or(gn.clone())));
    }
    // Integer field: accept integral floats (5.0), refuse fractions and negatives.
    let x = gn.as_f64().unwrap_or(f64::NAN);
    if gn.is_u64() {
        return Ok(given.clone());
    }
    if x.fract() == 0.0 && (0.0..=u64::MAX as f64).contains(&x) {
        return Ok(Value::Number((x as u64).into()));
    }
    Err(RmiError::config(path, gn.to_string(), "a non-negative integer"))
}

#[cfg(test)]
mod tests {
    use super::*;
    use serde_json::json;

    use crate::config::invalid_field as field;

    #[test]
    fn tables_merge_and_keep_the_defaults() {
        let d = json!({"a": 1.5, "t": {"n": 3, "s": "x"}});
        let out = overlay(&d, &json!({"t": {"n": 4.0}}), "").unwrap();
        assert_eq!(out, json!({"a": 1.5, "t": {"n": 4, "s": "x"}}));
    }

    #[test]
    fn errors_name_the_dotted_field() {
        let d = json!({"a": 1.5, "t": {"n": 3, "l": [0.0, 0.0]}, "o": null});
        assert_eq!(field(overlay(&d, &json!({"b": 1}), "").unwrap_err()), "b");
        assert_eq!(field(overlay(&d, &json!({"t": {"n": 2.5}}), "").unwrap_err()), "t.n");
        assert_eq!(field(overlay(&d, &json!({"t": {"n": -1}}), "").unwrap_err()), "t.n");
        assert_eq!(field(overlay(&d, &json!({"t": {"l": [1.0]}}), "").unwrap_err()), "t.l");
        assert_eq!(field(overlay(&d, &json!({"t": {"l": [1.0, "x"]}}), "").unwrap_err()), "t.l[1]");
        assert_eq!(field(overlay(&d, &json!({"t": 3}), "").unwrap_err()), "t");
        assert_eq!(field(overlay(&d, &json!({"a": true}), "").unwrap_err()), "a");
        assert_eq!(overlay(&d, &json!({"o": [1, 2]}), "").unwrap()["o"], json!([1, 2]));
    }

    #[test]
    fn paths_join_with_dots() {
        assert_eq!(field_path("", "gate"), "gate");
        assert_eq!(field_path("gate", "k_stable"), "gate.k_stable");
    }
}
