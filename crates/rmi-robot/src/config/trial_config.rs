//! [`TrialConfig`]: everything that defines a trial, its defaults, its checks, and the
//! simulation scene it describes.

use super::overlay::overlay;
use crate::controller::ControllerParams;
use crate::gate::GateParams;
use crate::gripper::{add_pads, GripperConfig, FORCE_LIMIT};
use rmi_sph::config::{
    check_range, check_seed, CgConfig, PorousMaterial, Preconditioner, PressureConfig, SimConfig, WallLayer,
};
use rmi_sph::contact::FrictionParams;
use rmi_sph::{presets, Result, RmiError};
use serde::{Deserialize, Serialize};

/// Everything that defines a trial (SI units). Serialised as JSON for stored runs.
#[derive(Clone, Debug, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct TrialConfig {
    /// Sponge size along x (squeeze axis), y and z (height) (m).
    pub size: [f64; 3],
    /// Porosity phi of the skeleton (-); the source of truth: `material.porosity` is
    /// validated and then set to it ([`TrialConfig::normalised`]).
    pub porosity: f64,
    /// Holding force before and during the lift (N).
    pub hold_force: f64,
    /// Squeeze force after the lift (N).
    pub squeeze_force: f64,
    /// Particle radius r (m).
    pub particle_radius: f64,
    /// Time step (s).
    pub dt: f64,
    /// Seed of the initial pore-water jitter, in [0, `SEED_MAX`] (2^63 - 1).
    pub seed: u64,
    /// Pore-water jitter as a fraction of the spacing.
    pub jitter: f64,
    /// Start with water in the pores.
    pub saturated: bool,
    /// Time (s) the pore water settles into the pinned skeleton before the trial's clock
    /// starts (`SceneConfig::soak_time`): the faces' pore water then starts at the rest
    /// density instead of the lattice's thinner sum, so that closing pores expels water.
    pub soak_time: f64,
    /// Skeleton material (its porosity is replaced by `porosity`).
    pub material: PorousMaterial,
    /// Pads.
    pub gripper: GripperConfig,
    /// Pad-skeleton friction (the floor uses the same law).
    pub friction: FrictionParams,
    /// Controller timing, gains and guards.
    pub controller: ControllerParams,
    /// Lift gate.
    pub gate: GateParams,
    /// Pressure solve (tolerance, iterations, drag coupling of the pressure impulse).
    pub pressure: PressureConfig,
    /// Implicit solve (tolerance, iterations, preconditioner). In a trial, `auto` means block
    /// Jacobi at every resolution: the two-level CG saves no time over a gripped 8 cm trial
    /// (docs/benchmark-history.md, "Porous anchor: a two-level preconditioner for the
    /// implicit CG" and "The two-level preconditioner applied additively, its coarse matrix
    /// kept for ten steps"). Name `two_level` to use it anyway.
    pub cg: CgConfig,
    /// Placement of the floor's and pads' boundary particles.
    pub wall_layer: WallLayer,
    /// Simulator steps per recorded row of [`run_trial`](crate::trial::run_trial).
    pub record_every: u32,
}

impl Default for TrialConfig {
    fn default() -> Self {
        TrialConfig {
            size: presets::SPONGE_SIZES[1],
            porosity: 0.6,
            hold_force: 40.0,
            squeeze_force: 80.0,
            particle_radius: 0.005,
            dt: 1e-3,
            seed: 0,
            jitter: 0.05,
            saturated: true,
            soak_time: presets::SOAK_TIME,
            material: PorousMaterial::default(),
            gripper: GripperConfig::default(),
            friction: FrictionParams::default(),
            controller: ControllerParams::default(),
            gate: GateParams::default(),
            pressure: PressureConfig::default(),
            cg: CgConfig::default(),
            wall_layer: WallLayer::Sunk,
            record_every: 5,
        }
    }
}

impl TrialConfig {
    /// Parses JSON (unknown fields are errors naming the field), then validates.
    /// Values serde refuses (an integer out of range, an unknown `wall_layer`) are errors
    /// naming their dotted path. `material.porosity` takes the value of `porosity`.
    pub fn from_json(s: &str) -> Result<Self> {
        let value: serde_json::Value = serde_json::from_str(s)
            .map_err(|e| RmiError::config("trial", e.to_string(), "valid JSON matching TrialConfig"))?;
        let c: TrialConfig = rmi_sph::config::from_value_named(&value)?;
        c.validate()?;
        Ok(c.normalised())
    }

