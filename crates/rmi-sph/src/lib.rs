//! # rmi-sph
//!
//! Implicit incompressible porous flow with SPH (Böttcher et al. 2025): water, porous
//! elastic skeletons (sponges) and rigid bodies. Pure Rust, parallel with rayon, f64.
//! All quantities are SI: metres, seconds, kilograms, newtons, pascals. The robot task built
//! on it (gripper, controller, trials) is the `rmi-robot` crate.
//!
//! Features:
//! - fluid, porous-skeleton and boundary particle sets; cubic spline kernel, `H = 4 r`,
//!   `V = (2 r)^3`; neighbour lists with cached `W` and `grad W`, built once per step;
//! - porosity-aware densities, DFSPH factor, local porosity, saturation (Shepard-corrected);
//! - one strongly coupled implicit CG over all velocities (viscosity, corotated elasticity,
//!   drag from a permeability, capillary adhesion), preconditioned by block Jacobi plus an
//!   additive coarse correction on aggregates of particles (two-level,
//!   `z = M^-1 r + Z E^-1 Z^T r` with `E = Z^T A Z`);
//! - porosity-aware relaxed-Jacobi pressure solve with per-material tolerances;
//! - compressible skeleton, static and kinematic rigid bodies with force read-back;
//!   skeleton-body contacts as constraints of the implicit solves, Coulomb friction with
//!   contact memory;
//! - validated configs, divergence guard, bit-identical snapshots, thread-count-independent
//!   determinism (each [`Simulation`] owns its rayon pool);
//! - hot loops compiled twice, for baseline x86-64 and for AVX2 + FMA, chosen at run time
//!   with the same bits either way (the `rmi-par` crate).
//!
//! Modules, by concept:
//! - [`simulation`]: the state, the step by stage, persistence and queries;
//! - [`world`]: particles, rigid bodies, scene building, retention;
//! - [`neighbourhood`]: kernel, grid, neighbour lists;
//! - [`solver`]: densities, pressure, elasticity, the implicit solve and its linear algebra;
//! - [`contact`]: contact detection and constraints, friction with contact memory, the step
//!   hook;
//! - [`config`] and [`presets`]: what defines a simulation, and ready-made scenes.
//!
//! ```no_run
//! use rmi_sph::{presets, Simulation};
//! let mut sim = Simulation::new(presets::dam_break(0.02), Some(2)).unwrap();
//! sim.run(10).unwrap();
//! println!("t = {} s, pressure iterations {}", sim.time(), sim.stats().pressure.iterations);
//! ```

#![warn(missing_docs)]
// Solver passes index many parallel per-particle arrays by particle number; iterator chains
// over one of them would hide that the index is the particle identity.
#![allow(clippy::needless_range_loop)]

pub mod config;
pub mod contact;
mod error;
pub mod neighbourhood;
pub mod presets;
pub mod simulation;
pub mod solver;
pub mod world;

pub use config::SimConfig;
pub use error::{Result, RmiError};
pub use simulation::Simulation;
