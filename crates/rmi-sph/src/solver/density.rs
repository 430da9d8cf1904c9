//! Porosity-aware densities, the DFSPH diagonal factor, local porosity and saturation.

use crate::solver::ctx::Ctx;
use nalgebra::Vector3;
use rayon::prelude::*;

/// Lower clamp of the fluid's local porosity where it divides (docs/physics.md §6.13).
pub const MIN_LOCAL_POROSITY: f64 = 0.05;

/// Outputs of the density pass; all indexed by dynamic particle.
#[derive(Clone, Debug, Default)]
pub struct DensityFields {
    /// Density ratio rho / rho0 (dimensionless).
    pub rho_ratio: Vec<f64>,
    /// DFSPH factor alpha (m^2).
    pub alpha: Vec<f64>,
    /// Fluid: local porosity (unclamped). Solid: current local porosity of the skeleton.
    pub porosity: Vec<f64>,
    /// Solid: saturation in [0, 1]. Fluid: 0.
    pub saturation: Vec<f64>,
    /// Fluid: skeleton coverage sum_s V W (about 1 inside a sponge, 1/2 on its surface).
    /// Solid: 0.
    pub skeleton_cover: Vec<f64>,
    /// Fluid: `sum_b V grad W_ab` over the fluid neighbours (1/m). Solid: 0.
    pub fluid_grad: Vec<Vector3<f64>>,
    /// Fluid: `sum_b (1 - phi_b) V grad W_ab` over the skeleton neighbours (1/m), what the
    /// pressure iterations read for a water particle's skeleton pairs. Solid: 0.
    pub solid_grad: Vec<Vector3<f64>>,
    /// Fluid: `sum_k V_k grad W_ak` over the boundary neighbours (1/m). Solid: 0.
    pub boundary_grad: Vec<Vector3<f64>>,
    /// Fluid: `sum_k V_k v_k . grad W_ak` over the boundary neighbours with the bodies'
    /// velocities of this step (1/s), the walls' part of the advected density. Solid: 0.
    pub boundary_flux: Vec<f64>,
}

/// Computes densities, alpha, local porosity and saturation for every dynamic particle.
pub fn compute(c: &Ctx, out: &mut DensityFields) {
    let n = c.p.len();
    for field in [&mut out.rho_ratio, &mut out.alpha, &mut out.porosity, &mut out.saturation, &mut out.skeleton_cover] {
        field.resize(n, 0.0);
    }
    for field in [&mut out.fluid_grad, &mut out.solid_grad, &mut out.boundary_grad] {
        field.resize(n, Vector3::zeros());
    }
    out.boundary_flux.resize(n, 0.0);
    // Each field written in place by its chunk's thread (no staging array, no serial unpack).
    let hc = rmi_par::HOT_CHUNK;
    (
        out.rho_ratio.par_chunks_mut(hc),
        out.alpha.par_chunks_mut(hc),
        out.porosity.par_chunks_mut(hc),
        out.saturation.par_chunks_mut(hc),
        out.skeleton_cover.par_chunks_mut(hc),
        out.fluid_grad.par_chunks_mut(hc),
        out.solid_grad.par_chunks_mut(hc),
        out.boundary_grad.par_chunks_mut(hc),
        out.boundary_flux.par_chunks_mut(hc),
    )
        .into_par_iter()
        .enumerate()
        .for_each(|(ci, (rho, alpha, phi, sat, cover, fg, sg, bg, bf))| {
            rmi_par::cpu::hot(
                #[inline(always)]
                || {
                    for k in 0..rho.len() {
                        let f = particle(c, ci * hc + k);
                        (rho[k], alpha[k], phi[k], sat[k], cover[k]) =
                            (f.rho, f.alpha, f.porosity, f.saturation, f.cover);
                        (fg[k], sg[k]) = (f.fluid_grad, f.solid_grad);
                        (bg[k], bf[k]) = (f.boundary_grad, f.boundary_flux);
                    }
                },
            )
        });
}

/// One particle's entries of [`DensityFields`].
struct Fields {
    rho: f64,
    alpha: f64,
    porosity: f64,
    saturation: f64,
    cover: f64,
    fluid_grad: Vector3<f64>,
    solid_grad: Vector3<f64>,
    boundary_grad: Vector3<f64>,
    boundary_flux: f64,
}

