//! Velocity-level non-penetration of particles against the analytic shapes of the bodies.
//!
//! A compressible skeleton barely feels Akinci boundary pressure (its density ratio stays
//! below one at a wall), so skeleton-body contact is resolved here instead (docs/physics.md
//! sec. 3.7). Fluid particles get the same projection only as a safety net against deep
//! penetration; their normal interaction is the pressure solve.

use super::Friction;
use crate::neighbourhood::lists::NeighbourLists;
use crate::solver::implicit::VelocityConstraint;
use crate::world::boundary::Boundary;
use crate::world::particles::Particles;
use nalgebra::Vector3;
use rayon::prelude::*;

/// One particle-body contact of the current step.
#[derive(Clone, Copy, Debug)]
pub struct Contact {
    /// Dynamic particle index.
    pub particle: u32,
    /// Body index.
    pub body: u16,
    /// Unit normal pointing from the body into the particle's side.
    pub normal: Vector3<f64>,
    /// Contact point on the body surface (m).
    pub point: Vector3<f64>,
    /// Normal force on the particle (N), `>= 0`.
    pub normal_force: f64,
    /// Friction of a contact held as a stick inside the implicit solves (already applied,
    /// and already in the body's load); `None` for the others.
    pub held: Option<HeldFriction>,
}

/// The friction of a contact that the step's solves held as a stick.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct HeldFriction {
    /// Tangential force on the particle (N).
    pub force: Vector3<f64>,
    /// True when the force the stick needed stayed within the static cone `mu_st N`; false
    /// when it left the cone within the step and the contact slid with the kinetic force
    /// `mu_kin N` instead (the anchor is to be dropped).
    pub stuck: bool,
}

impl Contact {
    /// Adds a constraint impulse `j` (N s, on the particle) over a step `dt` (s): its normal
    /// part to the normal force, its tangential part to the stick force of a held stick.
    pub fn add_impulse(&mut self, j: &Vector3<f64>, dt: f64) {
        let jn = self.normal.dot(j);
        self.normal_force += jn / dt;
        if let Some(h) = &mut self.held {
            h.force += (j - self.normal * jn) / dt;
        }
    }
}

/// Fraction of the particle radius a fluid particle may sink into a body before projection.
const FLUID_SKIN: f64 = 0.5;

/// Projects velocities so that no particle ends the step closer than its radius (skeleton)
/// or half of it (fluid) to a body surface. Returns the contacts in particle order.
pub fn resolve(
    p: &Particles,
    v: &mut [Vector3<f64>],
    nbb: &NeighbourLists,
    bnd: &Boundary,
    radius: f64,
    dt: f64,
) -> Vec<Contact> {
    let nb_bodies = bnd.bodies.len();
    if nb_bodies == 0 {
        return Vec::new();
    }
    let chunk = 1024;
    let found: Vec<Vec<Contact>> = v
        .par_chunks_mut(chunk)
        .enumerate()
        .map(|(ci, vs)| {
            let mut out = Vec::new();
            for (l, va) in vs.iter_mut().enumerate() {
                let a = ci * chunk + l;
                let nbl = nbb.of(a);
                if nbl.j.is_empty() {
                    continue;
                }
                let target = if p.is_fluid(a) { FLUID_SKIN * radius } else { radius };
                // Only bodies that have a boundary particle within the kernel can touch.
                let mut seen = 0u64;
                for &k in nbl.j {
                    let bi = bnd.body[k as usize] as usize;
                    if bi < 64 {
                        seen |= 1 << bi;
                    }
                }
                for bi in 0..nb_bodies {
                    if bi < 64 && seen & (1 << bi) == 0 {
                        continue;
                    }
                    let (dist, n) = bnd.distance(bi, &p.x[a]);
                    let point = p.x[a] - dist * n;
                    let vb = bnd.point_velocity(bi, &point);
                    let vn = (*va - vb).dot(&n);
                    let gap = dist + dt * vn - target;
                    if gap < 0.0 {
                        let dvn = -gap / dt;
                        *va += dvn * n;
                        out.push(Contact {
                            particle: a as u32,
                            body: bi as u16,
                            normal: n,
                            point,
                            normal_force: p.mass[a] * dvn / dt,
                            held: None,
                        });
                    }
                }
            }
            out
        })
        .collect();
    found.into_iter().flatten().collect()
}

/// Contact distance hysteresis: an active contact stays active while within this fraction
/// of the radius beyond touching, so that resting contacts do not flicker.
const HOLD_SKIN: f64 = 0.05;

/// Finds skeleton particles touching or about to touch a body, one constraint each (the
/// deepest), with the normal velocity that lands them exactly one radius from the surface.
///
/// `load` (by solid index, N) is the normal force of each contact in the previous step; those
/// that pushed (positive) are kept while within the hold skin, and are released when they
/// pulled. A contact with a body that has `friction` also holds its tangential velocity (see
/// [`Friction`]).
pub fn detect(
    p: &Particles,
    nbb: &NeighbourLists,
    bnd: &Boundary,
    radius: f64,
    dt: f64,
    load: &[f64],
    friction: Option<&Friction>,
) -> Vec<(VelocityConstraint, u16, Vector3<f64>)> {
    let nf = p.n_fluid;
    let found: Vec<Option<(VelocityConstraint, u16, Vector3<f64>)>> = (nf..p.len())
        .into_par_iter()
        .map(|a| {
            let nbl = nbb.of(a);
            if nbl.j.is_empty() {
                return None;
            }
            let mut best: Option<(f64, VelocityConstraint, u16, Vector3<f64>)> = None;
            let mut seen = 0u64;
            for &k in nbl.j {
                let bi = bnd.body[k as usize] as usize;
                if bi >= 64 || seen & (1 << bi) != 0 {
                    continue;
                }
                seen |= 1 << bi;
                let (dist, n) = bnd.distance(bi, &p.x[a]);
                let point = p.x[a] - dist * n;
                let vb = bnd.point_velocity(bi, &point);
                let gap = dist + dt * (p.v[a] - vb).dot(&n) - radius;
                let hold = load[a - nf] > 0.0 && dist < radius * (1.0 + HOLD_SKIN);
                if gap < 0.0 || hold {
                    let target = vb.dot(&n) + (radius - dist) / dt;
                    let tangential = friction.filter(|f| f.on(bi)).map(|f| {
                        let recovery = f.anchor(a as u32, bi as u16).map_or(Vector3::zeros(), |s| s.anchor - point);
                        let t = vb + f.gain / dt * recovery;
                        t - n * n.dot(&t)
                    });
                    let con = VelocityConstraint { particle: a as u32, normal: n, target, tangential };
                    if best.as_ref().is_none_or(|b| dist < b.0) {
                        best = Some((dist, con, bi as u16, point));
                    }
                }
            }
            best.map(|(_, c, b, pt)| (c, b, pt))
        })
        .collect();
    found.into_iter().flatten().collect()
}

/// Merges two particle-ordered contact lists, summing the forces of the same particle-body pair.
pub fn merge(a: Vec<Contact>, b: Vec<Contact>) -> Vec<Contact> {
    if b.is_empty() {
        return a;
    }
    let mut all: Vec<Contact> = a.into_iter().chain(b).collect();
    all.sort_by_key(|c| (c.particle, c.body));
    let mut out: Vec<Contact> = Vec::with_capacity(all.len());
    for c in all {
        match out.last_mut() {
            Some(last) if last.particle == c.particle && last.body == c.body => {
                last.normal_force += c.normal_force;
                last.held = last.held.or(c.held);
            }
            _ => out.push(c),
        }
    }
    out
}
