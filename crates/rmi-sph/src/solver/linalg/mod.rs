//! Linear algebra of the implicit solves: preconditioned CG with constraint filters
//! (`cg.rs`), the additive two-level preconditioner's coarse space, whose correction
//! `Z E^-1 Z^T r` (with `E = Z^T A Z`) joins the block-Jacobi step `M^-1 r` (`coarse.rs`),
//! and the envelope Cholesky factorisation of its coarse matrix (`skyline.rs`).

mod cg;
pub(crate) mod coarse;
mod skyline;

pub use cg::CgStats;
pub(crate) use cg::{pcg, CgWork, System};
