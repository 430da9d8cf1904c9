//! Simulation configuration: serde structs with units, defaults and range validation.
//!
//! All quantities are SI (m, s, kg, N, Pa). One JSON document reproduces a simulation.
//! [`SimConfig::validate`] checks every field and names the first offending one.

use crate::error::{Result, RmiError};
use serde::{Deserialize, Serialize};

mod memory;
mod named;
mod validate;

pub use validate::{check_range, check_seed, seed_range, DENSITY_RANGE, SEED_MAX};

pub use memory::{
    memory_limit, BOUNDARY_PARTICLE_BYTES, FALLBACK_MEMORY_LIMIT, FLUID_PARTICLE_BYTES, POROUS_PARTICLE_BYTES,
};
pub use named::from_value_named;
use named::json_path_hint;

/// How fluid viscosity is applied.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ViscosityMode {
    /// Weiler et al. 2018 viscosity inside the strongly coupled implicit solve.
    Implicit,
    /// SPlisHSPlasH's explicit "standard" Laplacian viscosity (for comparisons).
    Explicit,
}

/// Preconditioner of the implicit non-pressure CG solve.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Preconditioner {
    /// No preconditioning (what the reference code does).
    Identity,
    /// Exact 3x3 diagonal blocks of the viscosity, drag and adhesion terms plus the dominant
    /// neighbour term of elasticity.
    BlockJacobi,
    /// Block Jacobi plus a coarse correction on aggregates of `coarse_cell` spacings (the
    /// translations of each aggregate; see `solver/linalg/coarse.rs`): far fewer iterations for a
    /// stiff skeleton.
    TwoLevel,
    /// `two_level` for a skeleton of at least [`TWO_LEVEL_MIN_SOLIDS`](crate::solver::TWO_LEVEL_MIN_SOLIDS)
    /// (4,000) free particles, where its set-up per step pays for itself; `block_jacobi` below.
    Auto,
}

/// Where the one layer of boundary particles of each body lies.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum WallLayer {
    /// Sunk [`crate::world::boundary::wall_depth`] (0.598 d) below the surface, so that water rests
    /// half a spacing off a wall, where skeleton contacts hold a sponge's face particles and
    /// where volume-map boundaries (Bender et al. 2019) put water.
    Sunk,
    /// On the surface (Akinci et al. 2012 as SPlisHSPlasH samples it): water rests 1.1 d
    /// off a wall, so the pores of a sponge held against it at d/2 stay out of the water's
    /// reach (the engine's placement before the sunk layer; for comparisons).
    Surface,
}

/// Water (the liquid phase).
#[derive(Clone, Debug, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct FluidConfig {
    /// Rest density in kg/m^3.
    pub density: f64,
    /// Kinematic viscosity of the SPH viscosity term in m^2/s (numerical, not water's 1e-6).
    pub viscosity: f64,
    /// Kinematic viscosity against boundaries (walls, plates) in m^2/s.
    pub boundary_viscosity: f64,
    /// Implicit (in the coupled solve) or explicit viscosity.
    pub viscosity_mode: ViscosityMode,
    /// Physical dynamic viscosity used to convert permeability into the drag coefficient, Pa s.
    pub darcy_viscosity: f64,
}

impl Default for FluidConfig {
    fn default() -> Self {
        FluidConfig {
            density: 1000.0,
            viscosity: 1e-3,
            boundary_viscosity: 0.0,
            viscosity_mode: ViscosityMode::Implicit,
            darcy_viscosity: 1e-3,
        }
    }
}

/// Porous skeleton material (a sponge).
#[derive(Clone, Debug, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct PorousMaterial {
    /// Undeformed porosity phi (pore volume fraction), dimensionless.
    pub porosity: f64,
    /// Dry bulk density per sampling volume, kg/m^3 (the solid's `density0`; (1-phi) rho_s^0).
    pub dry_density: f64,
    /// Young's modulus of the skeleton in Pa.
    pub youngs_modulus: f64,
    /// Poisson ratio, dimensionless.
    pub poisson_ratio: f64,
    /// Compressible skeleton: squeezing closes pores and expels water instead of bulging.
    pub compressible: bool,
    /// Intrinsic (Darcy) permeability in m^2; converted to the SPH drag coefficient with the
    /// resolution scaling of docs/physics.md §3.1. Zero disables drag.
    pub permeability: f64,
    /// Adhesion (capillary) strength alpha in N/m at `adhesion_reference_spacing`.
    pub adhesion: f64,
    /// Particle spacing at which `adhesion` is given, m; alpha is rescaled as alpha * d / d_ref.
    pub adhesion_reference_spacing: f64,
    /// Saturation fall-off a_f of adhesion, in [0, 1].
    pub adhesion_falloff: f64,
    /// Relative change of the shear modulus with saturation (negative softens).
    pub softening_shear: f64,
    /// Relative change of the volumetric stiffness with saturation (negative softens).
    pub softening_volume: f64,
    /// Volumetric swelling strain per unit saturation, dimensionless.
    pub bloating: f64,
    /// Kinematic viscosity damping relative skeleton motion, m^2/s (explicit, like the
    /// reference scenes' solid "standard" viscosity). Zero disables it.
    pub damping: f64,
    /// Hourglass (zero-energy mode) control strength alpha, relative to E (Ganzenmüller 2015).
    pub hourglass: f64,
}

