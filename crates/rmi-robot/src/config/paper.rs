//! Trial configs of the paper's sponges: the size named in centimetres, the porosity, the
//! forces and the resolution, with further fields overridden by name.

use super::trial_config::TrialConfig;
use rmi_sph::presets::SPONGE_SIZES;
use rmi_sph::{Result, RmiError};
use serde_json::{Map, Number, Value};

/// The size (m) of the paper's sponge whose squeeze-axis side is `size_cm` centimetres (8,
/// 10 or 12, [`SPONGE_SIZES`]); `None` for any other value.
pub fn paper_sponge_size(size_cm: f64) -> Option<[f64; 3]> {
    SPONGE_SIZES.iter().copied().find(|s| (s[0] * 100.0).round() == size_cm)
}

/// The paper's sizes in centimetres as errors list them (`8, 10, 12`).
fn paper_sizes_cm() -> String {
    let cm: Vec<String> = SPONGE_SIZES.iter().map(|s| (s[0] * 100.0).round().to_string()).collect();
    cm.join(", ")
}

/// A trial config of one of the paper's sponges being put together: the named parameters
/// first ([`PaperTrial::new`]), then overrides one by one ([`PaperTrial::set`]), then the
/// checked config ([`PaperTrial::build`]). Each step refuses a bad value with an error naming
/// it, in the order the values were given.
#[derive(Clone, Debug)]
pub struct PaperTrial {
    /// The default config as JSON: the shape overrides are checked against.
    default: Value,
    /// Top-level fields given so far.
    given: Map<String, Value>,
    /// `ControllerParams` fields given so far, at the top level or under `controller`.
    controller: Map<String, Value>,
}

impl PaperTrial {
    /// The sponge of `size_cm` (8, 10 or 12) with porosity, holding and squeeze forces (N),
    /// particle radius (m) and jitter seed; every other field at its default. A size that is
    /// not the paper's, or a value that is not a finite number, is an error naming it
    /// (`size_cm`, `porosity`, `hold_force`, `squeeze_force`, `radius`); ranges are checked
    /// by [`PaperTrial::build`].
    pub fn new(
        size_cm: f64,
        porosity: f64,
        hold_force: f64,
        squeeze_force: f64,
        radius: f64,
        seed: u64,
    ) -> Result<Self> {
        let Some(size) = paper_sponge_size(size_cm) else {
            let expected = format!("one of the paper's sizes {} (cm)", paper_sizes_cm());
            return Err(RmiError::config("size_cm", size_cm, expected));
        };
        let num = |x: f64, name: &str| {
            Number::from_f64(x).map(Value::Number).ok_or_else(|| RmiError::config(name, x, "a finite number"))
        };
        let mut given = Map::new();
        given.insert("size".into(), Value::Array(size.iter().map(|s| Value::from(*s)).collect()));
        given.insert("porosity".into(), num(porosity, "porosity")?);
        given.insert("hold_force".into(), num(hold_force, "hold_force")?);
        given.insert("squeeze_force".into(), num(squeeze_force, "squeeze_force")?);
        given.insert("particle_radius".into(), num(radius, "radius")?);
        given.insert("seed".into(), Value::from(seed));
        Ok(PaperTrial { default: TrialConfig::default_json(), given, controller: Map::new() })
    }

    /// Overrides one field: a `TrialConfig` field (a table such as `gripper` merges into its
    /// defaults) or a `ControllerParams` field (`settle_time`, ...), which goes under
    /// `controller`. A controller field given at the top level wins over the same field in
    /// a `controller` table. An unknown name is an error naming it; values are checked by
    /// [`PaperTrial::build`].
    pub fn set(&mut self, key: &str, value: Value) -> Result<()> {
        let is_controller_field =
            self.default.get("controller").and_then(Value::as_object).is_some_and(|m| m.contains_key(key));
        if is_controller_field {
            self.controller.insert(key.to_owned(), value);
            return Ok(());
        }
        if self.default.get(key).is_none() {
            return Err(RmiError::config(
                key,
                "(unknown override)",
                "a TrialConfig field (dt, jitter, record_every, saturated, material, gripper, friction, gate, \
                 controller, ...) or a ControllerParams field (settle_time, ramp_time, hold_time, ...)",
            ));
        }
        if key == "controller" {
            if let Value::Object(m) = &value {
                for (ck, cv) in m {
                    self.controller.entry(ck.clone()).or_insert_with(|| cv.clone());
                }
                return Ok(());
            }
        }
        self.given.insert(key.to_owned(), value);
        Ok(())
    }

