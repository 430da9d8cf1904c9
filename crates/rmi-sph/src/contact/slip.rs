//! The slip release: held sticks whose friction left the static cone slide within the step.

use super::{Contact, Friction, HeldFriction};
use crate::solver::implicit::{self, CgStats, CgWork};
use nalgebra::Vector3;

/// Switches the held sticks whose friction left the static cone `mu_st N` to sliding: each
/// one's tangential force becomes the kinetic force `mu_kin N` along it, the operator
/// releases that particle's tangential velocity (its other constraints stay held), and its
/// contact records the kinetic force. Returns the velocity increment (m/s) of the force
/// difference `dt (kinetic - held) / m` on those particles, for the operator's response;
/// `None` when no force changed. A contact that already slides this step keeps its kinetic
/// force unless its normal load has since fallen so far that the force left the static cone;
/// it is then brought back to `mu_kin N` of the present load. `previous` (per skeleton
/// particle, the normal force in N its contact ended the previous step with, zero for none)
/// caps the load of the kinetic force: a stick released before the pressure response slides
/// with `mu_kin min(N, N_prev)`, so that a load the response takes back, as it did a step
/// earlier, leaves the force inside the cone. `contacts` are aligned with the operator's
/// constraints; `mass` (kg) has every particle's.
pub(crate) fn slide_sticks(
    op: &mut implicit::Op,
    contacts: &mut [Contact],
    friction: &Friction,
    mass: &[f64],
    dt: f64,
    previous: Option<&[f64]>,
) -> Option<Vec<Vector3<f64>>> {
    let mut dv: Vec<Vector3<f64>> = Vec::new();
    for (k, c) in contacts.iter_mut().enumerate() {
        let Some(h) = c.held.as_mut() else { continue };
        let normal = c.normal_force.max(0.0);
        let f = h.force.norm();
        if f <= friction.mu_static * normal {
            continue;
        }
        let prev = previous.and_then(|p| (c.particle as usize).checked_sub(mass.len() - p.len()).map(|s| p[s]));
        let load = match prev {
            Some(prev) if prev > 0.0 => normal.min(prev),
            _ => normal,
        };
        let kinetic = h.force * (friction.mu_kinetic * load / f);
        if dv.is_empty() {
            dv = vec![Vector3::zeros(); mass.len()];
        }
        let a = c.particle as usize;
        dv[a] += dt / mass[a] * (kinetic - h.force);
        if h.stuck {
            op.release_tangential(k);
        }
        *h = HeldFriction { force: kinetic, stuck: false };
    }
    (!dv.is_empty()).then_some(dv)
}

/// Lets the held sticks whose friction left the static cone slide within the step
/// (Coulomb's bound inside the coupled system, [`slide_sticks`]), the force difference
/// passed through the implicit operator. One pass: a stick that the release overloads in
/// turn slides from the next step on. The response is a correction to the step's earlier
/// solves: it stops at their absolute residual, `tolerance x rhs_floor` (N s, the norm of the
/// right-hand side of the solve it corrects), where its own right-hand side is smaller.
/// Returns the response's statistics (zero iterations when no stick slid).
#[allow(clippy::too_many_arguments)]
pub(crate) fn release_slipping_sticks(
    op: &mut implicit::Op,
    contacts: &mut [Contact],
    friction: &Friction,
    mass: &[f64],
    dt: f64,
    v: &mut [Vector3<f64>],
    work: &mut CgWork,
    rhs_floor: f64,
) -> CgStats {
    let Some(mut dv) = slide_sticks(op, contacts, friction, mass, dt, None) else {
        return CgStats::default();
    };
    let (stats, impulses) = implicit::pressure_response(op, &mut dv, None, work, rhs_floor);
    v.iter_mut().zip(&dv).for_each(|(vi, d)| *vi += d);
    for (c, j) in contacts.iter_mut().zip(&impulses) {
        c.add_impulse(j, dt);
    }
    stats
}
