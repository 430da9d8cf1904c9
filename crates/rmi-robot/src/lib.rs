//! # rmi-robot
//!
//! The grasp-lift-squeeze task on the [`rmi_sph`] engine: a parallel gripper's two pads
//! squeeze a water-filled sponge, lift it and squeeze it again, while the water it holds and
//! expels is observed every step. All quantities are SI.
//!
//! - [`config`]: the trial's configuration ([`TrialConfig`]), built from JSON or from the
//!   paper's sponge parameters and checked field by field;
//! - [`gripper`]: the two pads (kinematic boxes), their load read-back and force limit;
//! - [`controller`]: hybrid velocity/force regulation and the trial's phase sequence;
//! - [`gate`]: the lift stability gate;
//! - [`perturbation`]: seeded force targets from the lift on, for identifiable data;
//! - [`observe`]: the interaction state `y_t` and the extras recorded beside it;
//! - [`trial`]: the simulation, pads, contact memory, controller and gate stepped together
//!   ([`Trial`]), and the scripted trial run to the end ([`run_trial`]);
//! - [`squeeze_group`]: trials that differ only in their squeeze force, run from one shared
//!   prefix ([`run_squeeze_group`]).
//!
//! Friction between pads and sponge (Coulomb with contact memory) is the engine's
//! [`rmi_sph::contact`]; a trial keeps its [`ContactMemory`](rmi_sph::contact::ContactMemory).

#![warn(missing_docs)]

pub mod config;
pub mod controller;
pub mod gate;
pub mod gripper;
pub mod observe;
pub mod perturbation;
pub mod squeeze_group;
pub mod trial;

pub use config::TrialConfig;
pub use squeeze_group::run_squeeze_group;
pub use trial::{run_trial, Trial};