impl Default for PorousMaterial {
    fn default() -> Self {
        PorousMaterial {
            porosity: 0.6,
            dry_density: 100.0,
            youngs_modulus: 250e3,
            poisson_ratio: 0.3,
            compressible: true,
            permeability: 3e-11,
            adhesion: 21.0,
            adhesion_reference_spacing: 0.005,
            adhesion_falloff: 0.5,
            softening_shear: 0.0,
            softening_volume: 0.0,
            bloating: 0.0,
            damping: 0.0,
            hourglass: 0.1,
        }
    }
}

/// An axis-aligned block of water, sampled on a lattice of spacing `2 r`.
#[derive(Clone, Debug, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FluidBlock {
    /// Lower corner in m.
    pub min: [f64; 3],
    /// Upper corner in m.
    pub max: [f64; 3],
    /// Initial velocity in m/s.
    #[serde(default)]
    pub velocity: [f64; 3],
}

/// An axis-aligned porous block (a sponge), optionally pre-saturated with pore water.
#[derive(Clone, Debug, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PorousBlock {
    /// Lower corner in m.
    pub min: [f64; 3],
    /// Upper corner in m.
    pub max: [f64; 3],
    /// Material of the skeleton.
    #[serde(default)]
    pub material: PorousMaterial,
    /// Fill the pores with water sampled so that fluid plus skeleton densities sum to rest.
    #[serde(default = "default_true")]
    pub saturated: bool,
    /// Pin every skeleton particle (a fixed porous medium, e.g. for permeameter tests).
    #[serde(default)]
    pub fixed: bool,
}

fn default_true() -> bool {
    true
}

/// Geometry of a rigid boundary body.
#[derive(Clone, Debug, Serialize, Deserialize)]
#[serde(rename_all = "snake_case", deny_unknown_fields)]
pub enum Shape {
    /// A solid box with these half extents (m); particles stay outside.
    Box {
        /// Half extents in m.
        half_extents: [f64; 3],
    },
    /// The inside of a closed box (walls, floor and lid) with these inner half extents (m).
    Container {
        /// Inner half extents in m.
        half_extents: [f64; 3],
    },
}

/// A rigid boundary body: static (walls, floor) or kinematic (gripper plates).
#[derive(Clone, Debug, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct BodyConfig {
    /// Name used to address the body (e.g. `"left_plate"`).
    pub name: String,
    /// Shape in the body frame.
    pub shape: Shape,
    /// Centre position in m.
    pub position: [f64; 3],
    /// Orientation as a rotation vector (axis * angle, rad).
    #[serde(default)]
    pub rotation: [f64; 3],
    /// Moves under caller control (set its velocity); static bodies never move.
    #[serde(default)]
    pub kinematic: bool,
}

/// The initial scene.
#[derive(Clone, Debug, Default, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct SceneConfig {
    /// Free water blocks.
    pub fluid_blocks: Vec<FluidBlock>,
    /// Porous objects.
    pub porous_blocks: Vec<PorousBlock>,
    /// Rigid boundary bodies.
    pub bodies: Vec<BodyConfig>,
    /// Random displacement of every pore-water particle, as a fraction of the spacing, so
    /// that trials with different seeds start from different particle states (0 = lattice).
    pub jitter: f64,
    /// Seed of that displacement (a counter-based hash: the same seed gives the same scene).
    pub seed: u64,
    /// Time (s) the pore water settles into the pinned skeleton before the run starts
    /// (`Simulation::soak`); 0 starts from the sampled lattice.
    pub soak_time: f64,
}

