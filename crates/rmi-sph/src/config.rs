//! Simulation configuration: serde structs with units, defaults and range validation.
//!
//! All quantities are SI (m, s, kg, N, Pa). One JSON document reproduces a simulation.
//! [`SimConfig::validate`] checks every field and names the first offending one.

use crate::error::{Result, RmiError};
use serde::{Deserialize, Serialize};

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
    /// (hydrostatic floor load 2.5 % off at 1.0; docs/benchmark-history.md).
    pub warm_start_factor: f64,
    /// Pass the pressure impulse through the implicit operator of the non-pressure solve
    /// (drag, adhesion, viscosity, elasticity) within the step, so that pore water seeps at
    /// the Darcy speed instead of moving as free water for one step. `false` reproduces the
    /// reference code, which applies those terms only before the pressure.
    pub drag_coupled: bool,
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
        }
    }
}

/// Implicit non-pressure solve (CG) settings.
#[derive(Clone, Debug, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct CgConfig {
    /// Relative residual tolerance.
    pub tolerance: f64,
    /// Maximum number of CG iterations.
    pub max_iterations: u32,
    /// Preconditioner.
    pub preconditioner: Preconditioner,
    /// Start from the previous step's velocity change.
    pub warm_start: bool,
    /// Edge length of the two-level preconditioner's aggregates, in particle spacings.
    pub coarse_cell: f64,
}