    /// The config: the given fields over the defaults, checked field by field
    /// ([`TrialConfig::from_json_value`]), so that errors name the dotted field
    /// (`controller.settle_time`, `gate.k_stable`).
    pub fn build(self) -> Result<TrialConfig> {
        let mut given = self.given;
        if !self.controller.is_empty() {
            given.insert("controller".into(), Value::Object(self.controller));
        }
        TrialConfig::from_json_value(&Value::Object(given))
    }
}

/// A trial config of the paper's sponge of `size_cm` (8, 10 or 12) with `overrides` applied
/// in order ([`PaperTrial`]). Errors name the bad parameter or the dotted field.
pub fn trial_config(
    size_cm: f64,
    porosity: f64,
    hold_force: f64,
    squeeze_force: f64,
    radius: f64,
    seed: u64,
    overrides: impl IntoIterator<Item = (String, Value)>,
) -> Result<TrialConfig> {
    let mut trial = PaperTrial::new(size_cm, porosity, hold_force, squeeze_force, radius, seed)?;
    for (key, value) in overrides {
        trial.set(&key, value)?;
    }
    trial.build()
}

#[cfg(test)]
mod tests {
    use super::*;
    use serde_json::json;

    use crate::config::invalid_field as field;

    fn with(overrides: Value) -> Result<TrialConfig> {
        let Value::Object(m) = overrides else { panic!("overrides are a table") };
        trial_config(8.0, 0.6, 20.0, 40.0, 0.01, 3, m)
    }

    #[test]
    fn the_paper_sizes_come_from_the_engine() {
        for (cm, size) in [8.0, 10.0, 12.0].into_iter().zip(SPONGE_SIZES) {
            assert_eq!(paper_sponge_size(cm), Some(size));
            assert_eq!(trial_config(cm, 0.5, 30.0, 60.0, 0.005, 0, []).unwrap().size, size);
        }
        assert_eq!(paper_sponge_size(9.0), None);
        let e = trial_config(9.0, 0.6, 20.0, 40.0, 0.005, 0, []).unwrap_err();
        assert!(e.to_string().contains("one of the paper's sizes 8, 10, 12 (cm)"), "{e}");
        assert_eq!(field(e), "size_cm");
    }

    #[test]
    fn overrides_reach_their_fields() {
        let c = with(json!({"settle_time": 0.07, "dt": 5e-4, "gate": {"k_stable": 7}})).unwrap();
        assert_eq!(c.controller.settle_time, 0.07);
        assert_eq!(c.dt, 5e-4);
        assert_eq!(c.gate.k_stable, 7);
        assert_eq!((c.seed, c.particle_radius, c.hold_force), (3, 0.01, 20.0));
        // A top-level controller field wins over the same field in a `controller` table,
        // whichever comes first.
        for o in [
            json!({"settle_time": 0.07, "controller": {"settle_time": 0.09, "ramp_time": 0.2}}),
            json!({"controller": {"settle_time": 0.09, "ramp_time": 0.2}, "settle_time": 0.07}),
        ] {
            let c = with(o).unwrap();
            assert_eq!((c.controller.settle_time, c.controller.ramp_time), (0.07, 0.2));
        }
    }

    #[test]
    fn errors_name_the_parameter_or_the_dotted_field() {
        assert_eq!(field(trial_config(8.0, 0.99, 20.0, 40.0, 0.005, 0, []).unwrap_err()), "porosity");
        assert_eq!(field(trial_config(8.0, 0.6, -1.0, 40.0, 0.005, 0, []).unwrap_err()), "hold_force");
        assert_eq!(field(trial_config(8.0, 0.6, 20.0, 40.0, f64::NAN, 0, []).unwrap_err()), "radius");
        let e = with(json!({"bogus": 1})).unwrap_err();
        assert!(e.to_string().contains("unknown override"), "{e}");
        assert_eq!(field(e), "bogus");
        assert_eq!(field(with(json!({"settle_time": -1.0})).unwrap_err()), "controller.settle_time");
        assert_eq!(field(with(json!({"material": {"porosty": 1}})).unwrap_err()), "material.porosty");
        assert_eq!(field(with(json!({"gate": {"k_stable": 2.5}})).unwrap_err()), "gate.k_stable");
        assert_eq!(field(with(json!({"cg": {"tolerance": 0.5}})).unwrap_err()), "cg.tolerance");
    }
}
