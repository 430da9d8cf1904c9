//! Who interacts with whom: the cubic spline kernel (support `H = 4 r`), the uniform grid,
//! the per-step neighbour lists with cached kernel values, and the position-free water-pair
//! sums of the pressure passes.

pub(crate) mod grid;
pub(crate) mod kernel;
pub(crate) mod lists;
pub(crate) mod pairsum;

pub use grid::{bounds, Grid, SOA_PAD};
pub use kernel::CubicKernel;
pub use lists::{Nb, NeighbourLists};
