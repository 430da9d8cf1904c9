//! Darcy-like drag between pore water and skeleton in the operator.

use super::Op;
use crate::solver::density::MIN_LOCAL_POROSITY;
use crate::world::particles::LAPLACE_D;

impl Op<'_> {
    #[inline]
    pub(super) fn phi(&self, i: usize) -> f64 {
        self.dens.porosity[i].max(MIN_LOCAL_POROSITY)
    }

    /// Drag pair coefficient of water particle `i` against the skeleton of object `o` (an
    /// index into the context's objects): N s/m^2, times the 1/m^2 factor applied with the
    /// pair geometry. It depends on the skeleton particle only through its object, so the
    /// operator evaluates it once per water particle and object.
    #[inline]
    pub(super) fn drag(&self, i: usize, o: usize) -> f64 {
        let beta = self.c.objects[o].drag_beta;
        LAPLACE_D * beta * self.c.p.mass[i] * self.c.vol / (self.rho[i] * self.phi(i))
    }
}
