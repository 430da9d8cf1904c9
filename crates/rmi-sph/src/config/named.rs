//! Serde refusals reported by field: the dotted path of the value serde did not accept.

use crate::error::{Result, RmiError};
use serde::Serialize;

/// Deserialises a config of type `T` from JSON; a value serde refuses (an integer out of
/// its type's range, an unknown enum name, a wrong type) is an [`RmiError::InvalidConfig`]
/// naming its dotted path, found by trying each differing value alone on `T`'s default.
pub fn from_value_named<T>(value: &serde_json::Value) -> Result<T>
where
    T: serde::de::DeserializeOwned + Serialize + Default,
{
    let err = match serde_json::from_value::<T>(value.clone()) {
        Ok(cfg) => return Ok(cfg),
        Err(e) => e,
    };
    let root = serde_json::to_value(T::default()).expect("a default config serialises");
    let fails = |candidate: &serde_json::Value| serde_json::from_value::<T>(candidate.clone()).is_err();
    let (field, shown) = locate(&root, &root, value, "", "", &fails)
        .unwrap_or_else(|| ("(config)".to_owned(), "(see expected)".to_owned()));
    Err(RmiError::config(field, shown, expected_from_serde(&err.to_string())))
}

/// What serde says it expected (the part after its last ", expected "), with integer types
/// written as their ranges so that the message reads like the validator's own.
fn expected_from_serde(msg: &str) -> String {
    let Some(at) = msg.rfind("expected ") else { return msg.to_owned() };
    let wanted = msg[at + "expected ".len()..].trim();
    let range = |lo: i128, hi: i128| format!("an integer in [{lo}, {hi}]");
    match wanted {
        "u8" => range(0, u8::MAX.into()),
        "u16" => range(0, u16::MAX.into()),
        "u32" => range(0, u32::MAX.into()),
        "u64" => range(0, u64::MAX.into()),
        "usize" => range(0, usize::MAX as i128),
        "i32" => range(i32::MIN.into(), i32::MAX.into()),
        "i64" => range(i64::MIN.into(), i64::MAX.into()),
        "f64" | "f32" => "a number".to_owned(),
        other => other.to_owned(),
    }
}

/// The dotted path (and the value, as text) of the first entry of `given` that alone makes
/// `root` fail `fails`, `default` and `given` being the subtrees at JSON pointer `ptr`.
fn locate(
    root: &serde_json::Value,
    default: &serde_json::Value,
    given: &serde_json::Value,
    ptr: &str,
    dotted: &str,
    fails: &dyn Fn(&serde_json::Value) -> bool,
) -> Option<(String, String)> {
    use serde_json::Value;
    let entries: Vec<(String, String, Option<&Value>, &Value)> = match (default, given) {
        (Value::Object(d), Value::Object(g)) => g
            .iter()
            .map(|(k, gv)| {
                let sub = if dotted.is_empty() { k.clone() } else { format!("{dotted}.{k}") };
                (format!("{ptr}/{}", k.replace('~', "~0").replace('/', "~1")), sub, d.get(k), gv)
            })
            .collect(),
        (Value::Array(d), Value::Array(g)) if d.len() == g.len() => {
            g.iter().enumerate().map(|(i, gv)| (format!("{ptr}/{i}"), format!("{dotted}[{i}]"), d.get(i), gv)).collect()
        }
        _ => return None,
    };
    for (p, sub, dv, gv) in entries {
        let Some(dv) = dv else {
            // Unknown key: nothing to compare it with.
            return Some((sub, "(unknown field)".to_owned()));
        };
        if dv == gv {
            continue;
        }
        let mut candidate = root.clone();
        *candidate.pointer_mut(&p)? = gv.clone();
        if fails(&candidate) {
            return locate(root, dv, gv, &p, &sub, fails).or_else(|| Some((sub, gv.to_string())));
        }
    }
    None
}

pub(crate) fn json_path_hint(e: &serde_json::Error) -> String {
    // serde reports "unknown field `x`" or "invalid type ... for `y`"; surface the field name.
    let msg = e.to_string();
    if let Some(start) = msg.find('`') {
        if let Some(len) = msg[start + 1..].find('`') {
            return msg[start + 1..start + 1 + len].to_string();
        }
    }
    format!("(line {}, column {})", e.line(), e.column())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn serde_refusals_read_as_ranges() {
        assert_eq!(
            expected_from_serde("invalid value: integer `4294967296`, expected u32"),
            "an integer in [0, 4294967295]"
        );
        assert_eq!(expected_from_serde("unknown variant `x`, expected `sunk` or `surface`"), "`sunk` or `surface`");
        assert_eq!(expected_from_serde("invalid type: string \"a\", expected f64"), "a number");
    }
}