    /// A config from a JSON value laid over the defaults: every key and type is checked
    /// against the default config's shape first, so that an unknown field, a wrong type or a
    /// fraction in an integer field is an error naming its dotted path
    /// ([`overlay()`]); then the value is parsed, validated and
    /// [`normalised`](TrialConfig::normalised). Fields the value leaves out keep their
    /// defaults.
    pub fn from_json_value(given: &serde_json::Value) -> Result<Self> {
        let merged = overlay(&Self::default_json(), given, "")?;
        let cfg: TrialConfig = rmi_sph::config::from_value_named(&merged)?;
        cfg.validate()?;
        Ok(cfg.normalised())
    }

    /// The default config as a JSON value (every field).
    pub fn default_json() -> serde_json::Value {
        serde_json::to_value(TrialConfig::default()).expect("the default trial config serialises")
    }

    /// This config with `material.porosity` set to `porosity`, the value the scene uses (so
    /// that the config reads as what it simulates).
    pub fn normalised(mut self) -> Self {
        self.material.porosity = self.porosity;
        self
    }

    /// JSON text of this config.
    pub fn to_json(&self) -> String {
        serde_json::to_string_pretty(self).expect("trial config serialises")
    }

    /// Checks every field; errors name the field and the accepted range.
    pub fn validate(&self) -> Result<()> {
        for (k, s) in self.size.iter().enumerate() {
            check_range(&format!("size[{k}]"), *s, 0.01, 1.0, "m")?;
        }
        check_range("porosity", self.porosity, 0.05, 0.95, "(dimensionless)")?;
        // Every field of the material under its own name; its porosity is replaced by
        // `porosity` but must still be a porosity.
        self.material.validate("material")?;
        check_range("hold_force", self.hold_force, 0.0, FORCE_LIMIT, "N")?;
        check_range("squeeze_force", self.squeeze_force, 0.0, FORCE_LIMIT, "N")?;
        check_range("jitter", self.jitter, 0.0, 0.25, "(fraction of the spacing)")?;
        check_seed("seed", self.seed)?;
        check_range("soak_time", self.soak_time, 0.0, 10.0, "s")?;
        if self.record_every == 0 || self.record_every > 1_000_000 {
            return Err(RmiError::config("record_every", self.record_every, "an integer in [1, 1000000]"));
        }
        let d = 2.0 * self.particle_radius;
        if self.size.iter().any(|s| *s < 3.0 * d) {
            return Err(RmiError::config(
                "particle_radius",
                self.particle_radius,
                format!(
                    "at most {} m (three particles across the smallest sponge side)",
                    self.size.iter().cloned().fold(f64::INFINITY, f64::min) / 6.0
                ),
            ));
        }
        self.gripper.validate("gripper")?;
        self.friction.validate("friction")?;
        self.controller.validate("controller")?;
        self.gate.validate("gate")?;
        self.sim_config().validate()
    }

    /// The simulation scene: the sponge on its floor (`presets::sponge`: its sides the
    /// nearest whole numbers of spacings), the pads at both sides.
    pub fn sim_config(&self) -> SimConfig {
        let mut cfg = presets::sponge(self.size, self.porosity, self.particle_radius);
        cfg.dt = self.dt;
        cfg.scene.seed = self.seed;
        cfg.scene.jitter = self.jitter;
        cfg.scene.soak_time = self.soak_time;
        cfg.pressure = self.pressure.clone();
        cfg.wall_layer = self.wall_layer;
        cfg.cg = self.cg.clone();
        if cfg.cg.preconditioner == Preconditioner::Auto {
            cfg.cg.preconditioner = Preconditioner::BlockJacobi;
        }
        let block = &mut cfg.scene.porous_blocks[0];
        block.material = PorousMaterial { porosity: self.porosity, ..self.material.clone() };
        block.saturated = self.saturated;
        let (min, max) = (block.min, block.max);
        add_pads(&mut cfg, min, max, &self.gripper);
        cfg
    }

    /// Simulated time after which a trial that has not finished is stopped (s): every phase
    /// at its longest plus the time to close the initial gap.
    pub fn time_limit(&self) -> f64 {
        let c = &self.controller;
        let close = (2.0 * self.gripper.gap + self.size[0]) / (2.0 * c.close_speed);
        c.settle_time
            + close
            + c.ramp_time
            + c.hold_time
            + c.gate_timeout
            + 2.0 * c.lift_height / c.lift_speed
            + c.lift_accel_time
            + c.wait_time
            + c.squeeze_ramp_time
            + c.squeeze_hold_time
            + 1.0
    }
}
