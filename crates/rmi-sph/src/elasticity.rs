//! Corotated linear SPH elasticity of the skeleton (Peer et al. 2018) with the saturation
//! softening and bloating terms of the porous method (physics.md sec. 3.5).
//!
//! The trace term carries lambda (the probable intent of the method); the flag
//! `elasticity_reference_trace` reproduces the reference code, where it is missing.

use crate::ctx::Ctx;
use nalgebra::{Matrix3, UnitQuaternion, Vector3};
use rayon::prelude::*;

/// Per-solid matrices of the current step.
#[derive(Clone, Debug, Default)]
pub struct ElasticFields {
    /// R_s L_s for each solid.
    pub rl: Vec<Matrix3<f64>>,
    /// P_s R_s L_s (stress times correction) for the explicit force at x^n.
    pub prl: Vec<Matrix3<f64>>,
    /// `G_s = R_s L_s sum_r V_r0 grad W0_sr` (for the preconditioner).
    pub gsum: Vec<Vector3<f64>>,
    /// Full deformation gradient `sum_r V_r0 (x_r - x_s) (x) L_s grad W0_sr` (hourglass control).
    pub ftil: Vec<Matrix3<f64>>,
    /// Per solid the saturation-adjusted (shear modulus, trace coefficient) (Pa).
    pub moduli: Vec<(f64, f64)>,
}

/// Extracts the rotation of each skeleton particle (Müller et al. 2016), warm-started.
pub fn rotations(c: &Ctx, rot: &mut [UnitQuaternion<f64>]) {
    let nf = c.p.n_fluid;
    let x = &c.p.x;
    let rest = c.rest;
    rot.par_iter_mut().enumerate().for_each(|(s, q)| {
        let a = nf + s;
        let mut f = Matrix3::zeros();
        for e in rest.start[s] as usize..rest.start[s + 1] as usize {
            let r = rest.nbr[e] as usize;
            f += rest.v0[r - nf] * (x[r] - x[a]) * (rest.l[s] * rest.grad0[e]).transpose();
        }
        *q = extract_rotation(&f, *q, 10);
    });
}

/// Volume ratio `J = det F` of skeleton particle `s` (solid index) at positions `x` (by
/// dynamic index; `nf` fluid particles first), with `F = sum_r V_r0 (x_r - x_s) (x) L_s grad
/// W0_sr` the corrected deformation gradient: exact for affine motion, at faces too, where
/// kernel sums are truncated.
pub fn volume_ratio(rest: &crate::particles::SolidRest, x: &[Vector3<f64>], nf: usize, s: usize) -> f64 {
    let mut f = Matrix3::zeros();
    for e in rest.start[s] as usize..rest.start[s + 1] as usize {
        let r = rest.nbr[e] as usize;
        f += rest.v0[r - nf] * (x[r] - x[nf + s]) * (rest.l[s] * rest.grad0[e]).transpose();
    }
    f.determinant()
}

/// Iterative rotation extraction from a deformation matrix, starting at `q`.
pub fn extract_rotation(a: &Matrix3<f64>, mut q: UnitQuaternion<f64>, iterations: usize) -> UnitQuaternion<f64> {
    for _ in 0..iterations {
        let r = q.to_rotation_matrix();
        let r = r.matrix();
        let num = r.column(0).cross(&a.column(0)) + r.column(1).cross(&a.column(1)) + r.column(2).cross(&a.column(2));
        let den = (r.column(0).dot(&a.column(0)) + r.column(1).dot(&a.column(1)) + r.column(2).dot(&a.column(2))).abs()
            + 1e-9;
        let omega = num / den;
        let w = omega.norm();
        if w < 1e-9 {
            break;
        }
        q = UnitQuaternion::from_axis_angle(&nalgebra::Unit::new_unchecked(omega / w), w) * q;
    }
    q
}

/// Saturation-adjusted (shear modulus, trace coefficient) of solid dynamic index `a`.
#[inline]
pub fn moduli(c: &Ctx, a: usize, saturation: f64) -> (f64, f64) {
    let o = c.object(a);
    let m = &o.material;
    (
        (1.0 + saturation * m.softening_shear).max(1e-3) * o.mu,
        (1.0 + saturation * m.softening_volume).max(1e-3) * o.lambda_trace,
    )
}

/// Stress `P = 2 mu eps + (lam tr eps - bloat) I` from a displacement-gradient-like matrix.
#[inline]
fn stress(grad: &Matrix3<f64>, mu: f64, lam: f64, bloat: f64) -> Matrix3<f64> {
    let eps = 0.5 * (grad + grad.transpose());
    2.0 * mu * eps + Matrix3::from_diagonal_element(lam * eps.trace() - bloat)
}

