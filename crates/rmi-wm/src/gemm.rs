//! Products of a few rows with a weight matrix, the only dense operation of the rollout.
//!
//! At batch 4-8 a general BLAS call spends most of its time in set-up; here the rows stay
//! in registers against a column panel of the weights, which are read once per product.
//! Every output element is `out + x[0] w[0] + x[1] w[1] + ...` accumulated in that order
//! with fused multiply-adds, whatever the row block: a row's result does not depend on
//! which other rows share its call, hence on the thread count.

/// Row-major `f32` matrix (`rows x cols`).
#[derive(Clone, Debug, PartialEq)]
pub struct Mat {
    /// Number of rows (the inner dimension K of a product `x * self`).
    pub rows: usize,
    /// Number of columns (outputs N).
    pub cols: usize,
    /// `rows * cols` values, row after row.
    pub data: Vec<f32>,
}

impl Mat {
    /// The transpose of a torch weight (`out x inp`, row-major), so that `x * mat` is
    /// torch's `x @ weight.T`.
    pub fn from_torch(weight: &[f32], out: usize, inp: usize) -> Self {
        debug_assert_eq!(weight.len(), out * inp);
        let mut data = vec![0.0; out * inp];
        for o in 0..out {
            for i in 0..inp {
                data[i * out + o] = weight[o * inp + i];
            }
        }
        Mat { rows: inp, cols: out, data }
    }

    /// Rows `lo..hi` as a matrix of their own (a slice of the inner dimension).
    pub fn row_range(&self, lo: usize, hi: usize) -> Self {
        Mat { rows: hi - lo, cols: self.cols, data: self.data[lo * self.cols..hi * self.cols].to_vec() }
    }
}

/// `out[r] += x[r] * w` for `r < rows`, where row `r` of `x` starts at `r * ldx` (its first
/// `w.rows` values are used) and row `r` of `out` at `r * ldo` (its first `w.cols` values).
///
/// Runs a copy compiled for AVX2 + FMA where the CPU has them (the dispatch the engine uses too,
/// [`rmi_par::cpu::hot`]); elsewhere the fused multiply-adds are library calls: the same
/// bits, many times slower.
pub fn acc(x: &[f32], ldx: usize, rows: usize, w: &Mat, out: &mut [f32], ldo: usize) {
    rmi_par::cpu::hot(
        #[inline(always)]
        || acc_body(x, ldx, rows, w, out, ldo),
    );
}

#[inline(always)]
fn acc_body(x: &[f32], ldx: usize, rows: usize, w: &Mat, out: &mut [f32], ldo: usize) {
    let mut r = 0;
    while r < rows {
        let n = (rows - r).min(4);
        let (xs, os) = (&x[r * ldx..], &mut out[r * ldo..]);
        match n {
            4 => panel::<4, 16>(xs, ldx, w, os, ldo),
            3 => panel::<3, 16>(xs, ldx, w, os, ldo),
            2 => panel::<2, 32>(xs, ldx, w, os, ldo),
            _ => panel::<1, 64>(xs, ldx, w, os, ldo),
        }
        r += n;
    }
}

/// `R` rows against column blocks of `C` (R * C / 8 vector accumulators), then the column
/// tail one element at a time in the same order.
#[inline(always)]
fn panel<const R: usize, const C: usize>(x: &[f32], ldx: usize, w: &Mat, out: &mut [f32], ldo: usize) {
    let (k_len, n) = (w.rows, w.cols);
    let xs: [&[f32]; R] = std::array::from_fn(|r| &x[r * ldx..r * ldx + k_len]);
    let wrows = || w.data.chunks_exact(n).take(k_len);
    let mut j = 0;
    while j + C <= n {
        let mut a = [[0.0f32; C]; R];
        for (r, ar) in a.iter_mut().enumerate() {
            ar.copy_from_slice(&out[r * ldo + j..r * ldo + j + C]);
        }
        for (k, wrow) in wrows().enumerate() {
            let wk: &[f32; C] = wrow[j..j + C].try_into().expect("panel width");
            for (ar, xr) in a.iter_mut().zip(&xs) {
                let xv = xr[k];
                for c in 0..C {
                    ar[c] = xv.mul_add(wk[c], ar[c]);
                }
            }
        }
        for (r, ar) in a.iter().enumerate() {
            out[r * ldo + j..r * ldo + j + C].copy_from_slice(ar);
        }
        j += C;
    }
    for (r, xr) in xs.iter().enumerate() {
        for jj in j..n {
            let mut s = out[r * ldo + jj];
            for (&xv, wrow) in xr.iter().zip(wrows()) {
                s = xv.mul_add(wrow[jj], s);
            }
            out[r * ldo + jj] = s;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn lcg(seed: &mut u64) -> f32 {
        *seed = seed.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
        ((*seed >> 40) as f32 / (1u64 << 24) as f32) - 0.5
    }

    /// Against a plain triple loop in the same order: identical bits for every row count
    /// (1-9 rows exercise all panels and their combinations) and ragged column counts.
    #[test]
    fn matches_reference_order_for_any_row_count() {
        let mut s = 7;
        for &(k, n) in &[(23, 384), (128, 407), (5, 3), (64, 100)] {
            let w = Mat { rows: k, cols: n, data: (0..k * n).map(|_| lcg(&mut s)).collect() };
            for rows in 1..10 {
                let x: Vec<f32> = (0..rows * (k + 2)).map(|_| lcg(&mut s)).collect();
                let init: Vec<f32> = (0..rows * (n + 1)).map(|_| lcg(&mut s)).collect();
                let mut out = init.clone();
                acc(&x, k + 2, rows, &w, &mut out, n + 1);
                for r in 0..rows {
                    for j in 0..n {
                        let mut e = init[r * (n + 1) + j];
                        for kk in 0..k {
                            e = x[r * (k + 2) + kk].mul_add(w.data[kk * n + j], e);
                        }
                        assert_eq!(out[r * (n + 1) + j].to_bits(), e.to_bits(), "k {k} n {n} rows {rows}");
                    }
                    // The padding column is left alone.
                    assert_eq!(out[r * (n + 1) + n], init[r * (n + 1) + n]);
                }
            }
        }
    }

    #[test]
    fn from_torch_transposes() {
        let m = Mat::from_torch(&[1.0, 2.0, 3.0, 4.0, 5.0, 6.0], 2, 3);
        assert_eq!((m.rows, m.cols), (3, 2));
        assert_eq!(m.data, vec![1.0, 4.0, 2.0, 5.0, 3.0, 6.0]);
    }
}
