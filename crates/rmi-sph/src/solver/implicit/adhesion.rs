//! Capillary adhesion between pore water and skeleton: its velocity part in the operator,
//! its position part on the right-hand side.

use super::Op;
use nalgebra::Vector3;

impl Op<'_> {
    /// The skeleton particle's part of the adhesion pair coefficient, `alpha (1 - f S_s)`
    /// (N/m; 0 without adhesion): [`Op::adhesion`] takes it so that it is evaluated once per
    /// skeleton particle.
    #[inline]
    pub(super) fn adhesion_strength(&self, s: usize) -> f64 {
        let o = self.c.object(s);
        o.adhesion * (1.0 - o.material.adhesion_falloff * self.dens.saturation[s])
    }

    /// The water particle's part of the adhesion pair coefficient against object `o` (an index
    /// into the context's objects): the mixture density `rho_i phi_i + rho_dry` (kg/m^3).
    #[inline]
    pub(super) fn adhesion_density(&self, i: usize, o: usize) -> f64 {
        self.rho[i] * self.phi(i) + self.c.objects[o].material.dry_density
    }

    /// Adhesion pair coefficient c_is (N/m) of water `i` and skeleton `s`, given
    /// `strength = adhesion_strength(s)`, `density = adhesion_density(i, s's object)` and W_is.
    #[inline(always)]
    pub(super) fn adhesion(&self, i: usize, s: usize, strength: f64, density: f64, w: f64) -> f64 {
        if strength == 0.0 {
            return 0.0;
        }
        strength * (self.c.p.mass[i] + self.c.p.mass[s]) / density * w
    }

    /// Position part of adhesion on `a`, `-sum c_ab (x_a - x_b)` (N), given `a`'s pair
    /// coefficients `cf` (in the order of its neighbour list).
    #[inline(always)]
    pub(super) fn adhesion_position_force(&self, a: usize, cf: &[[f64; 2]]) -> Vector3<f64> {
        let c = self.c;
        let nb = c.nb.of(a);
        let xa = c.p.x[a];
        let mut f = Vector3::zeros();
        for k in self.coupled(a, &nb) {
            let adh = cf[k][1];
            if adh != 0.0 {
                f -= adh * (xa - c.p.x[nb.j[k] as usize]);
            }
        }
        f
    }
}
