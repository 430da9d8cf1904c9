//! How much liquid a sponge retains: the part of each fluid particle that lies inside its
//! deformed skeleton's volume.
//!
//! Water pressed out of the pores first collects on the sponge's surface, within one kernel
//! support of its skeleton, before it drips off. A kernel-coverage threshold therefore
//! counts a film of expelled water as retained. Instead each fluid particle is mapped back to
//! the skeleton's rest frame through its skeleton neighbours,
//!
//! `X = sum_s W_s (X_s0 + R_s^T (x - x_s)) / sum_s W_s`,
//!
//! with `X_s0` the rest position and `R_s` the corotated rotation of skeleton particle `s`,
//! and it counts with the part of its sampling cube (side d, centred on `X`) that lies
//! inside the object's rest block: per axis the overlap `clamp(1/2 - s_k / d, 0, 1)` of the
//! cube with the block, where `s_k` is how far `X` lies outside the block along axis k
//! (negative inside), multiplied over the axes. Pore water a spacing inside a face counts
//! whole, a particle centred on the face half, one half a spacing out nothing.
//!
//! At the datasets' resolution one particle is a few grams, and a squeeze that closes a few
//! cm^3 of pores first pushes the whole outer layer of pore water outward by a fraction of a
//! millimetre before any particle leaves: a 0/1 test cannot see that, the overlap can (it
//! moves by the layer's areal mass times the shift). Local stretch is ignored: at the 10-20 %
//! strains of a squeeze it shifts `X` by under a tenth of the spacing for neighbours one
//! spacing away. Lengths in m.

use crate::neighbourhood::kernel::CubicKernel;
use crate::neighbourhood::lists::NeighbourLists;
use crate::world::particles::{Particles, PorousObject, SolidRest, SolidState};
use nalgebra::Vector3;
use rayon::prelude::*;

/// The part (in [0, 1]) of the sampling cube of side `d` (m) centred on rest-frame point `x`
/// that lies inside the box `min..max` (m).
pub fn cube_inside(x: &Vector3<f64>, min: &Vector3<f64>, max: &Vector3<f64>, d: f64) -> f64 {
    (0..3)
        .map(|k| {
            let outside = (x[k] - max[k]).max(min[k] - x[k]);
            (0.5 - outside / d).clamp(0.0, 1.0)
        })
        .product()
}

/// The retained part of each fluid particle (in [0, 1], see the module docs), from the
/// neighbour lists of the last step (or of `Simulation::update_fields`) and the current
/// positions, for sampling cubes of side `d` (m). A particle without skeleton neighbours
/// counts nothing; with several objects in reach, the largest part counts.
pub fn retained_parts(
    p: &Particles,
    nb: &NeighbourLists,
    rest: &SolidRest,
    solid: &SolidState,
    objects: &[PorousObject],
    kernel: &CubicKernel,
    d: f64,
) -> Vec<f64> {
    let nf = p.n_fluid;
    if objects.is_empty() || nb.len() < nf {
        return vec![0.0; nf];
    }
    (0..nf)
        .into_par_iter()
        .map(|a| {
            let n = nb.of(a);
            // One rest-frame estimate per object (scenes hold one sponge): no allocation in
            // this per-particle, per-step pass.
            objects
                .iter()
                .enumerate()
                .map(|(k, o)| {
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
                        return 0.0;
                    }
                    cube_inside(&(xw / wsum), &o.rest_min, &o.rest_max, d)
                })
                .fold(0.0, f64::max)
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn cube_overlap_is_the_volume_fraction_inside_the_box() {
        let (min, max, d) = (Vector3::new(0.0, 0.0, 0.0), Vector3::new(1.0, 1.0, 1.0), 0.1);
        let at = |x, y, z| cube_inside(&Vector3::new(x, y, z), &min, &max, d);
        assert_eq!(at(0.5, 0.5, 0.5), 1.0);
        assert_eq!(at(0.95, 0.5, 0.5), 1.0, "a cube touching the face from inside is whole");
        assert!((at(1.0, 0.5, 0.5) - 0.5).abs() < 1e-12, "centred on a face: half");
        assert!((at(1.02, 0.5, 0.5) - 0.3).abs() < 1e-12);
        assert_eq!(at(1.05, 0.5, 0.5), 0.0, "touching the face from outside: nothing");
        assert!((at(1.0, 1.0, 0.5) - 0.25).abs() < 1e-12, "on an edge: a quarter");
        assert!((at(0.0, 0.0, 0.0) - 0.125).abs() < 1e-12, "on a corner: an eighth");
    }
}
