//! Cubic spline kernel (the SPlisHSPlasH/salva normalisation) with support radius `H = 4 r`.

use nalgebra::Vector3;

/// Cubic spline kernel in 3D. Lengths in m, `W` in 1/m^3, `grad W` in 1/m^4.
#[derive(Clone, Copy, Debug)]
pub struct CubicKernel {
    h: f64,
    inv_h: f64,
    k: f64,
    l: f64,
}

impl CubicKernel {
    /// Kernel with support radius `h` (m): `W` vanishes for `|x| >= h`.
    pub fn new(h: f64) -> Self {
        let h3 = h * h * h;
        CubicKernel { h, inv_h: 1.0 / h, k: 8.0 / (std::f64::consts::PI * h3), l: 48.0 / (std::f64::consts::PI * h3) }
    }

    /// Support radius in m.
    pub fn support(&self) -> f64 {
        self.h
    }

    /// `W(r)` for a distance `r >= 0`.
    #[inline]
    pub fn w(&self, r: f64) -> f64 {
        let q = r * self.inv_h;
        if q <= 0.5 {
            let q2 = q * q;
            self.k * (6.0 * q2 * q - 6.0 * q2 + 1.0)
        } else if q <= 1.0 {
            let f = 1.0 - q;
            2.0 * self.k * f * f * f
        } else {
            0.0
        }
    }

    /// `W(0)`, the self contribution.
    #[inline]
    pub fn w0(&self) -> f64 {
        self.k
    }

    /// Scalar `g(r)` such that `grad W(x) = g(|x|) x`; zero at the origin and outside the support.
    #[inline]
    pub fn grad_factor(&self, r: f64) -> f64 {
        if r < 1e-9 {
            return 0.0;
        }
        let q = r * self.inv_h;
        let dw = if q <= 0.5 {
            q * (3.0 * q - 2.0)
        } else if q <= 1.0 {
            let f = 1.0 - q;
            -f * f
        } else {
            return 0.0;
        };
        self.l * self.inv_h * dw / r
    }

    /// `(W(r), g(r))` in one evaluation, for `r` inside the support (see [`Self::grad_factor`]).
    #[inline(always)]
    pub fn w_and_grad_factor(&self, r: f64) -> (f64, f64) {
        let q = r * self.inv_h;
        if q <= 0.5 {
            let g = if r < 1e-9 { 0.0 } else { self.l * self.inv_h * q * (3.0 * q - 2.0) / r };
            (self.k * (6.0 * q * q * q - 6.0 * q * q + 1.0), g)
        } else if q <= 1.0 {
            let f = 1.0 - q;
            (2.0 * self.k * f * f * f, -self.l * self.inv_h * f * f / r)
        } else {
            (0.0, 0.0)
        }
    }

    /// [`Self::w_and_grad_factor`] for four distances at once, bit for bit: the same
    /// operations in the same order, every branch evaluated and the lane's result selected,
    /// so that four pairs cost one pass without a data-dependent branch.
    ///
    /// # Safety
    /// The CPU must support AVX.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx,avx2,fma")]
    #[inline]
    pub unsafe fn w_and_grad_factor_x4(
        &self,
        r: std::arch::x86_64::__m256d,
    ) -> (std::arch::x86_64::__m256d, std::arch::x86_64::__m256d) {
        use std::arch::x86_64::*;
        let s = _mm256_set1_pd;
        let q = _mm256_mul_pd(r, s(self.inv_h));
        // q <= 0.5: k (6 q q q - 6 q q + 1) and l / h q (3 q - 2) / r (0 below 1e-9).
        let six_q_q = _mm256_mul_pd(_mm256_mul_pd(s(6.0), q), q);
        let w_in = _mm256_mul_pd(s(self.k), _mm256_add_pd(_mm256_sub_pd(_mm256_mul_pd(six_q_q, q), six_q_q), s(1.0)));
        let g_in = _mm256_div_pd(
            _mm256_mul_pd(_mm256_mul_pd(s(self.l * self.inv_h), q), _mm256_sub_pd(_mm256_mul_pd(s(3.0), q), s(2.0))),
            r,
        );
        let g_in = _mm256_blendv_pd(g_in, s(0.0), _mm256_cmp_pd::<_CMP_LT_OQ>(r, s(1e-9)));
        // q <= 1: 2 k f f f and -l / h f f / r with f = 1 - q.
        let f = _mm256_sub_pd(s(1.0), q);
        let w_out = _mm256_mul_pd(_mm256_mul_pd(_mm256_mul_pd(s(2.0 * self.k), f), f), f);
        let g_out = _mm256_div_pd(_mm256_mul_pd(_mm256_mul_pd(s(-self.l * self.inv_h), f), f), r);
        // Outside the support (or NaN): both zero.
        let inside = _mm256_cmp_pd::<_CMP_LE_OQ>(q, s(1.0));
        let inner = _mm256_cmp_pd::<_CMP_LE_OQ>(q, s(0.5));
        let w = _mm256_and_pd(_mm256_blendv_pd(w_out, w_in, inner), inside);
        let g = _mm256_and_pd(_mm256_blendv_pd(g_out, g_in, inner), inside);
        (w, g)
    }

