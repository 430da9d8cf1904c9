//! The end of a step: the contacts and their loads on the bodies, the divergence guard with
//! what a diverged step puts back, and the commit (contact loads, advection, bodies, clock).

use crate::contact::{self, Contact};
use crate::error::{Result, RmiError};
use crate::simulation::Simulation;
use crate::solver::linalg::coarse::TwoLevel;
use crate::solver::pressure::BodyLoad;
use nalgebra::{UnitQuaternion, Vector3};
use rayon::prelude::*;
use std::sync::Arc;

/// Solver memory and fields of the last good step, restored when a step diverges.
pub(super) struct Undo {
    kappa_dt2: Vec<f64>,
    dv_prev: Vec<Vector3<f64>>,
    response_prev: Vec<Vector3<f64>>,
    vstar_prev: Vec<Vector3<f64>>,
    rotation: Vec<UnitQuaternion<f64>>,
    kappa: Vec<f64>,
    coarse: Option<Arc<TwoLevel>>,
}

impl Undo {
    /// What `sim`'s step is about to overwrite.
    pub(super) fn of(sim: &Simulation) -> Self {
        Undo {
            kappa_dt2: sim.kappa_dt2.clone(),
            dv_prev: sim.dv_prev.clone(),
            response_prev: sim.response_prev.clone(),
            vstar_prev: sim.vstar_prev.clone(),
            rotation: sim.solid.rotation.clone(),
            kappa: sim.kappa.clone(),
            coarse: sim.op_buffers.coarse.clone(),
        }
    }
}

impl Simulation {
    /// The constraint contacts merged with those of the safety projection of `v` (deep fluid
    /// penetration, contacts the pressure solve pushed in).
    pub(super) fn project_contacts(&self, v: &mut [Vector3<f64>], contacts: Vec<Contact>) -> Vec<Contact> {
        let extra = contact::resolve(&self.p, v, &self.nbb, &self.bnd, self.cfg.particle_radius, self.cfg.dt);
        contact::merge(contacts, extra)
    }

    /// Per body, its force and torque (N, N m): the pressure's `reactions` and the reactions
    /// of the contacts (normal force and held friction).
    pub(super) fn body_forces(&self, reactions: Vec<BodyLoad>, contacts: &[Contact]) -> Vec<BodyLoad> {
        let mut forces = reactions;
        for c in contacts {
            let f = -(c.normal * c.normal_force + c.held.map_or(Vector3::zeros(), |h| h.force));
            let bi = c.body as usize;
            forces[bi].0 += f;
            forces[bi].1 += (c.point - self.bnd.bodies[bi].state.position).cross(&f);
        }
        forces
    }

    /// The divergence guard: an error when a velocity of `v` is not finite or exceeds
    /// `max_velocity`.
    pub(super) fn check_velocities(&self, v: &[Vector3<f64>]) -> Result<()> {
        let vmax = rmi_par::max(v.len(), |a| v[a].norm());
        if vmax.is_finite() && vmax <= self.cfg.max_velocity {
            return Ok(());
        }
        let reason = if vmax.is_finite() {
            format!("particle speed {vmax:.3} m/s exceeds max_velocity = {} m/s", self.cfg.max_velocity)
        } else {
            "non-finite particle velocity".to_string()
        };
        Err(RmiError::Unstable { step: self.step, time: self.time, max_velocity: vmax, reason })
    }

    /// Puts back what a diverged step changed: the solver memory and the last step's fields.
    pub(super) fn roll_back(&mut self, undo: Undo) {
        self.kappa_dt2 = undo.kappa_dt2;
        self.dv_prev = undo.dv_prev;
        self.response_prev = undo.response_prev;
        self.vstar_prev = undo.vstar_prev;
        self.solid.rotation = undo.rotation;
        self.kappa = undo.kappa;
        self.op_buffers.coarse = undo.coarse;
        std::mem::swap(&mut self.dens, &mut self.dens_last);
    }

    /// Commits a step that passed its guard: the contacts' loads on the skeleton (the next
    /// step's hysteresis), positions advected with `v`, the bodies' loads and motion, the
    /// clock.
    pub(super) fn commit(&mut self, v: Vec<Vector3<f64>>, forces: Vec<BodyLoad>, contacts: &[Contact]) {
        let nf = self.p.n_fluid;
        let mut contact_load = vec![0.0; self.contact_load.len()];
        for c in contacts {
            if c.particle as usize >= nf && c.normal_force > 0.0 {
                contact_load[c.particle as usize - nf] += c.normal_force;
            }
        }
        self.contact_load = contact_load;
        let dt = self.cfg.dt;
        self.p.x.par_iter_mut().zip(v.par_iter()).for_each(|(x, vi)| *x += dt * vi);
        self.p.v = v;
        for (b, f) in self.bnd.bodies.iter_mut().zip(forces) {
            b.force = f.0;
            b.torque = f.1;
        }
        self.bnd.advance(dt);
        self.time += dt;
        self.step += 1;
    }
}
