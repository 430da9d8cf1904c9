//! Preconditioned conjugate gradients over per-particle 3-vectors, with constraint filters
//! and an optional coarse level: the solver of the implicit systems.

use super::coarse::TwoLevel;
use nalgebra::{Matrix3, Vector3};
use rayon::prelude::*;

/// What one CG solve did.
#[derive(Clone, Copy, Debug, Default)]
pub struct CgStats {
    /// Iterations performed (0 when the solve was skipped).
    pub iterations: u32,
    /// Final relative residual.
    pub residual: f64,
    /// Norm of the filtered right-hand side (N s): the scale of the solve's momentum.
    pub rhs_norm: f64,
}

/// Work arrays reused between steps.
#[derive(Clone, Debug, Default)]
pub struct CgWork {
    pub(crate) r: Vec<Vector3<f64>>,
    pub(crate) p: Vec<Vector3<f64>>,
    pub(crate) ap: Vec<Vector3<f64>>,
    pub(crate) b: Vec<Vector3<f64>>,
    /// Block-Jacobi step of the residual, then the two-level preconditioned residual.
    pub(crate) y: Vec<Vector3<f64>>,
    /// Per-solid scratch of the product (the linearised stress).
    pub(crate) prl: Vec<Matrix3<f64>>,
}

impl CgWork {
    /// Sizes the vectors for `n` particles and the product's scratch for `n_solid` solids
    /// (what [`pcg`] and its callers expect; contents are overwritten before they are read).
    pub(crate) fn resize(&mut self, n: usize, n_solid: usize) {
        for buf in [&mut self.r, &mut self.p, &mut self.ap, &mut self.b] {
            buf.resize(n, Vector3::zeros());
        }
        self.prl.resize(n_solid, Matrix3::zeros());
    }
}

/// A symmetric system over per-particle 3-vectors that [`pcg`] solves: its product, the
/// filter of the components constraints hold, a block preconditioner and an optional coarse
/// level. `scratch` is per-solid work space of the product (the linearised stress).
pub(crate) trait System: Sync {
    /// `out = A y`.
    fn apply(&self, y: &[Vector3<f64>], out: &mut [Vector3<f64>], scratch: &mut [Matrix3<f64>]);
    /// `out = filter(A y)`; returns `y . out`.
    fn apply_filtered_dot(&self, y: &[Vector3<f64>], out: &mut [Vector3<f64>], scratch: &mut [Matrix3<f64>]) -> f64;
    /// Removes the held components of particle `a`'s vector `x`.
    fn filter_at(&self, a: usize, x: &mut Vector3<f64>);
    /// The preconditioned residual of particle `a`, filtered.
    fn precondition(&self, a: usize, r: &Vector3<f64>) -> Vector3<f64>;
    /// The coarse level, if any.
    fn coarse(&self) -> Option<&TwoLevel>;
}

/// Preconditioned CG on `A x = w.b` from the guess in `x`, with the constrained rows' normal
/// components held fixed; the tolerance is relative to the filtered right-hand side's norm,
/// or to `rhs_floor` (N s) where that is larger: a correction to an earlier solve of the
/// same step needs no smaller residual than that solve left. `guess_product`: `w.ap` already
/// holds `A x` of the guess (computed by the caller with it), so the solve needs no first
/// product.
///
/// The preconditioner is block Jacobi `y = M^-1 r`, plus, when the operator has a coarse
/// level ([`crate::solver::linalg::coarse`]), the additive coarse correction
/// `z = y + Z E^-1 Z^T r`. Each iteration is three parallel passes besides the stress pass
/// (A p with the filter and p . Ap; the r update with y, r . r and r . y; x and the new
/// direction), and the coarse pass with r . z. The sums have the chunking of `rmi_par::sum`,
/// so the iterates do not depend on how the passes are fused.
pub(crate) fn pcg<S: System>(
    op: &S,
    x: &mut [Vector3<f64>],
    w: &mut CgWork,
    tolerance: f64,
    max_iterations: u32,
    rhs_floor: f64,
    guess_product: bool,
) -> CgStats {
    w.y.resize(x.len(), Vector3::zeros());
    // A zero guess (a correction solved from scratch, such as the slip release) leaves the
    // right-hand side itself: no product.
    let zero_guess = !guess_product && x.iter().all(|xa| *xa == Vector3::zeros());
    if !guess_product && !zero_guess {
        op.apply(x, &mut w.ap, &mut w.prl);
    }
    // The filtered residual and the filtered right-hand side's norm, in one pass.
    let (b, ap) = (&w.b, &w.ap);
    let [bb] = rmi_par::for_each_sum(
        &mut w.r,
        #[inline(always)]
        |a, r| {
            *r = if zero_guess { b[a] } else { b[a] - ap[a] };
            op.filter_at(a, r);
            let mut bf = b[a];
            op.filter_at(a, &mut bf);
            [bf.dot(&bf)]
        },
    );
    let rhs_norm = bb.sqrt();
    let bnorm = rhs_norm.max(rhs_floor).max(1e-300);
    // Given y = M^-1 r and r . y: adds the coarse correction Z E^-1 Z^T r to y (Z is zero on
    // constrained particles, so it needs no filter of its own) and returns r . z.
    let coarse = |r: &[Vector3<f64>], y: &mut [Vector3<f64>], ry: f64| -> f64 {
        let Some(tl) = op.coarse() else { return ry };
        let c = tl.coarse_correction(r);
        let [rz] = rmi_par::for_each_sum(
            y,
            #[inline(always)]
            |a, ya| {
                *ya += tl.prolong(a, &c);
                [r[a].dot(ya)]
            },
        );
        rz
    };
    let r = &w.r;
    let [ry, rr] = rmi_par::for_each_sum(
        &mut w.y,
        #[inline(always)]
        |a, y| {
            *y = op.precondition(a, &r[a]);
            [r[a].dot(y), r[a].dot(&r[a])]
        },
    );
    let mut rz = coarse(&w.r, &mut w.y, ry);
    w.p.copy_from_slice(&w.y);
    let mut stats = CgStats { iterations: 0, residual: rr.sqrt() / bnorm, rhs_norm };
    while stats.residual > tolerance && stats.iterations < max_iterations {
        let pap = op.apply_filtered_dot(&w.p, &mut w.ap, &mut w.prl);
        if pap <= 0.0 || !pap.is_finite() {
            break;
        }
        let alpha = rz / pap;
        let ap = &w.ap;
        let [ry, rr] = rmi_par::for_each2_sum(
            &mut w.r,
            &mut w.y,
            #[inline(always)]
            |a, r, y| {
                *r -= alpha * ap[a];
                *y = op.precondition(a, r);
                [r.dot(y), r.dot(r)]
            },
        );
        let rz_new = coarse(&w.r, &mut w.y, ry);
        let beta = rz_new / rz;
        rz = rz_new;
        let z = &w.y;
        x.par_iter_mut().zip(w.p.par_iter_mut()).enumerate().for_each(|(a, (xi, pi))| {
            *xi += alpha * *pi;
            *pi = z[a] + beta * *pi;
        });
        stats.iterations += 1;
        stats.residual = rr.sqrt() / bnorm;
    }
    stats
}
