//! Deterministic parallel helpers and runtime CPU dispatch, shared by the rmi SPH engine
//! (`rmi-sph`) and the world-model rollout (`rmi-wm`).
//!
//! Results never depend on the number of threads: floating-point sums are evaluated over
//! fixed-size chunks whose partial sums are then added sequentially, so the rounding is the
//! same whether one or many threads do the work. Per-element passes run each chunk through
//! [`cpu::hot`], which picks a copy compiled for AVX2 + FMA where the CPU has them, with the
//! same bits either way.

#![warn(missing_docs)]

pub mod cpu;

use rayon::prelude::*;

/// Chunk length for reductions; fixed so that results are independent of the thread count.
/// Short enough that a trial's sponge (about 1,800 particles at r = 5 mm) splits into several
/// chunks: with one chunk per pass, a second thread had nothing to do.
pub const REDUCE_CHUNK: usize = 256;

/// Deterministic sum of `f(i)` for `i in 0..n`.
pub fn sum<F>(n: usize, f: F) -> f64
where
    F: Fn(usize) -> f64 + Sync,
{
    let nchunks = n.div_ceil(REDUCE_CHUNK);
    let partial: Vec<f64> = (0..nchunks)
        .into_par_iter()
        .map(|c| {
            let lo = c * REDUCE_CHUNK;
            let hi = (lo + REDUCE_CHUNK).min(n);
            let mut s = 0.0;
            for i in lo..hi {
                s += f(i);
            }
            s
        })
        .collect();
    partial.iter().sum()
}

/// Calls `f(i, &mut out[i])` for every element in parallel (through [`crate::cpu::hot`]) and
/// returns the sums of the `K` values it yields, with the bits of [`sum`]: the same
/// [`REDUCE_CHUNK`] chunks, each summed in order, partial sums added in order. Fuses a
/// per-element update with the dot products that follow it, one pass instead of several.
#[inline(always)]
pub fn for_each_sum<T, F, const K: usize>(out: &mut [T], f: F) -> [f64; K]
where
    T: Send,
    F: Fn(usize, &mut T) -> [f64; K] + Sync,
{
    // A slice of zero-sized values costs nothing to allocate or to walk. The adapter must be
    // inlined too, or `f` is compiled as a function of its own for the baseline CPU.
    let mut none = vec![(); out.len()];
    for_each2_sum(
        out,
        &mut none,
        #[inline(always)]
        |i, x, _| f(i, x),
    )
}

/// [`for_each_sum`] over two arrays of equal length: `f(i, &mut a[i], &mut b[i])`, same
/// chunks and summation order.
#[inline(always)]
pub fn for_each2_sum<A, B, F, const K: usize>(a: &mut [A], b: &mut [B], f: F) -> [f64; K]
where
    A: Send,
    B: Send,
    F: Fn(usize, &mut A, &mut B) -> [f64; K] + Sync,
{
    let mut none = vec![(); a.len()];
    for_each3_sum(
        a,
        b,
        &mut none,
        #[inline(always)]
        |i, x, y, _| f(i, x, y),
    )
}

/// [`for_each_sum`] over three arrays of equal length: `f(i, &mut a[i], &mut b[i], &mut c[i])`,
/// same chunks and summation order.
#[inline(always)]
pub fn for_each3_sum<A, B, C, F, const K: usize>(a: &mut [A], b: &mut [B], c: &mut [C], f: F) -> [f64; K]
where
    A: Send,
    B: Send,
    C: Send,
    F: Fn(usize, &mut A, &mut B, &mut C) -> [f64; K] + Sync,
{
    let partial: Vec<[f64; K]> = a
        .par_chunks_mut(REDUCE_CHUNK)
        .zip(b.par_chunks_mut(REDUCE_CHUNK))
        .zip(c.par_chunks_mut(REDUCE_CHUNK))
        .enumerate()
        .map(|(ci, ((ca, cb), cc))| {
            crate::cpu::hot(
                #[inline(always)]
                || {
                    let mut s = [0.0; K];
                    for (k, ((x, y), z)) in ca.iter_mut().zip(cb.iter_mut()).zip(cc.iter_mut()).enumerate() {
                        let v = f(ci * REDUCE_CHUNK + k, x, y, z);
                        for (acc, vi) in s.iter_mut().zip(v) {
                            *acc += vi;
                        }
                    }
                    s
                },
            )
        })
        .collect();
    std::array::from_fn(|k| partial.iter().map(|p| p[k]).sum())
}

/// Deterministic maximum of `f(i)`; NaN wins so that divergence is never hidden.
pub fn max<F>(n: usize, f: F) -> f64
where
    F: Fn(usize) -> f64 + Sync,
{
    (0..n).into_par_iter().map(&f).reduce(
        || f64::NEG_INFINITY,
        |a, b| {
            if a.is_nan() || b.is_nan() {
                f64::NAN
            } else {
                a.max(b)
            }
        },
    )
}