impl Default for CgConfig {
    fn default() -> Self {
        CgConfig {
            tolerance: 1e-4,
            max_iterations: 100,
            preconditioner: Preconditioner::Auto,
            warm_start: true,
            coarse_cell: 4.0,
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
    /// size H) is the fastest for water-only scenes (dam-break list build 13 % faster than
    /// with 2) and 2 as fast as 1 for sponges; the default 2 keeps the bits of the runs made
    /// before the choice existed.
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

/// Range check helper: `lo <= v <= hi`, finite.
fn range(field: &str, v: f64, lo: f64, hi: f64, unit: &str) -> Result<()> {
    if v.is_finite() && v >= lo && v <= hi {
        Ok(())
    } else {
        Err(RmiError::config(field, v, format!("a finite value in [{lo}, {hi}] {unit}")))
    }
}

/// `lo <= v <= hi` and finite, else an [`RmiError::InvalidConfig`] naming `field`, the range
/// and `unit`; for the configs of crates built on the engine.
pub fn check_range(field: &str, v: f64, lo: f64, hi: f64, unit: &str) -> Result<()> {
    range(field, v, lo, hi, unit)
}

/// Open-interval check helper: `lo < v < hi`, finite.
fn open(field: &str, v: f64, lo: f64, hi: f64, unit: &str) -> Result<()> {
    if v.is_finite() && v > lo && v < hi {
        Ok(())
    } else {
        Err(RmiError::config(field, v, format!("a finite value in ({lo}, {hi}) {unit}")))
    }
}

fn vec3(field: &str, v: &[f64; 3], lim: f64, unit: &str) -> Result<()> {
    for (k, c) in v.iter().enumerate() {
        range(&format!("{field}[{k}]"), *c, -lim, lim, unit)?;
    }
    Ok(())
}

fn aabb(field: &str, min: &[f64; 3], max: &[f64; 3], d: f64) -> Result<()> {
    vec3(&format!("{field}.min"), min, 1e3, "m")?;
    vec3(&format!("{field}.max"), max, 1e3, "m")?;
    for k in 0..3 {
        if max[k] - min[k] < d {
            return Err(RmiError::config(
                format!("{field}.max[{k}]"),
                max[k],
                format!("at least min[{k}] + particle spacing = {} m", min[k] + d),
            ));
        }
    }
    Ok(())
}

impl PorousMaterial {
    /// Validates every field; `p` is the dotted path used in error messages.
    pub fn validate(&self, p: &str) -> Result<()> {
        open(&format!("{p}.porosity"), self.porosity, 0.0, 1.0, "(dimensionless)")?;
        range(&format!("{p}.dry_density"), self.dry_density, 1.0, 1e5, "kg/m^3")?;
        range(&format!("{p}.youngs_modulus"), self.youngs_modulus, 0.0, 1e10, "Pa")?;
        range(&format!("{p}.poisson_ratio"), self.poisson_ratio, 0.0, 0.49, "(dimensionless)")?;
        range(&format!("{p}.permeability"), self.permeability, 0.0, 1e-3, "m^2")?;
        range(&format!("{p}.adhesion"), self.adhesion, 0.0, 1e5, "N/m")?;
        range(&format!("{p}.adhesion_reference_spacing"), self.adhesion_reference_spacing, 1e-5, 1.0, "m")?;
        range(&format!("{p}.adhesion_falloff"), self.adhesion_falloff, 0.0, 1.0, "(dimensionless)")?;
        range(&format!("{p}.softening_shear"), self.softening_shear, -1.0, 10.0, "(dimensionless)")?;
        range(&format!("{p}.softening_volume"), self.softening_volume, -1.0, 10.0, "(dimensionless)")?;
        range(&format!("{p}.bloating"), self.bloating, 0.0, 1.0, "(dimensionless)")?;
        range(&format!("{p}.damping"), self.damping, 0.0, 10.0, "m^2/s")?;
        range(&format!("{p}.hourglass"), self.hourglass, 0.0, 10.0, "(dimensionless)")?;
        Ok(())
    }

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

    /// Checks every field; the error names the first offending field, its value and range.
    pub fn validate(&self) -> Result<()> {
        range("particle_radius", self.particle_radius, 1e-4, 0.1, "m")?;
        range("dt", self.dt, 1e-6, 0.01, "s")?;
        vec3("gravity", &self.gravity, 1e3, "m/s^2")?;
        let f = &self.fluid;
        range("fluid.density", f.density, 1.0, 1e5, "kg/m^3")?;
        range("fluid.viscosity", f.viscosity, 0.0, 100.0, "m^2/s")?;
        range("fluid.boundary_viscosity", f.boundary_viscosity, 0.0, 100.0, "m^2/s")?;
        range("fluid.darcy_viscosity", f.darcy_viscosity, 1e-6, 10.0, "Pa s")?;
        let p = &self.pressure;
        range("pressure.max_error", p.max_error, 1e-7, 0.1, "(fraction)")?;
        range("pressure.omega", p.omega, 0.05, 1.0, "(dimensionless)")?;
        range("pressure.warm_start_factor", p.warm_start_factor, 0.0, 1.0, "(dimensionless)")?;
        if p.max_iterations == 0 || p.max_iterations > 10_000 {
            return Err(RmiError::config("pressure.max_iterations", p.max_iterations, "an integer in [1, 10000]"));
        }
        if p.min_iterations > p.max_iterations {
            return Err(RmiError::config(
                "pressure.min_iterations",
                p.min_iterations,
                format!("an integer in [0, pressure.max_iterations = {}]", p.max_iterations),
            ));
        }
        range("cg.tolerance", self.cg.tolerance, 1e-14, 0.1, "(relative residual)")?;
        if self.cg.max_iterations == 0 || self.cg.max_iterations > 10_000 {
            return Err(RmiError::config("cg.max_iterations", self.cg.max_iterations, "an integer in [1, 10000]"));
        }
        range("cg.coarse_cell", self.cg.coarse_cell, 1.0, 64.0, "particle spacings")?;
        range("max_velocity", self.max_velocity, 1e-3, 1e4, "m/s")?;
        if !(1..=3).contains(&self.neighbour_reach) {
            return Err(RmiError::config("neighbour_reach", self.neighbour_reach, "an integer in [1, 3] (cells)"));
        }
        let d = self.spacing();
        for (i, b) in self.scene.fluid_blocks.iter().enumerate() {
            let p = format!("scene.fluid_blocks[{i}]");
            aabb(&p, &b.min, &b.max, d)?;
            vec3(&format!("{p}.velocity"), &b.velocity, 1e2, "m/s")?;
        }
        for (i, b) in self.scene.porous_blocks.iter().enumerate() {
            let p = format!("scene.porous_blocks[{i}]");
            aabb(&p, &b.min, &b.max, d)?;
            b.material.validate(&format!("{p}.material"))?;
        }
        range("scene.jitter", self.scene.jitter, 0.0, 0.25, "(fraction of the spacing)")?;
        range("scene.soak_time", self.scene.soak_time, 0.0, 10.0, "s")?;
        let mut names = std::collections::HashSet::new();
        for (i, b) in self.scene.bodies.iter().enumerate() {
            let p = format!("scene.bodies[{i}]");
            if b.name.is_empty() || !names.insert(b.name.clone()) {
                return Err(RmiError::config(
                    format!("{p}.name"),
                    format!("{:?}", b.name),
                    "a non-empty name unique among bodies",
                ));
            }
            vec3(&format!("{p}.position"), &b.position, 1e3, "m")?;
            vec3(&format!("{p}.rotation"), &b.rotation, 10.0, "rad")?;
            let he = match &b.shape {
                Shape::Box { half_extents } | Shape::Container { half_extents } => half_extents,
            };
            for (k, h) in he.iter().enumerate() {
                range(&format!("{p}.shape.half_extents[{k}]"), *h, 0.5 * self.particle_radius, 1e3, "m")?;
            }
        }
        let n = self.estimated_particles();
        if n > 2e7 {
            return Err(RmiError::config(
                "particle_radius",
                self.particle_radius,
                format!("a radius giving at most 2e7 particles (this scene would have about {n:.3e})"),
            ));
        }
        self.check_memory(memory_limit())
    }

    /// Refuses a scene whose [`SimConfig::estimated_bytes`] exceed `limit` (bytes), naming the
    /// particle radius and the scene, the estimate and the limit.
    pub fn check_memory(&self, limit: f64) -> Result<()> {
        let need = self.estimated_bytes();
        if need <= limit {
            return Ok(());
        }
        let (f, s, b) = self.estimated_counts();
        Err(RmiError::config(
            "particle_radius",
            self.particle_radius,
            format!(
                "a radius (or smaller scene.fluid_blocks, scene.porous_blocks, scene.bodies) whose particles fit \
                 in memory: about {f:.3e} fluid, {s:.3e} porous and {b:.3e} boundary particles need about \
                 {:.3} GB, more than the {:.3} GB available",
                need / 1e9,
                limit / 1e9
            ),
        ))
    }

    /// Rough number of fluid and solid particles the scene will create.
    pub fn estimated_particles(&self) -> f64 {
        let (f, s, _) = self.estimated_counts();
        f + s
    }

    /// Rough numbers of fluid, porous (skeleton) and boundary particles the scene will create
    /// (pore water counted as fluid; overestimates rather than under).
    pub fn estimated_counts(&self) -> (f64, f64, f64) {
        let d = self.spacing();
        let d3 = d.powi(3);
        let vol = |a: &[f64; 3], b: &[f64; 3]| (b[0] - a[0]) * (b[1] - a[1]) * (b[2] - a[2]);
        let f: f64 = self.scene.fluid_blocks.iter().map(|b| vol(&b.min, &b.max)).sum::<f64>() / d3;
        let solid: f64 = self.scene.porous_blocks.iter().map(|b| vol(&b.min, &b.max)).sum::<f64>() / d3;
        let pore: f64 =
            self.scene.porous_blocks.iter().map(|b| vol(&b.min, &b.max) * b.material.porosity).sum::<f64>() / d3;
        // One layer on each body's box surface, as `world::boundary` samples it (one spacing
        // of margin for the sunk layer's placement).
        let bnd: f64 = self
            .scene
            .bodies
            .iter()
            .map(|b| {
                let he = match &b.shape {
                    Shape::Box { half_extents } | Shape::Container { half_extents } => half_extents,
                };
                let n: Vec<f64> = he.iter().map(|h| (2.0 * h / d).round().max(1.0) + 2.0).collect();
                let inner: f64 = n.iter().map(|k| (k - 2.0).max(0.0)).product();
                n.iter().product::<f64>() - inner
            })
            .sum();
        (f + pore, solid, bnd)
    }

    /// Rough memory a simulation of this scene holds (bytes): each estimated particle times
    /// [`FLUID_PARTICLE_BYTES`], [`POROUS_PARTICLE_BYTES`] or [`BOUNDARY_PARTICLE_BYTES`].
    pub fn estimated_bytes(&self) -> f64 {
        let (f, s, b) = self.estimated_counts();
        f * FLUID_PARTICLE_BYTES + s * POROUS_PARTICLE_BYTES + b * BOUNDARY_PARTICLE_BYTES
    }
}

/// Memory per fluid particle (bytes) that [`SimConfig::estimated_bytes`] assumes: particle
/// data, neighbour lists and solver work arrays (`Simulation::memory_bytes` counts 600 to
/// 1,300 in water scenes; `tests/reliability.rs` checks the bound), with a margin for the
/// solvers' temporaries and the allocator.
pub const FLUID_PARTICLE_BYTES: f64 = 3000.0;

/// Memory per porous skeleton particle (bytes) that [`SimConfig::estimated_bytes`] assumes:
/// its rest neighbour pairs, rotations and elastic work arrays on top of a fluid particle's
/// (`Simulation::memory_bytes` counts about 3,500; checked in `tests/reliability.rs`).
pub const POROUS_PARTICLE_BYTES: f64 = 12_000.0;

/// Memory per boundary particle (bytes) that [`SimConfig::estimated_bytes`] assumes.
pub const BOUNDARY_PARTICLE_BYTES: f64 = 300.0;

/// Memory limit of [`SimConfig::validate`] where the system does not report its available
/// memory (bytes).
pub const FALLBACK_MEMORY_LIMIT: f64 = 8e9;

/// Memory a new simulation may use (bytes): the system's available memory (`MemAvailable`
/// of `/proc/meminfo` on Linux), else [`FALLBACK_MEMORY_LIMIT`].
pub fn memory_limit() -> f64 {
    std::fs::read_to_string("/proc/meminfo")
        .ok()
        .and_then(|text| {
            let line = text.lines().find(|l| l.starts_with("MemAvailable:"))?;
            let kib: f64 = line.split_whitespace().nth(1)?.parse().ok()?;
            Some(kib * 1024.0)
        })
        .unwrap_or(FALLBACK_MEMORY_LIMIT)
}

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

fn json_path_hint(e: &serde_json::Error) -> String {
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
    fn nan_dt_rejected() {
        let c = SimConfig { dt: f64::NAN, ..Default::default() };
        assert!(c.validate().unwrap_err().to_string().contains("`dt`"));
    }
}
