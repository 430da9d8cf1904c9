//! The solver passes of a step: porosity-aware densities, the DFSPH factor, local porosity
//! and saturation; the skeleton's corotated elasticity; the porosity-aware pressure solve;
//! the strongly coupled implicit non-pressure solve (viscosity, drag, adhesion, elasticity,
//! with the skeleton's contacts as constraints) and the linear algebra under it
//! (preconditioned CG, the two-level coarse space, a skyline factorisation).
//!
//! Every pass reads the step's borrowed state through one context and writes its own
//! fields; the order of the passes is [`Simulation::step`](crate::Simulation::step)'s.

pub(crate) mod ctx;
pub(crate) mod density;
pub(crate) mod elasticity;
pub(crate) mod implicit;
pub(crate) mod linalg;
pub(crate) mod pressure;

pub use density::{DensityFields, MIN_LOCAL_POROSITY};
pub use implicit::{CgStats, TWO_LEVEL_MIN_SOLIDS};
pub use pressure::PressureStats;
