//! The step hook's view of the state.

use super::Contact;
use crate::world::boundary::{BodyState, Boundary};
use crate::world::particles::Particles;
use nalgebra::Vector3;

/// What the hook of [`Simulation::step_with`](crate::Simulation::step_with) may read and
/// change: the velocities after the solves and the contact projection, before positions are
/// integrated, and the bodies' loads of the step. An impulse applied to a particle must add its
/// reaction to `body_forces` so that the bodies' force read-back stays balanced.
pub struct ContactStage<'a> {
    /// Dynamic particles (positions at the start of the step).
    pub particles: &'a Particles,
    /// Velocities to be integrated (m/s); modify to apply impulses.
    pub v: &'a mut [Vector3<f64>],
    /// Contacts found this step.
    pub contacts: &'a [Contact],
    /// Bodies (poses at the start of the step).
    pub boundary: &'a Boundary,
    /// Force and torque on each body this step (N, N m); add reactions of applied impulses.
    pub body_forces: &'a mut [(Vector3<f64>, Vector3<f64>)],
    /// Time step (s).
    pub dt: f64,
    /// Pinned skeleton particles (by solid index).
    pub rest_fixed: &'a [bool],
}

impl ContactStage<'_> {
    /// The state of body `i`.
    pub fn body(&self, i: usize) -> &BodyState {
        &self.boundary.bodies[i].state
    }
}
