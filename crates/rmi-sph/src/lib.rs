//! # rmi-sph
//!
//! Implicit incompressible porous flow with SPH (Böttcher et al. 2025) for a robot that
//! grasps, lifts and squeezes a water-filled sponge. Pure Rust, parallel with rayon, f64.
//! All quantities are SI: metres, seconds, kilograms, newtons, pascals.
//!
//! Features:
//! - fluid, porous-skeleton and boundary particle sets; cubic spline kernel, `H = 4 r`,
//!   `V = (2 r)^3`; neighbour lists with cached `W` and `grad W`, built once per step;
//! - porosity-aware densities, DFSPH factor, local porosity, saturation (Shepard-corrected);
//! - one strongly coupled implicit CG over all velocities (viscosity, corotated elasticity,
//!   drag from a permeability, capillary adhesion), preconditioned by block Jacobi plus a
//!   coarse level on aggregates of particles (two-level deflation, [`coarse`]);
//! - porosity-aware relaxed-Jacobi pressure solve with per-material tolerances;
//! - compressible skeleton, static and kinematic rigid bodies with force read-back;
//! - validated configs, divergence guard, bit-identical snapshots, thread-count-independent
//!   determinism (each [`Simulation`] owns its rayon pool);
//! - hot loops compiled twice, for baseline x86-64 and for AVX2 + FMA, chosen at run time
//!   with the same bits either way ([`cpu`]).
//!
//! ```no_run
//! use rmi_sph::{presets, Simulation};
//! let mut sim = Simulation::new(presets::dam_break(0.02), Some(2)).unwrap();
//! sim.run(10).unwrap();
//! println!("t = {} s, pressure iterations {}", sim.time(), sim.stats().pressure.iterations);
//! ```

// Solver passes index many parallel per-particle arrays by particle number; iterator chains
// over one of them would hide that the index is the particle identity.
#![allow(clippy::needless_range_loop)]

pub mod boundary;
pub mod coarse;
pub mod config;
pub mod contact;
pub mod controller;
pub mod cpu;
pub mod ctx;
pub mod density;
pub mod elasticity;
pub mod error;
pub mod friction;
pub mod gate;
pub mod grid;
pub mod gripper;
pub mod kernel;
pub mod neighbours;
pub mod nonpressure;
pub mod observe;
pub mod pairsum;
pub mod par;
pub mod particles;
pub mod presets;
pub mod pressure;
pub mod retention;
pub mod scene;
pub mod simulation;
pub mod skyline;
pub mod snapshot;
pub mod trial;

pub use config::SimConfig;
pub use error::{Result, RmiError};
pub use simulation::Simulation;
pub use trial::{run_trial, Trial, TrialConfig};
