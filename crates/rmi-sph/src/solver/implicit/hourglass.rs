//! Hourglass control of the skeleton (Ganzenmüller 2015): springs on the part of each
//! rest-neighbour offset that a particle's deformation gradient does not explain. Their
//! velocity part is in the operator's elastic rows and diagonal blocks.

use crate::neighbourhood::kernel::CubicKernel;
use crate::solver::ctx::Ctx;
use crate::solver::elasticity::ElasticFields;
use crate::world::particles::{Particles, PorousObject, SolidRest};
use nalgebra::Vector3;

/// Hourglass spring constants (N/m) per rest pair: `alpha E V_s0 V_r0 W0_sr / |x0_sr|^2`
/// (Ganzenmüller 2015); they depend only on the rest configuration.
pub(crate) fn hourglass_constants(
    rest: &SolidRest,
    p: &Particles,
    objects: &[PorousObject],
    kernel: &CubicKernel,
) -> Vec<f64> {
    let nf = p.n_fluid;
    (0..rest.x0.len())
        .flat_map(|s| {
            let o = &objects[p.material[nf + s] as usize - 1];
            (rest.start[s] as usize..rest.start[s + 1] as usize).map(move |e| {
                let r = rest.nbr[e] as usize - nf;
                let dist = (rest.x0[r] - rest.x0[s]).norm();
                o.material.hourglass * o.material.youngs_modulus * rest.v0[s] * rest.v0[r] * kernel.w(dist)
                    / (dist * dist)
            })
        })
        .collect()
}

/// Explicit hourglass force on solid `s`: springs on the part of each rest-neighbour offset
/// that the particle's deformation gradient does not explain (zero for affine motion).
pub(super) fn hourglass_force(c: &Ctx, ef: &ElasticFields, s: usize) -> Vector3<f64> {
    let nf = c.p.n_fluid;
    let rest = c.rest;
    let x = &c.p.x;
    let a = nf + s;
    let mut f = Vector3::zeros();
    for e in rest.start[s] as usize..rest.start[s + 1] as usize {
        let r = rest.nbr[e] as usize;
        let k = rest.hg_k[e];
        if k == 0.0 {
            continue;
        }
        let d0 = rest.x0[r - nf] - rest.x0[s];
        let es = (x[r] - x[a]) - ef.ftil[s] * d0;
        let er = (x[a] - x[r]) + ef.ftil[r - nf] * d0;
        f += 0.5 * k * (es - er);
    }
    f
}
