//! Darcy-like drag between pore water and skeleton in the operator.

use super::Op;
use crate::solver::density::MIN_LOCAL_POROSITY;
use crate::world::particles::LAPLACE_D;

impl Op<'_> {
    #[inline]
    pub(super) fn phi(&self, i: usize) -> f64 {
        self.dens.porosity[i].max(MIN_LOCAL_POROSITY)
    }

    /// Drag pair coefficient (N s/m^2 times 1/m^2 factor applied with the pair geometry).
    #[inline]
    pub(super) fn drag(&self, i: usize, s: usize) -> f64 {
        let beta = self.c.object(s).drag_beta;
        LAPLACE_D * beta * self.c.p.mass[i] * self.c.vol / (self.rho[i] * self.phi(i))
    }
}
