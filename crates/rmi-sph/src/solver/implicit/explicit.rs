//! Forces outside the implicit solve: explicit fluid viscosity and skeleton damping, and the
//! force diagnostics (drag plus adhesion at given velocities, buoyancy).

use super::operator::NonPressureSettings;
use super::Op;
use crate::config::{Preconditioner, ViscosityMode};
use crate::solver::ctx::Ctx;
use crate::solver::density::DensityFields;
use crate::solver::elasticity::ElasticFields;
use crate::world::particles::LAPLACE_D;
use nalgebra::Vector3;
use rayon::prelude::*;

/// Explicit accelerations outside the implicit solve: SPlisHSPlasH "standard" fluid viscosity
/// (when configured explicit) and skeleton damping; added to `acc` (m/s^2).
pub fn explicit_accelerations(
    c: &Ctx,
    dens: &DensityFields,
    s: &NonPressureSettings,
    v: &[Vector3<f64>],
    acc: &mut [Vector3<f64>],
) {
    let nf = c.p.n_fluid;
    let h = c.kernel.support();
    let eps_h = 0.01 * h * h;
    let explicit_visc = s.viscosity_mode == ViscosityMode::Explicit;
    // Fluid volumes once per particle instead of once per pair (same expression, same bits).
    let vol: Vec<f64> = if explicit_visc {
        (0..nf).into_par_iter().map(|b| c.p.mass[b] / (dens.rho_ratio[b] * c.rho0_f)).collect()
    } else {
        Vec::new()
    };
    rmi_par::for_each_hot(
        acc,
        #[inline(always)]
        |a, acc| {
            let nb = c.nb.of(a);
            let xa = c.p.x[a];
            let va = v[a];
            if a < nf {
                if !explicit_visc {
                    return;
                }
                let mut sum = Vector3::zeros();
                // The lists' own copy of the positions (the current ones, the lists were built
                // this step): one position read per pair instead of two.
                for k in 0..nb.n_fluid {
                    let b = nb.j[k] as usize;
                    let (xab, gf) = nb.d_and_gf(k);
                    sum += (vol[b] * (va - v[b]).dot(&xab) / (xab.norm_squared() + eps_h)) * (xab * gf);
                }
                let mut bsum = Vector3::zeros();
                if s.boundary_viscosity > 0.0 {
                    let nbb = c.nbb.of(a);
                    for k in 0..nbb.j.len() {
                        let kk = nbb.j[k] as usize;
                        let xak = xa - c.bnd.x[kk];
                        bsum += (c.bnd.volume[kk] / dens.rho_ratio[a] * (va - c.bnd.v[kk]).dot(&xak)
                            / (xak.norm_squared() + eps_h))
                            * nbb.g(k);
                    }
                }
                *acc += LAPLACE_D * (s.viscosity * sum + s.boundary_viscosity * bsum);
            } else {
                let o = c.object(a);
                let nu = o.material.damping;
                if nu == 0.0 || c.rest.fixed[a - nf] {
                    return;
                }
                let mut sum = Vector3::zeros();
                for k in nb.n_fluid..nb.j.len() {
                    let b = nb.j[k] as usize;
                    if c.p.material[b] != c.p.material[a] {
                        continue;
                    }
                    let (xab, gf) = nb.d_and_gf(k);
                    sum += (c.vol * (va - v[b]).dot(&xab) / (xab.norm_squared() + eps_h)) * (xab * gf);
                }
                *acc += LAPLACE_D * nu * sum;
            }
        },
    );
}

/// Drag plus adhesion force (N) on every dynamic particle for velocities `v` at the current
/// positions (both the velocity and the position part). Pairwise equal and opposite, so the
/// sum vanishes to round-off: a momentum-conservation diagnostic.
pub fn coupling_forces(c: &Ctx, dens: &DensityFields, v: &[Vector3<f64>]) -> Vec<Vector3<f64>> {
    // Viscosity off: only the inter-phase terms (drag, adhesion) are evaluated.
    let s = NonPressureSettings {
        viscosity: 0.0,
        boundary_viscosity: 0.0,
        viscosity_mode: ViscosityMode::Explicit,
        tolerance: 0.0,
        max_iterations: 0,
        preconditioner: Preconditioner::Identity,
        warm_start: false,
        coarse_cell: 0.0,
        coarse_steps: 1,
        step: 0,
    };
    let ef = ElasticFields::default();
    let op = Op::new(c, dens, &ef, &s, Vec::new());
    (0..c.p.len()).into_par_iter().map(|a| op.pair_forces(a, v) + op.adhesion_force[a]).collect()
}

/// Buoyancy force (N) on each skeleton particle from the pressure `kappa` (docs/physics.md §3.3).
pub fn buoyancy_forces(c: &Ctx, kappa: &[f64]) -> Vec<Vector3<f64>> {
    let nf = c.p.n_fluid;
    (nf..c.p.len())
        .into_par_iter()
        .map(|a| {
            let nb = c.nb.of(a);
            let phi = c.object(a).material.porosity;
            let mut f = Vector3::zeros();
            for k in 0..nb.n_fluid {
                let i = nb.j[k] as usize;
                f -= ((1.0 - phi) * c.vol * c.p.mass[i] * kappa[i]) * nb.g(k);
            }
            f
        })
        .collect()
}
