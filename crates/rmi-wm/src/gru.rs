//! GRU layers with torch's gate equations, and the command encoder E_u.
//!
//! For input gates `gi = b_ih + x W_ih^T` and recurrent gates `gh = b_hh + h W_hh^T`, each
//! split `[r | z | n]`: `r = sigmoid(gi_r + gh_r)`, `z = sigmoid(gi_z + gh_z)`,
//! `n = tanh(gi_n + r * gh_n)`, `h' = n + z * (h - n)` (torch's `(1 - z) n + z h`).

use crate::gemm::{acc, Mat};

/// One GRU layer, weights transposed for [`acc`].
#[derive(Clone, Debug)]
pub struct GruLayer {
    /// Hidden width H.
    pub hidden: usize,
    /// Input weights, `inputs x 3H`.
    pub w_ih: Mat,
    /// Recurrent weights, `H x 3H`.
    pub w_hh: Mat,
    /// Input bias, `3H`.
    pub b_ih: Vec<f32>,
    /// Recurrent bias, `3H`.
    pub b_hh: Vec<f32>,
}

/// Fills `rows` rows of width `bias.len()` with `bias`.
pub fn fill_rows(out: &mut [f32], rows: usize, bias: &[f32]) {
    for row in out[..rows * bias.len()].chunks_exact_mut(bias.len()) {
        row.copy_from_slice(bias);
    }
}

impl GruLayer {
    /// `gi = b_ih + x W_ih^T` for `rows` rows of `x` (row stride `ldx`); `gi` is `rows x 3H`.
    pub fn input_gates(&self, x: &[f32], ldx: usize, rows: usize, gi: &mut [f32]) {
        fill_rows(gi, rows, &self.b_ih);
        acc(x, ldx, rows, &self.w_ih, gi, 3 * self.hidden);
    }

    /// Advances `h` (`rows x H`) by one step given its input gates `gi` (`rows x 3H`);
    /// `gh` is scratch of the same size.
    pub fn step(&self, gi: &[f32], h: &mut [f32], rows: usize, gh: &mut [f32]) {
        let hd = self.hidden;
        fill_rows(gh, rows, &self.b_hh);
        acc(h, hd, rows, &self.w_hh, gh, 3 * hd);
        rmi_par::cpu::hot(
            #[inline(always)]
            || {
                for r in 0..rows {
                    let gi = &gi[r * 3 * hd..(r + 1) * 3 * hd];
                    let gh = &mut gh[r * 3 * hd..(r + 1) * 3 * hd];
                    let hr = &mut h[r * hd..(r + 1) * hd];
                    // In passes over contiguous slices, so that the exponentials vectorise.
                    let (rz, n) = gh.split_at_mut(2 * hd);
                    for (g, &i) in rz.iter_mut().zip(&gi[..2 * hd]) {
                        *g = sigmoid(i + *g);
                    }
                    let (rg, z) = rz.split_at(hd);
                    for ((g, &i), &rj) in n.iter_mut().zip(&gi[2 * hd..]).zip(rg) {
                        *g = tanh(i + rj * *g);
                    }
                    for ((hj, &nj), &zj) in hr.iter_mut().zip(n.iter()).zip(z) {
                        *hj = nj + zj * (*hj - nj);
                    }
                }
            },
        );
    }
}

