//! Linear algebra of the implicit solves: preconditioned CG with constraint filters
//! (`cg.rs`), the two-level (deflation) coarse space (`coarse.rs`) and the envelope
//! Cholesky factorisation of its coarse matrix (`skyline.rs`).

mod cg;
pub(crate) mod coarse;
mod skyline;

pub use cg::CgStats;
pub(crate) use cg::{pcg, CgWork, System};