/// Pressure solver settings (relaxed Jacobi IISPH with porosity-aware volume factors).
#[derive(Clone, Debug, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct PressureConfig {
    /// Allowed mean compression per material, as a fraction (5e-4 = 0.05 %).
    pub max_error: f64,
    /// Minimum number of Jacobi iterations.
    pub min_iterations: u32,
    /// Maximum number of Jacobi iterations.
    pub max_iterations: u32,
    /// Jacobi relaxation factor.
    pub omega: f64,
    /// Start from the previous step's pressure.
    pub warm_start: bool,
    /// Fraction of the previous pressure the warm start uses (the reference code and
    /// SPlisHSPlasH's DFSPH use 0.5). Larger values save iterations in fast flows (dam break:
    /// 3.5 -> 2.2 at 1.0) but the stopping test counts compression only, so a solve that
    /// starts above the answer can stop over-pressured: resting water then does not settle
    /// (hydrostatic floor load 2.5 % off at 1.0; docs/benchmark-history.md, "Dam break: quiet
    /// rounds and per-round ratios; two solver changes that did not pay").
    pub warm_start_factor: f64,
    /// Pass the pressure impulse through the implicit operator of the non-pressure solve
    /// (drag, adhesion, viscosity, elasticity) within the step, so that pore water seeps at
    /// the Darcy speed instead of moving as free water for one step. `false` reproduces the
    /// reference code, which applies those terms only before the pressure.
    pub drag_coupled: bool,
    /// With `drag_coupled`: solve the pressure first, on the velocities with gravity alone,
    /// and put its impulse on the right-hand side of the implicit solve, so that a step
    /// solves the implicit system once instead of twice (the implicit solve, then the
    /// response to the pressure impulse). The same system at the end; the pressure sees the
    /// velocities before drag and elasticity act in this step rather than after (and before
    /// the explicit forces, fluid viscosity when explicit and skeleton damping), an operator
    /// split that converges with the time step (docs/engine.md, "One implicit solve per
    /// step"). Off by default.
    pub single_solve: bool,
}

impl Default for PressureConfig {
    fn default() -> Self {
        PressureConfig {
            max_error: 5e-4,
            min_iterations: 2,
            max_iterations: 100,
            omega: 0.5,
            warm_start: true,
            warm_start_factor: 0.5,
            drag_coupled: true,
            single_solve: false,
        }
    }
}

/// Implicit non-pressure solve (CG) settings.
#[derive(Clone, Debug, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct CgConfig {
    /// Relative residual tolerance of each implicit solve. The default is the loosest
    /// measured at which the validation cases stay within their bounds and the trials'
    /// observables keep their values at 1e-4 (docs/engine.md, "Implicit solve tolerance").
    pub tolerance: f64,
    /// Maximum number of CG iterations.
    pub max_iterations: u32,
    /// Preconditioner.
    pub preconditioner: Preconditioner,
    /// Start from the previous step's velocity change.
    pub warm_start: bool,
    /// Edge length of the two-level preconditioner's aggregates, in particle spacings.
    pub coarse_cell: f64,
    /// Steps that one coarse matrix of the two-level preconditioner serves before it is
    /// assembled again (1: every step). The additive two-level preconditioner stays
    /// symmetric positive definite with a matrix from an earlier step, so an older one costs
    /// iterations, never correctness; it is assembled anew sooner when a contact constrains
    /// a particle inside an aggregate.
    pub coarse_steps: u32,
}

impl Default for CgConfig {
    fn default() -> Self {
        CgConfig {
            tolerance: 3e-3,
            max_iterations: 100,
            preconditioner: Preconditioner::Auto,
            warm_start: true,
            coarse_cell: 4.0,
            coarse_steps: 10,
        }
    }
}

/// Full simulation configuration.
#[derive(Clone, Debug, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct SimConfig {
    /// Particle radius r in m; spacing d = 2r, kernel support H = 4r, volume V = d^3.
    pub particle_radius: f64,
    /// Fixed time step in s.
    pub dt: f64,
    /// Gravity in m/s^2.
    pub gravity: [f64; 3],
    /// Water.
    pub fluid: FluidConfig,
    /// Pressure solve.
    pub pressure: PressureConfig,
    /// Implicit non-pressure solve.
    pub cg: CgConfig,
    /// Divergence guard: a particle faster than this (m/s) stops the run with an error.
    pub max_velocity: f64,
    /// Re-sort fluid particles by grid cell every this many steps (0 = never), for locality.
    pub reorder_every: u32,
    /// Neighbour grid: cells of size `H / neighbour_reach`, searched `neighbour_reach` cells to
    /// each side (1, 2 or 3). The neighbour sets are the same for every value; their order, and
    /// so the last bits of every sum over them, is not. With the AVX2 scan, 1 (27 cells of
    /// size H) is the fastest for water-only scenes and 2 as fast as 1 for sponges
    /// (docs/benchmark-history.md, "Dam break: a four-wide neighbour scan"); the default 2
    /// keeps the bits of the runs made before the choice existed.
    pub neighbour_reach: u32,
    /// Reproduce the reference code's elasticity (trace term without lambda).
    pub elasticity_reference_trace: bool,
    /// Placement of the bodies' boundary particles.
    pub wall_layer: WallLayer,
    /// The initial scene.
    pub scene: SceneConfig,
}

