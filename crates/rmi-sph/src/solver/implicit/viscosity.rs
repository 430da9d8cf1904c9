//! Fluid viscosity in the operator (Weiler et al. 2018): the water-water pair coefficient
//! and the boundary viscosity against the walls, whose wall-velocity part goes to the
//! right-hand side.

use super::Op;
use crate::world::particles::LAPLACE_D;
use nalgebra::Vector3;

impl Op<'_> {
    /// Current volume `m_a / rho_a` of water particle `a` (m^3), a factor of its viscosity pairs.
    #[inline]
    pub(super) fn volume(&self, a: usize) -> f64 {
        self.c.p.mass[a] / self.rho[a]
    }

    /// Viscosity pair coefficient of two water particles with current volumes `va` and `vb`
    /// (m^3, [`Op::volume`]) before the pair geometry (`V_a V_b d mu`, N s m), divided by
    /// `|x|^2 + eps` by the cache.
    #[inline(always)]
    pub(super) fn viscosity(&self, va: f64, vb: f64) -> f64 {
        va * vb * LAPLACE_D * (self.s.viscosity * self.c.rho0_f)
    }

    /// Boundary viscosity with the fluid velocity `q` (matrix part) or the wall velocity (rhs part).
    pub(super) fn boundary_visc(&self, a: usize, q: Vector3<f64>, rhs: bool) -> Vector3<f64> {
        let mut f = Vector3::zeros();
        self.boundary_visc_terms(a, |k, coef, xak, g| {
            let vel = if rhs { -self.c.bnd.v[k] } else { q };
            f += (coef * vel.dot(xak)) * g;
        });
        f
    }

    /// Calls `term(k, coef, x_ak, grad W_ak)` for each wall neighbour k of fluid `a`: boundary
    /// viscosity is `sum coef ((v_a - v_k) . x_ak) grad W_ak`.
    #[inline(always)]
    pub(super) fn boundary_visc_terms(&self, a: usize, mut term: impl FnMut(usize, f64, &Vector3<f64>, &Vector3<f64>)) {
        let c = self.c;
        let nbb = c.nbb.of(a);
        let mub = self.s.boundary_viscosity * c.rho0_f;
        let va = self.volume(a);
        for k in 0..nbb.j.len() {
            let kk = nbb.j[k] as usize;
            let xak = c.p.x[a] - c.bnd.x[kk];
            let coef =
                va * LAPLACE_D * mub * (c.rho0_f * c.bnd.volume[kk] / self.rho[a]) / (xak.norm_squared() + self.eps_h);
            term(kk, coef, &xak, &nbb.g(k));
        }
    }
}
