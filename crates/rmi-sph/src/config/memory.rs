//! How much memory a scene may take: the bytes assumed per particle and the system's limit.

use super::{Shape, SimConfig};
use crate::error::{Result, RmiError};

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

impl SimConfig {
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