/// Computes R L, the explicit stress term P R L at the current positions, and G_s.
pub fn prepare(c: &Ctx, rot: &[UnitQuaternion<f64>], saturation: &[f64], out: &mut ElasticFields) {
    let nf = c.p.n_fluid;
    let ns = c.p.n_solid();
    let rest = c.rest;
    let x = &c.p.x;
    out.rl.resize(ns, Matrix3::zeros());
    out.rl.par_iter_mut().enumerate().for_each(|(s, rl)| *rl = rot[s].to_rotation_matrix().matrix() * rest.l[s]);
    let rl = &out.rl;
    // Per solid: P R L, G_s, F~ and the moduli.
    type Row = (Matrix3<f64>, Vector3<f64>, Matrix3<f64>, (f64, f64));
    let rows: Vec<Row> = (0..ns)
        .into_par_iter()
        .map(|s| {
            let a = nf + s;
            let rs = rot[s].to_rotation_matrix();
            let mut grad = Matrix3::zeros();
            let mut gsum = Vector3::zeros();
            let mut ftil = Matrix3::zeros();
            for e in rest.start[s] as usize..rest.start[s + 1] as usize {
                let r = rest.nbr[e] as usize;
                ftil += rest.v0[r - nf] * (x[r] - x[a]) * (rest.l[s] * rest.grad0[e]).transpose();
                let g = rl[s] * rest.grad0[e];
                let u = (x[r] - x[a]) - rs * (rest.x0[r - nf] - rest.x0[s]);
                grad += rest.v0[r - nf] * u * g.transpose();
                gsum += rest.v0[r - nf] * g;
            }
            let sat = saturation[a];
            let (mu, lam) = moduli(c, a, sat);
            let o = c.object(a);
            let bloat = o.lambda * o.material.bloating * sat;
            (stress(&grad, mu, lam, bloat) * rl[s], gsum, ftil, (mu, lam))
        })
        .collect();
    out.prl.clear();
    out.gsum.clear();
    out.ftil.clear();
    out.moduli.clear();
    for (p, g, f, m) in rows {
        out.prl.push(p);
        out.gsum.push(g);
        out.ftil.push(f);
        out.moduli.push(m);
    }
}

