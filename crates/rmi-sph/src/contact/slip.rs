//! The slip release: held sticks whose friction left the static cone slide within the step.

use super::{Contact, Friction, HeldFriction};
use crate::solver::implicit::{self, CgStats, CgWork};
use nalgebra::Vector3;

/// Lets the held sticks whose friction left the static cone `mu_st N` slide within the step
/// (Coulomb's bound inside the coupled system): each one's tangential force becomes the
/// kinetic force `mu_kin N` along it, the difference passes through the implicit operator
/// with that particle's tangential velocity released (the other constraints held), and its
/// contact records the kinetic force. `contacts` are aligned with the operator's
/// constraints. One pass: a stick that the release overloads in turn slides from the next
/// step on. Returns the response's statistics (zero iterations when no stick slid).
pub(crate) fn release_slipping_sticks(
    op: &mut implicit::Op,
    contacts: &mut [Contact],
    friction: &Friction,
    mass: &[f64],
    dt: f64,
    v: &mut [Vector3<f64>],
    work: &mut CgWork,
) -> CgStats {
    let mut dv: Vec<Vector3<f64>> = Vec::new();
    for (k, c) in contacts.iter_mut().enumerate() {
        let Some(h) = c.held.as_mut() else { continue };
        let normal = c.normal_force.max(0.0);
        let f = h.force.norm();
        if f <= friction.mu_static * normal {
            continue;
        }
        let kinetic = h.force * (friction.mu_kinetic * normal / f);
        if dv.is_empty() {
            dv = vec![Vector3::zeros(); v.len()];
        }
        let a = c.particle as usize;
        dv[a] += dt / mass[a] * (kinetic - h.force);
        *h = HeldFriction { force: kinetic, stuck: false };
        op.release_tangential(k);
    }
    if dv.is_empty() {
        return CgStats::default();
    }
    let (stats, impulses) = implicit::pressure_response(op, &mut dv, None, work);
    v.iter_mut().zip(&dv).for_each(|(vi, d)| *vi += d);
    for (c, j) in contacts.iter_mut().zip(&impulses) {
        c.add_impulse(j, dt);
    }
    stats
}