/// The fields of particle `a`.
#[inline(always)]
fn particle(c: &Ctx, a: usize) -> Fields {
    let nf = c.p.n_fluid;
    let nb = c.nb.of(a);
    let nbb = c.nbb.of(a);
    let v = c.vol;
    let fluid = a < nf;
    let self_factor = if fluid { 1.0 } else { c.volume_factor(a, a) };
    let mut dens = self_factor * v * c.kernel.w0();
    let mut grad_sum = Vector3::zeros();
    let mut grad_sq = 0.0;
    let mut solid_cover = 0.0; // sum over solids (1-phi) V W, for fluid porosity
    let mut skeleton_cover = 0.0; // sum over solids V W
    let mut fluid_sum = 0.0; // sum over fluid V W, for saturation
    let mut same_shepard = v * c.kernel.w0(); // same-object sum V W, self included

    // Fluid-fluid pairs have f = 1 (most pairs of a water scene): no material lookup.
    // `1 * v * w` is `v * w` exactly, so this is the general loop below to the bit.
    let mut first = 0;
    if fluid {
        for k in 0..nb.n_fluid {
            dens += v * nb.w[k];
            let gv = v * nb.g(k);
            grad_sum += gv;
            grad_sq += gv.norm_squared();
        }
        first = nb.n_fluid;
    }
    let fluid_grad = grad_sum;
    // A water particle's skeleton pairs (all pairs from `first` on), kept for the pressure
    // iterations, which would otherwise walk them again.
    let mut solid_grad = Vector3::zeros();
    for k in first..nb.j.len() {
        let b = nb.j[k] as usize;
        let f = c.volume_factor(a, b);
        dens += f * v * nb.w[k];
        let gv = f * v * nb.g(k);
        grad_sum += gv;
        grad_sq += gv.norm_squared();
        if fluid {
            solid_grad += gv;
            if k >= nb.n_fluid {
                solid_cover += f * v * nb.w[k];
                skeleton_cover += v * nb.w[k];
            }
        } else if k < nb.n_fluid {
            fluid_sum += v * nb.w[k];
        } else if c.p.material[b] == c.p.material[a] {
            same_shepard += v * nb.w[k];
        }
    }
    let mut bcover = 0.0;
    // Kept here, where the walk over the walls happens anyway, so that the pressure solve's
    // advected density needs no walk of its own: `sum V_k (v_a - v_k) . grad W_ak` is
    // `v_a . boundary_grad - boundary_flux`.
    let mut boundary_grad = Vector3::zeros();
    let mut boundary_flux = 0.0;
    // Bodies act on the skeleton only through contact constraints (contact/detect.rs): boundary
    // density under a compressible skeleton would make it float on pressure instead.
    let nbb_len = if fluid { nbb.j.len() } else { 0 };
    for k in 0..nbb_len {
        let kk = nbb.j[k] as usize;
        let vk = c.bnd.volume[kk];
        dens += vk * nbb.w[k];
        bcover += vk * nbb.w[k];
        let gk = vk * nbb.g(k);
        grad_sum += gk;
        boundary_grad += gk;
        boundary_flux += c.bnd.v[kk].dot(&gk);
    }
    let denom = grad_sum.norm_squared() + grad_sq;
    let alpha = if denom > 1e-5 { 1.0 / denom } else { 0.0 };
    let (porosity, saturation) = if fluid {
        (1.0 - solid_cover - bcover, 0.0)
    } else {
        // Saturation = water volume / current pore volume within the kernel. The rest
        // Shepard sum is the kernel coverage; compaction raises the current one.
        let s = a - nf;
        let phi = c.object(a).material.porosity;
        let cover0 = c.rest.shepard0[s];
        let cur_phi = (1.0 - (1.0 - phi) * same_shepard / cover0).max(MIN_LOCAL_POROSITY);
        (cur_phi, (fluid_sum / (cover0 * cur_phi)).min(1.0))
    };
    Fields {
        rho: dens,
        alpha,
        porosity,
        saturation,
        cover: skeleton_cover,
        fluid_grad,
        solid_grad,
        boundary_grad,
        boundary_flux,
    }
}