impl Default for SimConfig {
    fn default() -> Self {
        SimConfig {
            particle_radius: 0.005,
            dt: 1e-3,
            gravity: [0.0, 0.0, -9.81],
            fluid: FluidConfig::default(),
            pressure: PressureConfig::default(),
            cg: CgConfig::default(),
            max_velocity: 50.0,
            reorder_every: 25,
            neighbour_reach: 2,
            elasticity_reference_trace: false,
            wall_layer: WallLayer::Sunk,
            scene: SceneConfig::default(),
        }
    }
}

impl PorousMaterial {
    /// Lame parameters (mu, lambda) in Pa.
    pub fn lame(&self) -> (f64, f64) {
        let e = self.youngs_modulus;
        let nu = self.poisson_ratio;
        (e / (2.0 * (1.0 + nu)), e * nu / ((1.0 + nu) * (1.0 - 2.0 * nu)))
    }
}

impl SimConfig {
    /// Parses a JSON document (unknown fields are rejected) and validates it.
    pub fn from_json(text: &str) -> Result<Self> {
        let value: serde_json::Value = serde_json::from_str(text).map_err(|e| {
            RmiError::config(json_path_hint(&e), "(malformed)", format!("valid JSON for SimConfig: {e}"))
        })?;
        let cfg: SimConfig = from_value_named(&value)?;
        cfg.validate()?;
        Ok(cfg)
    }

    /// Serialises to pretty JSON.
    pub fn to_json(&self) -> String {
        serde_json::to_string_pretty(self).expect("config serialises")
    }

    /// Particle spacing d = 2r in m.
    pub fn spacing(&self) -> f64 {
        2.0 * self.particle_radius
    }

    /// Kernel support H = 4r in m.
    pub fn support(&self) -> f64 {
        4.0 * self.particle_radius
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn defaults_validate() {
        SimConfig::default().validate().unwrap();
    }

    #[test]
    fn bad_porosity_names_field_and_range() {
        let mut c = SimConfig::default();
        c.scene.porous_blocks.push(PorousBlock {
            min: [0.0; 3],
            max: [0.1; 3],
            material: PorousMaterial { porosity: 1.5, ..Default::default() },
            saturated: true,
            fixed: false,
        });
        let e = c.validate().unwrap_err().to_string();
        assert!(e.contains("scene.porous_blocks[0].material.porosity"), "{e}");
        assert!(e.contains("1.5") && e.contains("(0, 1)"), "{e}");
    }

    #[test]
    fn unknown_field_is_rejected() {
        let e = SimConfig::from_json(r#"{"particle_radus": 0.01}"#).unwrap_err().to_string();
        assert!(e.contains("particle_radus"), "{e}");
    }

    #[test]
    fn neighbour_reach_outside_one_to_three_is_rejected() {
        for bad in [0, 4] {
            let c = SimConfig { neighbour_reach: bad, ..Default::default() };
            let e = c.validate().unwrap_err().to_string();
            assert!(e.contains("neighbour_reach") && e.contains("[1, 3]") && e.contains(&bad.to_string()), "{e}");
        }
        for ok in 1..=3 {
            SimConfig { neighbour_reach: ok, ..Default::default() }.validate().unwrap();
        }
    }

    #[test]
    fn single_solve_without_drag_coupling_is_rejected() {
        let mut c = SimConfig::default();
        c.pressure.single_solve = true;
        c.validate().unwrap();
        c.pressure.drag_coupled = false;
        let e = c.validate().unwrap_err().to_string();
        assert!(e.contains("pressure.single_solve") && e.contains("drag_coupled"), "{e}");
    }

    #[test]
    fn nan_dt_rejected() {
        let c = SimConfig { dt: f64::NAN, ..Default::default() };
        assert!(c.validate().unwrap_err().to_string().contains("`dt`"));
    }
}
