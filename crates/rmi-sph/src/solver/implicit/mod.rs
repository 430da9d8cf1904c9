//! Strongly coupled implicit non-pressure solve (docs/physics.md §2.4).
//!
//! One matrix-free preconditioned CG over all dynamic velocities solves
//! `m v* - dt F_lin(v*) = m v + dt F_exp`, where `F_lin` holds fluid viscosity (Weiler et al.
//! 2018), Darcy-like drag, the velocity part of adhesion and the linearised corotated
//! elasticity, and `F_exp` holds elasticity at x^n, the position part of adhesion, buoyancy
//! and the boundary-velocity part of boundary viscosity.
//!
//! - `operator.rs`: the step's system `A y = m y - dt F_lin(y)`, its pair-coefficient cache,
//!   its rows, block-Jacobi preconditioner and coarse level;
//! - one file per physical term of the operator: `viscosity.rs`, `drag.rs`, `adhesion.rs`,
//!   `elasticity.rs` (the linearised stress), `hourglass.rs` (hourglass springs);
//! - `constraints.rs`: the skeleton-body contacts as velocity constraints (filtered PCG);
//! - `solve.rs`: the implicit solve and the implicit response to a velocity increment;
//! - `explicit.rs`: the forces outside the solve (explicit viscosity, skeleton damping) and
//!   force diagnostics (coupling, buoyancy).
//!
//! The CG itself is in [`crate::solver::linalg`].

mod adhesion;
mod constraints;
mod drag;
mod elasticity;
mod explicit;
mod hourglass;
mod operator;
mod solve;
mod viscosity;

pub use crate::solver::linalg::CgStats;
pub use constraints::VelocityConstraint;
pub use operator::{NonPressureSettings, TWO_LEVEL_MIN_SOLIDS};

pub(crate) use crate::solver::linalg::CgWork;
pub(crate) use explicit::{buoyancy_forces, coupling_forces, explicit_accelerations};
pub(crate) use hourglass::hourglass_constants;
pub(crate) use operator::{needed, Op, OpBuffers};
pub(crate) use solve::{pressure_response, solve};