/// `exp(x)` in single precision to about 1 ulp for `x` in [-87, 88] (clamped beyond: 0 and
/// 2^127 stand for underflow and overflow), branch-free so that a loop of it vectorises.
///
/// Range reduction `x = n ln 2 + r` with a two-part `ln 2`, then the degree-7 polynomial of
/// Cephes' `expf` on |r| <= ln 2 / 2, then `2^n` put into the exponent bits. Only plain
/// products and sums: the same bits with and without the AVX2 copy.
#[inline(always)]
pub fn exp(x: f32) -> f32 {
    const LOG2E: f32 = std::f32::consts::LOG2_E;
    const LN2_HI: f32 = 0.693_359_4;
    const LN2_LO: f32 = -2.121_944_4e-4;
    // Adding and subtracting 1.5 * 2^23 rounds to the nearest integer (ties to even).
    const ROUND: f32 = 12_582_912.0;
    let x = x.clamp(-87.0, 88.0);
    let t = x * LOG2E + ROUND;
    let n = t - ROUND;
    let r = (x - n * LN2_HI) - n * LN2_LO;
    let mut p = 1.987_569_1e-4;
    p = p * r + 1.398_199_9e-3;
    p = p * r + 8.333_452e-3;
    p = p * r + 4.166_579_6e-2;
    p = p * r + 1.666_666_5e-1;
    p = p * r + 0.5;
    let e = p * (r * r) + r + 1.0;
    // The low bits of `t` hold n (|n| < 2^22): 2^n from them by integer arithmetic, not a
    // float-to-integer cast, which would not vectorise (it saturates).
    let biased = t.to_bits().wrapping_sub(ROUND.to_bits()).wrapping_add(127);
    e * f32::from_bits(biased << 23)
}

/// Logistic function `1 / (1 + e^-x)`.
#[inline(always)]
pub fn sigmoid(x: f32) -> f32 {
    1.0 / (1.0 + exp(-x))
}

/// Hyperbolic tangent as `1 - 2 / (e^2x + 1)`: absolute error about 1e-7 (relative error
/// grows only where |tanh x| is below that), enough for a GRU state.
#[inline(always)]
pub fn tanh(x: f32) -> f32 {
    1.0 - 2.0 / (exp(2.0 * x) + 1.0)
}

/// The command encoder E_u: `Linear(n_u, E)`, ReLU, `Linear(E, E)`.
#[derive(Clone, Debug)]
pub struct Mlp2 {
    /// `n_u x E`.
    pub w1: Mat,
    /// `E`.
    pub b1: Vec<f32>,
    /// `E x E`.
    pub w2: Mat,
    /// `E`.
    pub b2: Vec<f32>,
}

impl Mlp2 {
    /// Output width E.
    pub fn width(&self) -> usize {
        self.b2.len()
    }

    /// Encodes `rows` commands (`x`: `rows x n_u`) into `out` (`rows x E`); `hidden` is
    /// scratch of the same size.
    pub fn forward(&self, x: &[f32], rows: usize, hidden: &mut [f32], out: &mut [f32]) {
        let e = self.width();
        fill_rows(hidden, rows, &self.b1);
        acc(x, self.w1.rows, rows, &self.w1, hidden, e);
        for v in &mut hidden[..rows * e] {
            // Not `max`, which would turn NaN into 0 where torch's ReLU keeps it.
            if *v < 0.0 {
                *v = 0.0;
            }
        }
        fill_rows(out, rows, &self.b2);
        acc(hidden, e, rows, &self.w2, out, e);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Against the standard library in double precision, over the whole range the GRU sees.
    #[test]
    fn exp_sigmoid_tanh_accuracy() {
        let mut worst = (0.0f64, 0.0f64, 0.0f64);
        let mut x = -87.0f32;
        while x < 88.0 {
            let e = f64::from(x).exp();
            let rel = (f64::from(exp(x)) - e).abs() / e;
            worst.0 = worst.0.max(rel);
            let s = 1.0 / (1.0 + (-f64::from(x)).exp());
            worst.1 = worst.1.max((f64::from(sigmoid(x)) - s).abs());
            worst.2 = worst.2.max((f64::from(tanh(x)) - f64::from(x).tanh()).abs());
            x += 1.37e-3;
        }
        // Measured 7.8e-8, 8.7e-8, 1.7e-7: about one ulp (of 1 for sigmoid and tanh).
        assert!(worst.0 < 1.2e-7, "exp relative error {}", worst.0);
        assert!(worst.1 < 1.5e-7, "sigmoid error {}", worst.1);
        assert!(worst.2 < 3e-7, "tanh error {}", worst.2);
        assert_eq!(exp(-200.0), exp(-87.0));
        assert!(exp(200.0).is_finite());
    }
}
