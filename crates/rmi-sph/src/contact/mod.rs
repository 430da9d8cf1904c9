//! Particle-body contact: detection, the skeleton's contacts as velocity constraints of the
//! implicit solves, and Coulomb friction with contact memory (paper Eq. 4, supplement S3-S8).
//!
//! - detection and constraints (`detect.rs`, [`Contact`]): a
//!   compressible skeleton barely feels Akinci boundary pressure, so its contacts with the
//!   bodies' analytic shapes hold their normal velocity inside the implicit solves; water gets
//!   a projection only as a safety net against deep penetration;
//! - the law ([`Friction`], [`FrictionParams`], [`coulomb`]): every frictional contact first
//!   holds its tangential velocity, the body's plus `beta e / dt` toward its anchor, as a
//!   constraint of the step's solves, so that the drag couples its pore water to it;
//! - the slip release (`slip.rs`): a held stick whose force left the static cone `mu_st N`
//!   slides with `mu_kin N` along it, passed through the same operator: those the implicit
//!   solve's load already pushes out within the pressure response, those the response's load
//!   pushes out in a correction of their own;
//! - the memory ([`ContactMemory`]): each contacting skeleton particle keeps an anchor, its
//!   contact point in the body frame, while it sticks, and drops it when it slips or the
//!   contact ends;
//! - the step hook ([`ContactStage`]): what a caller of
//!   [`Simulation::step_with`](crate::Simulation::step_with) may read and change after the
//!   solves, before positions are integrated.
//!
//! Memoryless damping would let the integration error of a held sponge accumulate into a
//! slow slide. Applied after the solve to the skeleton particle alone
//! ([`FrictionParams::coupled`] false), friction stops a held particle but not its water,
//! which then runs along the pads at centimetres per second instead of seeping at the Darcy
//! speed.

mod detect;
mod hook;
mod law;
mod memory;
mod slip;

pub use detect::{Contact, HeldFriction};
pub use hook::ContactStage;
pub use law::{coulomb, Friction, FrictionForce, FrictionParams, Stick};
pub use memory::{Anchor, ContactFriction, ContactMemory};

pub(crate) use detect::{detect, merge, resolve};
pub(crate) use slip::{release_slipping_sticks, slide_sticks};
