//! The trial config: JSON that keeps every bit, a partial JSON value over the defaults with
//! errors naming the dotted field, and the engine settings it hands on.

use rmi_robot::config::TrialConfig;
use rmi_sph::RmiError;
use serde_json::json;

mod common;
use common::tiny;

/// A saved trial carries its config as JSON: every float must come back with the same bits,
/// or a continuation (and a squeeze group's members) would run another trial.
#[test]
fn config_json_keeps_every_bit_of_its_floats() {
    let mut u: u64 = 0x9E37_79B9_7F4A_7C15;
    for _ in 0..20_000 {
        u = u.wrapping_mul(6_364_136_223_846_793_005).wrapping_add(1_442_695_040_888_963_407);
        let x = f64::from_bits((u >> 12) | 0x3FF0_0000_0000_0000) - 1.0; // in [0, 1)
        let back: f64 = serde_json::from_str(&serde_json::to_string(&x).unwrap()).unwrap();
        assert_eq!(back.to_bits(), x.to_bits(), "{x:e}");
    }
    // Values that need all 17 digits.
    let mut c = TrialConfig { hold_force: 60.0 + 1e-9 / 3.0, squeeze_force: 90.0, ..tiny() };
    c.friction.mu_static = 0.6 + 1e-3 / 7.0;
    c.material.youngs_modulus = 250_000.0 / 3.0;
    let back = TrialConfig::from_json(&c.to_json()).unwrap();
    assert_eq!(back.to_json(), c.to_json());
    assert_eq!(back.friction.mu_static.to_bits(), c.friction.mu_static.to_bits());
    assert_eq!(back.hold_force.to_bits(), c.hold_force.to_bits());
}

/// A partial value keeps the defaults elsewhere; errors name the dotted field, and the
/// value reads as the same config as its JSON text.
#[test]
fn json_values_lay_over_the_defaults() {
    let c = TrialConfig::from_json_value(&json!({"porosity": 0.5, "controller": {"settle_time": 0.07}})).unwrap();
    assert_eq!((c.porosity, c.material.porosity, c.controller.settle_time), (0.5, 0.5, 0.07));
    assert_eq!(c.hold_force, TrialConfig::default().hold_force);
    let text = tiny().to_json();
    let value: serde_json::Value = serde_json::from_str(&text).unwrap();
    assert_eq!(
        TrialConfig::from_json_value(&value).unwrap().to_json(),
        TrialConfig::from_json(&text).unwrap().to_json()
    );
    for (given, field) in [
        (json!({"dt": "fast"}), "dt"),
        (json!({"size": [0.1, 0.1]}), "size"),
        (json!({"controller": 3}), "controller"),
        (json!({"saturated": 1}), "saturated"),
        (json!({"record_every": 4.5}), "record_every"),
        (json!({"gripper": {"gapp": 0.01}}), "gripper.gapp"),
        (json!({"porosity": 0.99}), "porosity"),
    ] {
        match TrialConfig::from_json_value(&given) {
            Err(RmiError::InvalidConfig { field: f, .. }) => assert_eq!(f, field, "{given}"),
            other => panic!("{given}: {other:?}"),
        }
    }
    assert_eq!(TrialConfig::from_json_value(&json!({"record_every": 4.0})).unwrap().record_every, 4);
}

/// A trial's `cg` reaches the engine: its tolerance as given, `auto` as block Jacobi (the
/// two-level set-up does not pay over a gripped trial), a named preconditioner as named.
#[test]
fn trial_cg_settings_reach_the_engine() {
    use rmi_sph::config::Preconditioner;
    let mut c = TrialConfig::default();
    assert_eq!(c.cg.preconditioner, Preconditioner::Auto);
    c.cg.tolerance = 1e-4;
    let sim = c.sim_config();
    assert_eq!(sim.cg.preconditioner, Preconditioner::BlockJacobi);
    assert_eq!(sim.cg.tolerance, 1e-4);
    c.cg.preconditioner = Preconditioner::TwoLevel;
    assert_eq!(c.sim_config().cg.preconditioner, Preconditioner::TwoLevel);
    let partial = r#"{"cg": {"tolerance": 2e-3}}"#;
    let parsed = TrialConfig::from_json(partial).unwrap();
    assert_eq!(parsed.sim_config().cg.preconditioner, Preconditioner::BlockJacobi);
    assert_eq!(parsed.sim_config().cg.tolerance, 2e-3);
    let e = TrialConfig::from_json(r#"{"cg": {"tolerance": 0.5}}"#).unwrap_err().to_string();
    assert!(e.contains("cg.tolerance") && e.contains("0.5"), "{e}");
}

/// Every seed a config holds (the trial's, the perturbed targets', the engine scene's) is in
/// [0, SEED_MAX] (2^63 - 1), the range run files can store; one above is an error of one
/// line naming the field and that range, whichever way the config comes in.
#[test]
fn seeds_beyond_int64_are_refused_naming_the_field_and_the_range() {
    use rmi_sph::config::{seed_range, SEED_MAX};
    assert_eq!(SEED_MAX, i64::MAX as u64);
    assert_eq!(seed_range(), "an integer in [0, 9223372036854775807]");
    let top = TrialConfig::from_json_value(&json!({"seed": SEED_MAX})).unwrap();
    assert_eq!(top.seed, SEED_MAX);
    top.sim_config().validate().unwrap();
    let cases = [
        (json!({"seed": SEED_MAX + 1}), "seed"),
        (json!({"seed": u64::MAX}), "seed"),
        (
            json!({"controller": {"perturbation": {"enabled": true, "seed": SEED_MAX + 1}}}),
            "controller.perturbation.seed",
        ),
    ];
    for (given, want) in cases {
        let e = TrialConfig::from_json_value(&given).unwrap_err();
        let text = e.to_string();
        assert!(!text.contains('\n') && text.contains(&seed_range()), "{text}");
        match e {
            RmiError::InvalidConfig { field, .. } => assert_eq!(field, want, "{given}"),
            other => panic!("{given}: {other:?}"),
        }
        let e = TrialConfig::from_json(&given.to_string()).unwrap_err();
        assert!(e.to_string().contains(&format!("`{want}`")), "{e}");
    }
    let mut sim = tiny().sim_config();
    sim.scene.seed = SEED_MAX + 1;
    match sim.validate() {
        Err(RmiError::InvalidConfig { field, expected, .. }) => {
            assert_eq!((field.as_str(), expected), ("scene.seed", seed_range()))
        }
        other => panic!("{other:?}"),
    }
    assert!(rmi_robot::config::trial_config(8.0, 0.6, 20.0, 40.0, 0.01, SEED_MAX + 1, []).is_err());
}
