//! Velocity-level non-penetration of particles against the analytic shapes of the bodies.
//!
//! A compressible skeleton barely feels Akinci boundary pressure (its density ratio stays
//! below one at a wall), so skeleton-body contact is resolved here instead (physics.md
//! sec. 3.7). Fluid particles get the same projection only as a safety net against deep
//! penetration; their normal interaction is the pressure solve.

use crate::boundary::Boundary;
use crate::neighbours::NeighbourLists;
use crate::particles::Particles;
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
                let target = if p.is_fluid(a) {
                    FLUID_SKIN * radius
                } else {
                    radius
                };
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
                        });
                    }
                }
            }
            out
        })
        .collect();
    found.into_iter().flatten().collect()
}