/// Hourglass spring constants (N/m) per rest pair: `alpha E V_s0 V_r0 W0_sr / |x0_sr|^2`
/// (Ganzenmüller 2015); they depend only on the rest configuration.
pub fn hourglass_constants(
    rest: &crate::particles::SolidRest,
    p: &crate::particles::Particles,
    objects: &[crate::particles::PorousObject],
    kernel: &crate::kernel::CubicKernel,
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
pub fn hourglass_force(c: &Ctx, ef: &ElasticFields, s: usize) -> Vector3<f64> {
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

/// The operator's elastic row of solid `s`: [`force`] from the linearised `prl` plus the
/// linear (velocity) part of the hourglass springs for velocities `y`, `dt k (y_r - y_s)`,
/// in one pass over the rest neighbours. The two sums keep separate accumulators, so the
/// result has the bits of evaluating them one after the other.
#[inline(always)]
pub fn linear_row(c: &Ctx, s: usize, prl: &[Matrix3<f64>], y: &[Vector3<f64>]) -> Vector3<f64> {
    let nf = c.p.n_fluid;
    let rest = c.rest;
    let ya = y[nf + s];
    let mut f = prl[s] * rest.grad0_sum[s];
    let mut hg = Vector3::zeros();
    for e in rest.start[s] as usize..rest.start[s + 1] as usize {
        let r = rest.nbr[e] as usize;
        f += rest.v0[r - nf] * (prl[r - nf] * rest.grad0[e]);
        hg += (rest.hg_k[e] * c.dt) * (y[r] - ya);
    }
    rest.v0[s] * f + hg
}

/// Linearised stress term P(eps(y)) R L for velocities `y`: eps = sym(dt sum V0 (y_r - y_s) (x) g)
/// with `g = R_s L_s grad W0_sr`, summed as `dt (sum V0 (y_r - y_s) (x) grad W0_sr) (R_s L_s)^T`:
/// the rotation enters once per particle, not once per pair, so the pass reads only the rest
/// data every CG iteration (it is memory-bound at fine resolution).
pub fn linear_prl(c: &Ctx, ef: &ElasticFields, y: &[Vector3<f64>], out: &mut [Matrix3<f64>]) {
    let nf = c.p.n_fluid;
    let rest = c.rest;
    let dt = c.dt;
    crate::par::for_each_hot(
        out,
        #[inline(always)]
        |s, prl| {
            let ya = y[nf + s];
            let mut sum = Matrix3::zeros();
            for e in rest.start[s] as usize..rest.start[s + 1] as usize {
                let r = rest.nbr[e] as usize;
                sum += (rest.v0[r - nf] * (y[r] - ya)) * rest.grad0[e].transpose();
            }
            let grad = dt * sum * ef.rl[s].transpose();
            let (mu, lam) = ef.moduli[s];
            *prl = stress(&grad, mu, lam, 0.0) * ef.rl[s];
        },
    );
}

/// Elastic force on solid `s` from per-solid `prl` matrices: `V_s0 sum_r V_r0 (PRL_s + PRL_r) grad W0_sr`,
/// evaluated as `V_s0 (PRL_s sum_r V_r0 grad W0_sr + sum_r V_r0 PRL_r grad W0_sr)`.
#[inline(always)]
pub fn force(c: &Ctx, s: usize, prl: &[Matrix3<f64>]) -> Vector3<f64> {
    let nf = c.p.n_fluid;
    let rest = c.rest;
    let mut f = prl[s] * rest.grad0_sum[s];
    for e in rest.start[s] as usize..rest.start[s + 1] as usize {
        let r = rest.nbr[e] as usize - nf;
        f += rest.v0[r] * (prl[r] * rest.grad0[e]);
    }
    rest.v0[s] * f
}

/// Exact 3x3 diagonal block (w.r.t. y_s) of `-dt * F_lin`, divided by dt^2.
pub fn diagonal_block(c: &Ctx, ef: &ElasticFields, s: usize) -> Matrix3<f64> {
    let nf = c.p.n_fluid;
    let rest = c.rest;
    let vs = rest.v0[s];
    let (mu, lam) = ef.moduli[s];
    let g = ef.gsum[s];
    let mut d = vs * (mu * g.norm_squared() * Matrix3::identity() + (mu + lam) * g * g.transpose());
    for e in rest.start[s] as usize..rest.start[s + 1] as usize {
        let r = rest.nbr[e] as usize;
        let (mur, lamr) = ef.moduli[r - nf];
        // Neighbour r's strain sees y_s through g_rs = R_r L_r grad W(x_r0 - x_s0) = -R_r L_r grad0_sr.
        let grs = -(ef.rl[r - nf] * rest.grad0[e]);
        d += vs
            * vs
            * rest.v0[r - nf]
            * (mur * grs.norm_squared() * Matrix3::identity() + (mur + lamr) * grs * grs.transpose());
    }
    // Hourglass springs: dt^2 k (y_s - y_r) per pair.
    let ksum: f64 = (rest.start[s] as usize..rest.start[s + 1] as usize).map(|e| rest.hg_k[e]).sum();
    d + Matrix3::from_diagonal_element(ksum)
}

/// The two-level preconditioner's coarse unit translations seen by the linearised stress of
/// [`linear_prl`]: the velocity field `e_k` on aggregate J's particles (zero elsewhere) gives
/// solid s the displacement gradient `dt e_k (x) h_sJ` with
/// `h_sJ = R_s L_s (sum_{r in J} V_r0 grad W0_sr - [s in J] sum_r V_r0 grad W0_sr)`.
/// Returns `h_sJ` per solid and aggregate (`agg`: each dynamic particle's aggregate).
pub fn coarse_strain(c: &Ctx, ef: &ElasticFields, agg: &[u32]) -> crate::coarse::BlockRows<Vector3<f64>> {
    let nf = c.p.n_fluid;
    let rest = c.rest;
    crate::coarse::BlockRows::build(c.p.n_solid(), |s, b| {
        for e in rest.start[s] as usize..rest.start[s + 1] as usize {
            let r = rest.nbr[e] as usize;
            b.add(agg[r], rest.v0[r - nf] * rest.grad0[e]);
        }
        b.add(agg[nf + s], -rest.grad0_sum[s]);
        b.map(|g| ef.rl[s] * g);
    })
}

/// The 3x3 block `[P_x R L v, P_y R L v, P_z R L v]` of the stress term `P(eps) R L` applied
/// to `v` for the coarse displacement gradients `dt e_k (x) h` of [`coarse_strain`], with
/// moduli (mu, lam) and `w = R L v`: `dt (mu (h . w) I + mu h w^T + lam w h^T)`.
#[inline(always)]
pub fn coarse_stress_times(h: &Vector3<f64>, w: &Vector3<f64>, (mu, lam): (f64, f64), dt: f64) -> Matrix3<f64> {
    dt * (Matrix3::from_diagonal_element(mu * h.dot(w)) + mu * h * w.transpose() + lam * w * h.transpose())
}
