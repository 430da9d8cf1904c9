//! Corotated linear SPH elasticity of the skeleton (Peer et al. 2018) with the saturation
//! softening and bloating terms of the porous method (docs/physics.md §3.5).
//!
//! The trace term carries lambda (the probable intent of the method); the flag
//! `elasticity_reference_trace` reproduces the reference code, where it is missing.

use crate::solver::ctx::Ctx;
use crate::world::particles::SolidRest;
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

/// Extracts the rotation of each skeleton particle (Müller et al. 2016), warm-started, from
/// its corrected deformation gradient, which it leaves in `ftil` for [`prepare`].
pub fn rotations(c: &Ctx, rot: &mut [UnitQuaternion<f64>], ftil: &mut Vec<Matrix3<f64>>) {
    let nf = c.p.n_fluid;
    let x = &c.p.x;
    let rest = c.rest;
    ftil.resize(rot.len(), Matrix3::zeros());
    rmi_par::for_each_hot2(
        rot,
        ftil,
        #[inline(always)]
        |s, q, f| {
            *f = deformation_gradient(rest, x, nf, s);
            *q = extract_rotation(f, *q, 10);
        },
    );
}

/// The corrected deformation gradient `F = sum_r V_r0 (x_r - x_s) (x) L_s grad W0_sr` of
/// skeleton particle `s` (solid index) at positions `x` (by dynamic index; `nf` fluid
/// particles first): exact for affine motion, at faces too, where kernel sums are truncated.
#[inline(always)]
fn deformation_gradient(rest: &SolidRest, x: &[Vector3<f64>], nf: usize, s: usize) -> Matrix3<f64> {
    let mut f = Matrix3::zeros();
    for e in rest.start[s] as usize..rest.start[s + 1] as usize {
        let r = rest.nbr[e] as usize;
        f += rest.v0[r - nf] * (x[r] - x[nf + s]) * (rest.l[s] * rest.grad0[e]).transpose();
    }
    f
}

/// Volume ratio `J = det F` of skeleton particle `s` (solid index) at positions `x` (by
/// dynamic index; `nf` fluid particles first), `F` the corrected deformation gradient.
#[inline]
pub fn volume_ratio(rest: &SolidRest, x: &[Vector3<f64>], nf: usize, s: usize) -> f64 {
    deformation_gradient(rest, x, nf, s).determinant()
}

/// Iterative rotation extraction from a deformation matrix, starting at `q`.
#[inline]
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
pub(crate) fn stress(grad: &Matrix3<f64>, mu: f64, lam: f64, bloat: f64) -> Matrix3<f64> {
    let eps = 0.5 * (grad + grad.transpose());
    2.0 * mu * eps + Matrix3::from_diagonal_element(lam * eps.trace() - bloat)
}

/// Computes R L, the explicit stress term P R L at the current positions, and G_s; `out.ftil`
/// holds the deformation gradients [`rotations`] left there.
pub fn prepare(c: &Ctx, rot: &[UnitQuaternion<f64>], saturation: &[f64], out: &mut ElasticFields) {
    let nf = c.p.n_fluid;
    let ns = c.p.n_solid();
    let rest = c.rest;
    let x = &c.p.x;
    debug_assert_eq!(out.ftil.len(), ns, "rotations() leaves the deformation gradients first");
    out.rl.resize(ns, Matrix3::zeros());
    out.rl.par_iter_mut().enumerate().for_each(|(s, rl)| *rl = rot[s].to_rotation_matrix().matrix() * rest.l[s]);
    let rl = &out.rl;
    // Per solid: P R L, G_s and the moduli.
    type Row = (Matrix3<f64>, Vector3<f64>, (f64, f64));
    let mut rows: Vec<Row> = vec![(Matrix3::zeros(), Vector3::zeros(), (0.0, 0.0)); ns];
    rmi_par::for_each_hot(
        &mut rows,
        #[inline(always)]
        |s, row| {
            let a = nf + s;
            let rs = rot[s].to_rotation_matrix();
            let mut grad = Matrix3::zeros();
            let mut gsum = Vector3::zeros();
            for e in rest.start[s] as usize..rest.start[s + 1] as usize {
                let r = rest.nbr[e] as usize;
                let g = rl[s] * rest.grad0[e];
                let u = (x[r] - x[a]) - rs * (rest.x0[r - nf] - rest.x0[s]);
                grad += rest.v0[r - nf] * u * g.transpose();
                gsum += rest.v0[r - nf] * g;
            }
            let sat = saturation[a];
            let (mu, lam) = moduli(c, a, sat);
            let o = c.object(a);
            let bloat = o.lambda * o.material.bloating * sat;
            *row = (stress(&grad, mu, lam, bloat) * rl[s], gsum, (mu, lam));
        },
    );
    out.prl.clear();
    out.gsum.clear();
    out.moduli.clear();
    for (p, g, m) in rows {
        out.prl.push(p);
        out.gsum.push(g);
        out.moduli.push(m);
    }
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
