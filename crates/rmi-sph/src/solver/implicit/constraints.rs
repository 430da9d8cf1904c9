//! Skeleton-body contacts as velocity constraints of the implicit solves: the components
//! each holds, the filter of Baraff and Witkin's modified PCG, and the impulse each exerted.

use super::Op;
use crate::solver::ctx::Ctx;
use crate::solver::linalg::CgWork;
use nalgebra::{Matrix3, Vector3};
use rayon::prelude::*;

/// A velocity constraint on one particle (a skeleton-body contact): `n . v* = target`, and
/// for a sticking contact also the tangential velocity.
#[derive(Clone, Copy, Debug)]
pub struct VelocityConstraint {
    /// Dynamic particle index.
    pub particle: u32,
    /// Unit normal (from the body into the particle's side).
    pub normal: Vector3<f64>,
    /// Required normal velocity in m/s.
    pub target: f64,
    /// Required tangential velocity (m/s, perpendicular to `normal`) of a contact that
    /// sticks: the whole velocity is then held, and the constraint's impulse carries the
    /// static friction force. `None` leaves the tangential motion free.
    pub tangential: Option<Vector3<f64>>,
}

impl VelocityConstraint {
    /// The velocity this constraint prescribes, given the particle's current one `v` (m/s):
    /// the normal component set to the target, the tangential one too where it sticks.
    pub fn project(&self, v: &Vector3<f64>) -> Vector3<f64> {
        match self.tangential {
            Some(t) => self.normal * self.target + t,
            None => v + self.normal * (self.target - self.normal.dot(v)),
        }
    }

    /// The part of a row impulse `j` (N s) that the constraint takes: along the normal, or
    /// all of it where it sticks (the free components of `j` are the solver's residual).
    pub fn held(&self, j: &Vector3<f64>) -> Vector3<f64> {
        match self.tangential {
            Some(_) => *j,
            None => self.normal * self.normal.dot(j),
        }
    }
}

/// The components of one particle's velocity that constraints hold.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(super) enum Filter {
    /// None.
    Free,
    /// The component along this unit normal.
    Normal(Vector3<f64>),
    /// All three.
    Full,
}

impl Filter {
    /// Removes the held components of `x` (the filter of Baraff and Witkin's modified PCG).
    #[inline(always)]
    pub(super) fn apply(&self, x: &mut Vector3<f64>) {
        match self {
            Filter::Free => {}
            Filter::Normal(n) => *x -= n * n.dot(x),
            Filter::Full => *x = Vector3::zeros(),
        }
    }
}

/// Per-particle filters of the constraints.
pub(super) fn constraint_field(n: usize, cons: &[VelocityConstraint]) -> Vec<Filter> {
    let mut f = vec![Filter::Free; n];
    for c in cons {
        f[c.particle as usize] = if c.tangential.is_some() { Filter::Full } else { Filter::Normal(c.normal) };
    }
    f
}

/// Per solid, whether a constrained row of the operator reads its linearised stress: the
/// constrained skeleton particles and their rest neighbours (a water particle's row reads
/// none).
pub(super) fn stress_rows(c: &Ctx, cons: &[VelocityConstraint]) -> Vec<bool> {
    let nf = c.p.n_fluid;
    let rest = c.rest;
    let mut rows = vec![false; c.p.n_solid()];
    for con in cons {
        let Some(s) = (con.particle as usize).checked_sub(nf) else { continue };
        rows[s] = true;
        for e in rest.start[s] as usize..rest.start[s + 1] as usize {
            rows[rest.nbr[e] as usize - nf] = true;
        }
    }
    rows
}

/// Removes the constrained components of every particle's vector.
pub(super) fn filter(x: &mut [Vector3<f64>], filters: &[Filter]) {
    x.par_iter_mut().zip(filters.par_iter()).for_each(|(xi, f)| f.apply(xi));
}

/// The preconditioned residual of particle `a`: `filter(M^-1 r)`.
#[inline(always)]
pub(super) fn precondition(minv: &[Matrix3<f64>], filters: &[Filter], a: usize, r: &Vector3<f64>) -> Vector3<f64> {
    let mut z = minv[a] * r;
    filters[a].apply(&mut z);
    z
}

/// What the constrained rows still lack after a solve, `A x - w.b` (N s), in the components
/// each constraint holds: the impulse it exerted on its particle. Only the constrained rows
/// of `A x` are evaluated, and the linearised stress only where they read it
/// ([`stress_rows`]).
pub(super) fn constraint_impulses(op: &Op, x: &[Vector3<f64>], w: &mut CgWork) -> Vec<Vector3<f64>> {
    if op.constraints.is_empty() {
        return Vec::new();
    }
    op.stress_pass_of_rows(x, &op.impulse_stress, &mut w.prl);
    op.constraints
        .iter()
        .map(|con| {
            let a = con.particle as usize;
            con.held(&(op.row(a, x, &w.prl) - w.b[a]))
        })
        .collect()
}

impl Op<'_> {
    /// Releases the tangential velocity of constraint `k` (a stick that slides): from now on
    /// the solves hold only its normal velocity.
    pub fn release_tangential(&mut self, k: usize) {
        let con = &mut self.constraints[k];
        con.tangential = None;
        self.filters[con.particle as usize] = Filter::Normal(con.normal);
    }
}