/// Chunk length of [`for_each_hot`] (fixed, so the split never depends on the thread count);
/// [`REDUCE_CHUNK`], for the same reason.
pub const HOT_CHUNK: usize = REDUCE_CHUNK;

/// Calls `f(i, &mut out[i])` for every element in parallel, each chunk through
/// [`crate::cpu::hot`] so that per-particle loops get the AVX2 copy. Pass `f` marked
/// `#[inline(always)]` so that its body is compiled into that copy.
#[inline(always)]
pub fn for_each_hot<T, F>(out: &mut [T], f: F)
where
    T: Send,
    F: Fn(usize, &mut T) + Sync,
{
    out.par_chunks_mut(HOT_CHUNK).enumerate().for_each(|(c, ch)| {
        crate::cpu::hot(
            #[inline(always)]
            || {
                for (k, x) in ch.iter_mut().enumerate() {
                    f(c * HOT_CHUNK + k, x);
                }
            },
        )
    });
}

/// [`for_each_hot`] over two arrays of equal length: `f(i, &mut a[i], &mut b[i])`.
// Written out rather than delegated to `for_each_hot3` with a slice of `()`: that version
// made the pressure and viscosity passes slower (dam break, alternating runs).
#[inline(always)]
pub fn for_each_hot2<A, B, F>(a: &mut [A], b: &mut [B], f: F)
where
    A: Send,
    B: Send,
    F: Fn(usize, &mut A, &mut B) + Sync,
{
    a.par_chunks_mut(HOT_CHUNK).zip(b.par_chunks_mut(HOT_CHUNK)).enumerate().for_each(|(c, (ca, cb))| {
        crate::cpu::hot(
            #[inline(always)]
            || {
                for (k, (x, y)) in ca.iter_mut().zip(cb.iter_mut()).enumerate() {
                    f(c * HOT_CHUNK + k, x, y);
                }
            },
        )
    });
}

/// [`for_each_hot`] over three arrays of equal length: `f(i, &mut a[i], &mut b[i], &mut c[i])`.
#[inline(always)]
pub fn for_each_hot3<A, B, C, F>(a: &mut [A], b: &mut [B], c: &mut [C], f: F)
where
    A: Send,
    B: Send,
    C: Send,
    F: Fn(usize, &mut A, &mut B, &mut C) + Sync,
{
    a.par_chunks_mut(HOT_CHUNK).zip(b.par_chunks_mut(HOT_CHUNK)).zip(c.par_chunks_mut(HOT_CHUNK)).enumerate().for_each(
        |(ci, ((ca, cb), cc))| {
            crate::cpu::hot(
                #[inline(always)]
                || {
                    for (k, ((x, y), z)) in ca.iter_mut().zip(cb.iter_mut()).zip(cc.iter_mut()).enumerate() {
                        f(ci * HOT_CHUNK + k, x, y, z);
                    }
                },
            )
        },
    );
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Values whose sum depends on the order of the additions.
    fn values(n: usize) -> Vec<f64> {
        (0..n).map(|i| ((i * 7919 % 1009) as f64 - 504.5) * 10f64.powi((i % 13) as i32 - 6)).collect()
    }

    #[test]
    fn fused_sums_have_the_bits_of_separate_sums_for_any_thread_count() {
        let n = 3 * REDUCE_CHUNK + 517;
        let v = values(n);
        let want = [sum(n, |i| v[i]), sum(n, |i| v[i] * v[i])];
        for threads in [1, 2, 3] {
            let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap();
            let mut out = vec![0.0; n];
            let got = pool.install(|| {
                for_each_sum(&mut out, |i, o| {
                    *o = 2.0 * v[i];
                    [v[i], v[i] * v[i]]
                })
            });
            assert_eq!(got[0].to_bits(), want[0].to_bits(), "{threads} threads");
            assert_eq!(got[1].to_bits(), want[1].to_bits(), "{threads} threads");
            assert!(out.iter().zip(&v).all(|(o, x)| *o == 2.0 * x));
            let (mut p, mut q, mut r) = (vec![0.0; n], vec![0.0; n], vec![0.0; n]);
            let got3 = pool.install(|| {
                for_each3_sum(&mut p, &mut q, &mut r, |i, p, q, r| {
                    (*p, *q, *r) = (v[i], 2.0 * v[i], 3.0 * v[i]);
                    [v[i], v[i] * v[i]]
                })
            });
            assert_eq!(got3.map(f64::to_bits), want.map(f64::to_bits), "{threads} threads, three arrays");
            assert!((0..n).all(|i| (p[i], q[i], r[i]) == (v[i], 2.0 * v[i], 3.0 * v[i])));
        }
        // The chunking matters: a plain sequential sum of these values rounds differently.
        assert_ne!(v.iter().sum::<f64>().to_bits(), want[0].to_bits());
    }
}
