//! What the solver acts on: the dynamic particles (water first, then the porous skeleton)
//! and the skeleton's rest data, the rigid boundary bodies (static walls, kinematic boxes),
//! the scene sampled from a [`SimConfig`](crate::SimConfig), and the part of the water a
//! sponge retains.

pub(crate) mod boundary;
pub(crate) mod particles;
pub(crate) mod retention;
pub(crate) mod scene;

pub use boundary::{signed_distance, wall_depth, Body, BodyState, Boundary};
pub use particles::{drag_beta, Particles, PorousObject, SolidRest, SolidState, DRAG_LATTICE_C, FLUID, LAPLACE_D};
pub use retention::cube_inside;
