//! Linearised corotated elasticity in the operator: the stress of a velocity field, the
//! elastic rows (with the velocity part of the hourglass springs), the preconditioner's
//! diagonal blocks and the coarse level's strains.

use super::Op;
use crate::solver::ctx::Ctx;
use crate::solver::elasticity::{stress, ElasticFields};
use crate::solver::linalg::coarse::BlockRows;
use nalgebra::{Matrix3, Vector3};

/// The operator's elastic row of solid `s`: the elastic force
/// ([`force`](crate::solver::elasticity::force)) from the linearised `prl` plus the linear
/// (velocity) part of the hourglass springs for velocities `y`, `dt k (y_r - y_s)`, in one
/// pass over the rest neighbours. The two sums keep separate accumulators, so the
/// result has the bits of evaluating them one after the other.
#[inline(always)]
pub(super) fn linear_row(c: &Ctx, s: usize, prl: &[Matrix3<f64>], y: &[Vector3<f64>]) -> Vector3<f64> {
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
pub(super) fn linear_prl(c: &Ctx, ef: &ElasticFields, y: &[Vector3<f64>], out: &mut [Matrix3<f64>]) {
    rmi_par::for_each_hot(
        out,
        #[inline(always)]
        |s, prl| *prl = linear_prl_of(c, ef, y, s),
    );
}

/// [`linear_prl`] of the solids marked in `rows` only; the others' entries keep what they held.
pub(super) fn linear_prl_of_rows(
    c: &Ctx,
    ef: &ElasticFields,
    y: &[Vector3<f64>],
    rows: &[bool],
    out: &mut [Matrix3<f64>],
) {
    rmi_par::for_each_hot(
        out,
        #[inline(always)]
        |s, prl| {
            if rows[s] {
                *prl = linear_prl_of(c, ef, y, s);
            }
        },
    );
}

/// The linearised stress term of solid `s` ([`linear_prl`]).
#[inline(always)]
fn linear_prl_of(c: &Ctx, ef: &ElasticFields, y: &[Vector3<f64>], s: usize) -> Matrix3<f64> {
    let nf = c.p.n_fluid;
    let rest = c.rest;
    let ya = y[nf + s];
    let mut sum = Matrix3::zeros();
    for e in rest.start[s] as usize..rest.start[s + 1] as usize {
        let r = rest.nbr[e] as usize;
        sum += (rest.v0[r - nf] * (y[r] - ya)) * rest.grad0[e].transpose();
    }
    let grad = c.dt * sum * ef.rl[s].transpose();
    let (mu, lam) = ef.moduli[s];
    stress(&grad, mu, lam, 0.0) * ef.rl[s]
}

/// Exact 3x3 diagonal block (w.r.t. y_s) of `-dt * F_lin`, divided by dt^2.
pub(super) fn diagonal_block(c: &Ctx, ef: &ElasticFields, s: usize) -> Matrix3<f64> {
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
pub(super) fn coarse_strain(c: &Ctx, ef: &ElasticFields, agg: &[u32]) -> BlockRows<Vector3<f64>> {
    let nf = c.p.n_fluid;
    let rest = c.rest;
    BlockRows::build(
        c.p.n_solid(),
        #[inline(always)]
        |s, b| {
            for e in rest.start[s] as usize..rest.start[s + 1] as usize {
                let r = rest.nbr[e] as usize;
                b.add(agg[r], rest.v0[r - nf] * rest.grad0[e]);
            }
            b.add(agg[nf + s], -rest.grad0_sum[s]);
            b.map(|g| ef.rl[s] * g);
        },
    )
}

/// The 3x3 block `[P_x R L v, P_y R L v, P_z R L v]` of the stress term `P(eps) R L` applied
/// to `v` for the coarse displacement gradients `dt e_k (x) h` of [`coarse_strain`], with
/// moduli (mu, lam) and `w = R L v`: `dt (mu (h . w) I + mu h w^T + lam w h^T)`.
#[inline(always)]
pub(super) fn coarse_stress_times(h: &Vector3<f64>, w: &Vector3<f64>, (mu, lam): (f64, f64), dt: f64) -> Matrix3<f64> {
    dt * (Matrix3::from_diagonal_element(mu * h.dot(w)) + mu * h * w.transpose() + lam * w * h.transpose())
}

impl Op<'_> {
    /// Linearised stress of `y` into `prl` (the pass every row of `A y` reads).
    pub(super) fn stress_pass(&self, y: &[Vector3<f64>], prl: &mut [Matrix3<f64>]) {
        if self.c.p.n_solid() > 0 {
            linear_prl(self.c, self.ef, y, prl);
        }
    }

    /// The linearised stress of `y` at the solids marked in `rows` (the others' entries of
    /// `prl` keep what they held).
    pub(super) fn stress_pass_of_rows(&self, y: &[Vector3<f64>], rows: &[bool], prl: &mut [Matrix3<f64>]) {
        if self.c.p.n_solid() > 0 {
            linear_prl_of_rows(self.c, self.ef, y, rows, prl);
        }
    }
}
