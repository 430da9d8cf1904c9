//! Which liquid a sponge retains: the fluid inside its deformed skeleton's volume.
//!
//! Water pressed out of the pores first collects on the sponge's surface, within one kernel
//! support of its skeleton, before it drips off. A kernel-coverage threshold therefore
//! counts a film of expelled water as retained, and at coarse resolution that film holds
//! more water than a squeeze displaces. Instead each fluid particle is mapped back to the
//! skeleton's rest frame through its skeleton neighbours,
//!
//! `X = sum_s W_s (X_s0 + R_s^T (x - x_s)) / sum_s W_s`,
//!
//! with `X_s0` the rest position and `R_s` the corotated rotation of skeleton particle `s`,
//! and it is retained when `X` lies inside that object's rest block grown by one particle
//! radius: a particle centred there still overlaps the sponge. The margin keeps the outer
//! layer of pore water, which settles against the faces, from flickering in and out; water
//! a full spacing out, the film that a squeeze leaves on the surface, is expelled. Local
//! stretch is ignored: at the 10-20 % strains of a squeeze it shifts `X` by under a tenth of
//! the spacing for neighbours one spacing away. Lengths in m.

use crate::kernel::CubicKernel;
use crate::neighbours::NeighbourLists;
use crate::particles::{Particles, PorousObject, SolidRest, SolidState};
use nalgebra::Vector3;
use rayon::prelude::*;

/// Whether each fluid particle lies inside a porous object's deformed volume, from the
/// neighbour lists of the last step (or of `Simulation::update_fields`) and the current
/// positions, with the block grown by `margin` (m) on every side. A particle without
/// skeleton neighbours is outside.
pub fn inside(
    p: &Particles,
    nb: &NeighbourLists,
    rest: &SolidRest,
    solid: &SolidState,
    objects: &[PorousObject],
    kernel: &CubicKernel,
    margin: f64,
) -> Vec<bool> {
    let nf = p.n_fluid;
    if objects.is_empty() || nb.len() < nf {
        return vec![false; nf];
    }
    (0..nf)
        .into_par_iter()
        .map(|a| {
            let n = nb.of(a);
            // One rest-frame estimate per object (scenes hold one sponge): no allocation in
            // this per-particle, per-step pass.
            objects.iter().enumerate().any(|(k, o)| {
                let material = (k + 1) as u16;
                let (mut wsum, mut xw) = (0.0, Vector3::zeros());
                for &b in &n.j[n.n_fluid..] {
                    let b = b as usize;
                    if p.material[b] != material {
                        continue;
                    }
                    let s = b - nf;
                    let dx = p.x[a] - p.x[b];
                    let w = kernel.w(dx.norm());
                    if w > 0.0 {
                        wsum += w;
                        xw += w * (rest.x0[s] + solid.rotation[s].inverse_transform_vector(&dx));
                    }
                }
                if wsum <= 0.0 {
                    return false;
                }
                let x = xw / wsum;
                (0..3).all(|i| x[i] >= o.rest_min[i] - margin && x[i] <= o.rest_max[i] + margin)
            })
        })
        .collect()
}
