//! Validation of a [`SimConfig`]: every field checked against its accepted range, the
//! error naming the field, its value and the range with its unit.

use super::{memory_limit, PorousMaterial, Shape, SimConfig};
use crate::error::{Result, RmiError};

/// Accepted densities (kg/m^3) of the water and of a skeleton's dry material; a particle's
/// mass is its density times the spacing cubed, so these bound the masses of a snapshot too.
pub const DENSITY_RANGE: [f64; 2] = [1.0, 1e5];

/// Largest seed any config accepts (2^63 - 1). The engine would take any u64, but run files
/// and their indexes store seeds as signed 64-bit integers, so one range everywhere keeps
/// every seed the engine accepts storable.
pub const SEED_MAX: u64 = i64::MAX as u64;

/// The accepted seeds, as errors state them.
pub fn seed_range() -> String {
    format!("an integer in [0, {SEED_MAX}]")
}

/// `seed <= SEED_MAX`, else an [`RmiError::InvalidConfig`] naming `field` and the range.
pub fn check_seed(field: &str, seed: u64) -> Result<()> {
    if seed <= SEED_MAX {
        Ok(())
    } else {
        Err(RmiError::config(field, seed, seed_range()))
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
        range(&format!("{p}.dry_density"), self.dry_density, DENSITY_RANGE[0], DENSITY_RANGE[1], "kg/m^3")?;
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
}

impl SimConfig {
    /// Checks every field; the error names the first offending field, its value and range.
    pub fn validate(&self) -> Result<()> {
        range("particle_radius", self.particle_radius, 1e-4, 0.1, "m")?;
        range("dt", self.dt, 1e-6, 0.01, "s")?;
        vec3("gravity", &self.gravity, 1e3, "m/s^2")?;
        let f = &self.fluid;
        range("fluid.density", f.density, DENSITY_RANGE[0], DENSITY_RANGE[1], "kg/m^3")?;
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
        if p.single_solve && !p.drag_coupled {
            return Err(RmiError::config(
                "pressure.single_solve",
                p.single_solve,
                "false while pressure.drag_coupled is false (the single solve is a drag-coupled scheme)",
            ));
        }
        range("cg.tolerance", self.cg.tolerance, 1e-14, 0.1, "(relative residual)")?;
        if self.cg.max_iterations == 0 || self.cg.max_iterations > 10_000 {
            return Err(RmiError::config("cg.max_iterations", self.cg.max_iterations, "an integer in [1, 10000]"));
        }
        range("cg.coarse_cell", self.cg.coarse_cell, 1.0, 64.0, "particle spacings")?;
        if self.cg.coarse_steps == 0 || self.cg.coarse_steps > 10_000 {
            return Err(RmiError::config("cg.coarse_steps", self.cg.coarse_steps, "an integer in [1, 10000] (steps)"));
        }
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
        check_seed("scene.seed", self.scene.seed)?;
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
}
