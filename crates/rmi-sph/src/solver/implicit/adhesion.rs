//! Capillary adhesion between pore water and skeleton: its velocity part in the operator,
//! its position part on the right-hand side.

use super::Op;
use nalgebra::Vector3;

impl Op<'_> {
    /// Adhesion pair coefficient c_is (N/m), given W_is.
    #[inline]
    pub(super) fn adhesion(&self, i: usize, s: usize, w: f64) -> f64 {
        let o = self.c.object(s);
        if o.adhesion == 0.0 {
            return 0.0;
        }
        let sat = self.dens.saturation[s];
        o.adhesion * (1.0 - o.material.adhesion_falloff * sat) * (self.c.p.mass[i] + self.c.p.mass[s])
            / (self.rho[i] * self.phi(i) + o.material.dry_density)
            * w
    }

    /// Position part of adhesion on `a`, `-sum c_ab (x_a - x_b)` (N).
    pub(super) fn adhesion_position_force(&self, a: usize) -> Vector3<f64> {
        let c = self.c;
        let nb = c.nb.of(a);
        let cf = self.coefs(a);
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