    /// `grad W(x)` for the offset `x = x_a - x_b`.
    #[inline]
    pub fn grad(&self, x: &Vector3<f64>) -> Vector3<f64> {
        x * self.grad_factor(x.norm())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn lattice_sum_is_partition_of_unity() {
        // On a cubic lattice of spacing d = 2r with V = d^3, sum V W ~ 1 (docs/physics.md §1: 0.99997).
        let r = 0.01;
        let d = 2.0 * r;
        let k = CubicKernel::new(4.0 * r);
        let mut s = 0.0;
        let mut g = Vector3::zeros();
        for i in -3i32..=3 {
            for j in -3i32..=3 {
                for l in -3i32..=3 {
                    let x = Vector3::new(i as f64, j as f64, l as f64) * d;
                    s += d * d * d * k.w(x.norm());
                    g += d * d * d * k.grad(&x);
                }
            }
        }
        assert!((s - 1.0).abs() < 1e-3, "sum V W = {s}");
        assert!(g.norm() < 1e-9);
    }

    #[test]
    fn gradient_matches_finite_difference() {
        let k = CubicKernel::new(0.04);
        for &r in &[0.003, 0.012, 0.019, 0.021, 0.033, 0.0399] {
            let x = Vector3::new(r * 0.6, r * 0.8, 0.0);
            let e = 1e-7;
            let fd = (k.w(r + e) - k.w(r - e)) / (2.0 * e);
            let an = k.grad(&x).norm() * if k.grad_factor(r) < 0.0 { -1.0 } else { 1.0 };
            assert!((fd - an).abs() < 1e-4 * fd.abs().max(1.0), "r={r} fd={fd} an={an}");
        }
        assert_eq!(k.w(0.05), 0.0);
    }

    #[cfg(target_arch = "x86_64")]
    #[test]
    fn four_wide_kernel_has_the_bits_of_the_scalar_one() {
        use std::arch::x86_64::*;
        if !(std::is_x86_feature_detected!("avx2") && std::is_x86_feature_detected!("fma")) {
            return;
        }
        let k = CubicKernel::new(0.05);
        // Both pieces, the join at q = 1/2, the support's edge, beyond it, tiny and zero distances, NaN.
        let mut rs: Vec<f64> = (0..4000).map(|i| i as f64 * 0.05 / 3000.0).collect();
        rs.extend([0.025, 0.025 * (1.0 + f64::EPSILON), 0.05, 0.05 * (1.0 - f64::EPSILON), 1e-10, 1e-9, 0.0, f64::NAN]);
        for c in rs.chunks(4) {
            let mut lane = [0.0; 4];
            lane[..c.len()].copy_from_slice(c);
            let (mut w, mut g) = ([0.0; 4], [0.0; 4]);
            // SAFETY: AVX2 detected above.
            unsafe {
                let (wv, gv) = k.w_and_grad_factor_x4(_mm256_loadu_pd(lane.as_ptr()));
                _mm256_storeu_pd(w.as_mut_ptr(), wv);
                _mm256_storeu_pd(g.as_mut_ptr(), gv);
            }
            for i in 0..4 {
                let (ws, gs) = k.w_and_grad_factor(lane[i]);
                assert_eq!((w[i].to_bits(), g[i].to_bits()), (ws.to_bits(), gs.to_bits()), "r = {:e}", lane[i]);
            }
        }
    }
}
