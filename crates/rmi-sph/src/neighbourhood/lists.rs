//! Per-step neighbour lists with cached kernel values.
//!
//! Lists are built once per step and reused by every solver pass (densities, CG, Jacobi).
//! They are stored in fixed-size chunks of particles so that they can be built in parallel
//! without a global prefix sum, and so that the layout does not depend on the thread count.
//! For each particle the fluid neighbours come first, then the solid ones (`split`).
//!
//! A pair keeps its kernel gradient as the scalar factor `g(r)` of `grad W = g(r) (x_a - x_b)`
//! (8 bytes, not the 24 of the vector), with the lists' own copy of the positions they were
//! built at; [`Nb::g`] multiplies it back out with the same operations the build used, so
//! the gradient has the bits it would have had stored. The pressure iterations read only the
//! factor for their water pairs (the position-free sums of [`crate::neighbourhood::pairsum`], over
//! [`NeighbourLists::target_positions`] shifted once per step).

use crate::neighbourhood::grid::Grid;
use crate::neighbourhood::kernel::CubicKernel;
use nalgebra::Vector3;
use rayon::prelude::*;

/// Particles per chunk. Fixed: determinism must not depend on how work is split.
pub const CHUNK: usize = 256;

/// Neighbours of one chunk of particles, structure of arrays.
#[derive(Clone, Debug, Default)]
pub struct NbChunk {
    start: Vec<u32>,
    split: Vec<u32>,
    /// Neighbour indices.
    pub j: Vec<u32>,
    /// `W(x_a - x_b)`.
    pub w: Vec<f64>,
    /// Gradient factor `g(|x_a - x_b|)` (1/m^5 for the cubic spline's 1/m^4 gradient).
    gf: Vec<f64>,
}

/// Neighbours of one particle: slices into its chunk.
pub struct Nb<'a> {
    /// Neighbour indices (fluid ones first).
    pub j: &'a [u32],
    /// Kernel values.
    pub w: &'a [f64],
    /// Number of fluid neighbours at the front of the slices.
    pub n_fluid: usize,
    gf: &'a [f64],
    xa: Vector3<f64>,
    /// Target positions at build time; every `j` indexes it (checked when built).
    xt: &'a [Vector3<f64>],
}

impl Nb<'_> {
    /// Kernel gradient of pair `k` w.r.t. the centre particle (1/m^4), bit for bit the
    /// `(x_a - x_b) g(r)` of the build.
    #[inline(always)]
    pub fn g(&self, k: usize) -> Vector3<f64> {
        let (d, gf) = self.d_and_gf(k);
        d * gf
    }

    /// The pairs' gradient factors `g(r)` (1/m^5), in the order of [`Nb::j`].
    #[inline(always)]
    pub fn gf(&self) -> &[f64] {
        self.gf
    }

    /// `x_a - x_b` of pair `k` at the build positions (m) and the pair's gradient factor
    /// (1/m^5): `g(k)` is their product. For passes that need the distance vector too,
    /// so that they read each neighbour's position once.
    #[inline(always)]
    pub fn d_and_gf(&self, k: usize) -> (Vector3<f64>, f64) {
        let b = self.j[k] as usize;
        // SAFETY: `build` checks that every target index is below `xt.len()`.
        let xb = unsafe { self.xt.get_unchecked(b) };
        (self.xa - xb, self.gf[k])
    }
}

/// Neighbour lists of all dynamic particles.
#[derive(Clone, Debug, Default)]
pub struct NeighbourLists {
    chunks: Vec<NbChunk>,
    /// Query positions at build time.
    xq: Vec<Vector3<f64>>,
    /// Target positions by target index at build time (empty: the targets are the queries).
    xt: Vec<Vector3<f64>>,
    /// [`Grid::build_id`] of the grid `xt` was read from (0: none).
    xt_grid: u64,
}

impl NeighbourLists {
    /// Neighbours of particle `a`.
    #[inline(always)]
    pub fn of(&self, a: usize) -> Nb<'_> {
        let c = &self.chunks[a / CHUNK];
        let l = a % CHUNK;
        let s = c.start[l] as usize;
        let e = c.start[l + 1] as usize;
        let xt = if self.xt.is_empty() { &self.xq } else { &self.xt };
        Nb { j: &c.j[s..e], w: &c.w[s..e], n_fluid: (c.split[l] as usize) - s, gf: &c.gf[s..e], xa: self.xq[a], xt }
    }

    /// The positions the targets had when the lists were built (m), by target index.
    pub fn target_positions(&self) -> &[Vector3<f64>] {
        if self.xt.is_empty() {
            &self.xq
        } else {
            &self.xt
        }
    }

    /// Chunk index and the range of particle `a`'s pairs inside that chunk's arrays.
    #[inline(always)]
    pub fn span(&self, a: usize) -> (usize, usize, usize) {
        let c = &self.chunks[a / CHUNK];
        let l = a % CHUNK;
        (a / CHUNK, c.start[l] as usize, c.start[l + 1] as usize)
    }

    /// Number of pairs stored in each chunk (to size per-pair caches).
    pub fn chunk_pairs(&self) -> Vec<usize> {
        self.chunks.iter().map(|c| c.j.len()).collect()
    }

    /// Number of particles the lists cover (0 before the first build).
    pub fn len(&self) -> usize {
        self.chunks.iter().map(|c| c.start.len().saturating_sub(1)).sum()
    }

    /// Whether the lists cover no particle.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Total number of stored pairs.
    pub fn pairs(&self) -> usize {
        self.chunks.iter().map(|c| c.j.len()).sum()
    }

    /// Bytes held by the lists (capacity), for memory reports.
    pub fn bytes(&self) -> usize {
        self.chunks
            .iter()
            .map(|c| {
                c.j.capacity() * 4
                    + c.w.capacity() * 8
                    + c.gf.capacity() * 8
                    + (c.start.capacity() + c.split.capacity()) * 4
            })
            .sum::<usize>()
            + (self.xq.capacity() + self.xt.capacity()) * 24
    }

    /// Rebuilds the lists of `queries` against the points in `grid`.
    ///
    /// `n_fluid_targets`: target indices below it count as fluid (sorted to the front).
    /// `exclude_self`: skip the pair (a, a); only when queries and targets are the same set
    /// (the lists then keep one copy of the positions).
    ///
    /// # Panics
    /// If `exclude_self` and the grid holds a different number of points than `queries`.
    pub fn build(
        &mut self,
        queries: &[Vector3<f64>],
        grid: &Grid,
        kernel: &CubicKernel,
        n_fluid_targets: usize,
        exclude_self: bool,
    ) {
        let nchunks = queries.len().div_ceil(CHUNK);
        self.chunks.resize_with(nchunks, NbChunk::default);
        self.chunks.truncate(nchunks);
        let h2 = kernel.support() * kernel.support();
        self.xq.clear();
        self.xq.extend_from_slice(queries);
        let targets = grid.sorted_idx.len();
        if exclude_self {
            assert_eq!(targets, queries.len(), "exclude_self needs the queries to be the grid's points");
            debug_assert!(grid.sorted_idx.iter().enumerate().all(|(slot, &b)| grid.point(slot) == queries[b as usize]));
            self.xt.clear();
            self.xt_grid = 0;
        } else if self.xt_grid != grid.build_id() {
            // Positions by target index, read back from the grid (its indices are a
            // permutation of 0..targets), so a pair's gradient can be rebuilt from them.
            // Kept while the grid is not rebuilt (static walls).
            self.xt.resize(targets, Vector3::zeros());
            for (slot, &b) in grid.sorted_idx.iter().enumerate() {
                self.xt[b as usize] = grid.point(slot);
            }
            self.xt_grid = grid.build_id();
        }
        self.chunks.par_iter_mut().enumerate().for_each(|(ci, ch)| {
            let lo = ci * CHUNK;
            let hi = (lo + CHUNK).min(queries.len());
            let mut fill = Fill {
                ch,
                grid,
                kernel,
                n_fluid_targets,
                exclude_self,
                slots: Vec::new(),
                fluid: Vec::new(),
                solid: Vec::new(),
            };
            // The four-wide path holds slot numbers in 32-bit signed lanes.
            #[cfg(target_arch = "x86_64")]
            if rmi_par::cpu::avx2_enabled() && grid.sorted_idx.len() < i32::MAX as usize {
                // SAFETY: the CPU has AVX2 and FMA (detected by `avx2_enabled`).
                unsafe { fill.chunk_avx2(&queries[lo..hi], lo, h2) };
                return;
            }
            fill.chunk(
                &queries[lo..hi],
                lo,
                |xa, slots| scan(grid, xa, h2, slots),
                |ch, xa, slots| emit(ch, grid, kernel, xa, slots),
            );
        });
    }
}

/// State of one chunk's list build.
struct Fill<'a> {
    ch: &'a mut NbChunk,
    grid: &'a Grid,
    kernel: &'a CubicKernel,
    n_fluid_targets: usize,
    exclude_self: bool,
    /// Sorted slots of the current query's candidates inside the support, in scan order.
    slots: Vec<u32>,
    /// The same slots split into fluid and solid targets (self excluded), each in scan order.
    fluid: Vec<u32>,
    solid: Vec<u32>,
}

impl Fill<'_> {
    /// Builds the chunk's lists. `scan(x_a, slots)` fills `slots` with the sorted slots of the
    /// points closer than the support, in the grid's scan order, and returns their number;
    /// `emit(chunk, x_a, slots)` appends the pairs of `x_a` with those points.
    #[inline(always)]
    fn chunk(
        &mut self,
        queries: &[Vector3<f64>],
        first: usize,
        scan: impl Fn(&Vector3<f64>, &mut Vec<u32>) -> usize,
        emit: impl Fn(&mut NbChunk, &Vector3<f64>, &[u32]),
    ) {
        let ch = &mut *self.ch;
        ch.start.clear();
        ch.split.clear();
        ch.j.clear();
        ch.w.clear();
        ch.gf.clear();
        let grid = self.grid;
        let all_fluid = self.n_fluid_targets >= grid.sorted_idx.len();
        let one_side = all_fluid || self.n_fluid_targets == 0;
        for (k, xa) in queries.iter().enumerate() {
            let a = first + k;
            ch.start.push(ch.j.len() as u32);
            let n = scan(xa, &mut self.slots);
            self.fluid.clear();
            self.solid.clear();
            if one_side {
                // Every target on one side (water only, or the walls): the split is a copy
                // without the query's own slot, found by a compare-only search.
                let found = &self.slots[..n];
                let own = if self.exclude_self {
                    found.iter().position(|&slot| grid.sorted_idx[slot as usize] as usize == a)
                } else {
                    None
                };
                let side = if all_fluid { &mut self.fluid } else { &mut self.solid };
                match own {
                    Some(p) => {
                        side.extend_from_slice(&found[..p]);
                        side.extend_from_slice(&found[p + 1..]);
                    }
                    None => side.extend_from_slice(found),
                }
            } else {
                for &slot in &self.slots[..n] {
                    let b = grid.sorted_idx[slot as usize] as usize;
                    if self.exclude_self && b == a {
                        continue;
                    }
                    if b < self.n_fluid_targets { &mut self.fluid } else { &mut self.solid }.push(slot);
                }
            }
            emit(ch, xa, &self.fluid);
            ch.split.push(ch.j.len() as u32);
            emit(ch, xa, &self.solid);
        }
        ch.start.push(ch.j.len() as u32);
    }

    /// [`Fill::chunk`] with the four-wide scan and pair evaluation, compiled for AVX2.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx,avx2,fma,bmi1,bmi2,lzcnt,popcnt")]
    unsafe fn chunk_avx2(&mut self, queries: &[Vector3<f64>], first: usize, h2: f64) {
        let (grid, kernel) = (self.grid, self.kernel);
        self.chunk(
            queries,
            first,
            |xa, slots| unsafe { scan_avx2(grid, xa, h2, slots) },
            |ch, xa, slots| unsafe { emit_avx2(ch, grid, kernel, xa, slots) },
        );
    }
}

/// Scalar pair evaluation: `d = x_a - x_b`, `W(|d|)` and the gradient factor `g(|d|)`.
fn emit(ch: &mut NbChunk, grid: &Grid, kernel: &CubicKernel, xa: &Vector3<f64>, slots: &[u32]) {
    for &slot in slots {
        let d = xa - grid.point(slot as usize);
        let (w, gf) = kernel.w_and_grad_factor(d.norm_squared().sqrt());
        ch.j.push(grid.sorted_idx[slot as usize]);
        ch.w.push(w);
        ch.gf.push(gf);
    }
}

/// [`emit`] four pairs at a time, bit for bit: coordinates gathered from the grid's
/// coordinate arrays, the kernel through [`CubicKernel::w_and_grad_factor_x4`].
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx,avx2,fma,bmi1,bmi2,lzcnt,popcnt")]
unsafe fn emit_avx2(ch: &mut NbChunk, grid: &Grid, kernel: &CubicKernel, xa: &Vector3<f64>, slots: &[u32]) {
    use std::arch::x86_64::*;
    let [sx, sy, sz] = grid.soa();
    let (ax, ay, az) = (_mm256_set1_pd(xa.x), _mm256_set1_pd(xa.y), _mm256_set1_pd(xa.z));
    let m = slots.len();
    let base = ch.j.len();
    // Whole groups of four are stored, so up to three entries past the end are written (and
    // left beyond the length, overwritten by the next query's pairs).
    ch.j.reserve(m + 3);
    ch.w.reserve(m + 3);
    ch.gf.reserve(m + 3);
    let (jo, wo, go) = (ch.j.as_mut_ptr(), ch.w.as_mut_ptr(), ch.gf.as_mut_ptr());
    let mut i = 0;
    while i < m {
        // A last, partial group repeats its last slot in the missing lanes (results dropped).
        let [s0, s1, s2, s3] = [0, 1, 2, 3].map(|q| slots[(i + q).min(m - 1)] as usize);
        // SAFETY: the slots index the grid's points, which each coordinate array and the
        // sorted indices hold; the stores stay below base + m + 3, within the reserved capacity.
        unsafe {
            // Four scalar loads per coordinate rather than a gather instruction: the faster
            // of the two on the project's Zen 3 machine (docs/benchmark-history.md, "The list
            // build, cheaper by a fifth").
            let lanes = |a: &[f64]| {
                _mm256_set_pd(*a.get_unchecked(s3), *a.get_unchecked(s2), *a.get_unchecked(s1), *a.get_unchecked(s0))
            };
            let dx = _mm256_sub_pd(ax, lanes(sx));
            let dy = _mm256_sub_pd(ay, lanes(sy));
            let dz = _mm256_sub_pd(az, lanes(sz));
            let o = &grid.sorted_idx;
            let jv = _mm_set_epi32(
                *o.get_unchecked(s3) as i32,
                *o.get_unchecked(s2) as i32,
                *o.get_unchecked(s1) as i32,
                *o.get_unchecked(s0) as i32,
            );
            let r2 = _mm256_add_pd(_mm256_add_pd(_mm256_mul_pd(dx, dx), _mm256_mul_pd(dy, dy)), _mm256_mul_pd(dz, dz));
            let (wv, gf) = kernel.w_and_grad_factor_x4(_mm256_sqrt_pd(r2));
            _mm256_storeu_pd(wo.add(base + i), wv);
            _mm256_storeu_pd(go.add(base + i), gf);
            _mm_storeu_si128(jo.add(base + i) as *mut __m128i, jv);
        }
        i += 4;
    }
    // SAFETY: the first base + m entries are initialised (the old ones and those just written).
    unsafe {
        ch.j.set_len(base + m);
        ch.w.set_len(base + m);
        ch.gf.set_len(base + m);
    }
}

/// Scalar scan: the slots of the points within the support of `xa`, in scan order.
#[inline(always)]
fn scan(grid: &Grid, xa: &Vector3<f64>, h2: f64, slots: &mut Vec<u32>) -> usize {
    slots.clear();
    grid.for_each_run(
        xa,
        #[inline(always)]
        |lo, hi| {
            for slot in lo..hi {
                // Skip on `r2 >= h2` rather than keep on `r2 < h2`: a NaN distance is kept, as
                // the AVX2 scan keeps it, so a diverging state reaches the guard the same way
                // on any CPU.
                if (xa - grid.point(slot)).norm_squared() >= h2 {
                    continue;
                }
                slots.push(slot as u32);
            }
        },
    );
    slots.len()
}

/// For each 4-bit mask, the positions of its set bits, packed to the front.
#[cfg(target_arch = "x86_64")]
const COMPRESS: [[u32; 4]; 16] = {
    let mut t = [[0u32; 4]; 16];
    let mut m = 0;
    while m < 16 {
        let mut n = 0;
        let mut bit = 0;
        while bit < 4 {
            if m & (1 << bit) != 0 {
                t[m][n] = bit as u32;
                n += 1;
            }
            bit += 1;
        }
        m += 1;
    }
    t
};

/// The scan four candidates at a time: distances in AVX registers, the accepted slots packed
/// into `slots` through [`COMPRESS`] without a branch per candidate (about a quarter of the
/// candidates pass, in no pattern a predictor can learn). Same slots, same order as [`scan`];
/// returns how many (`slots` may hold garbage after them).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx,avx2,fma,bmi1,bmi2,lzcnt,popcnt")]
unsafe fn scan_avx2(grid: &Grid, xa: &Vector3<f64>, h2: f64, slots: &mut Vec<u32>) -> usize {
    use std::arch::x86_64::*;
    let [sx, sy, sz] = grid.soa();
    let (ax, ay, az) = (_mm256_set1_pd(xa.x), _mm256_set1_pd(xa.y), _mm256_set1_pd(xa.z));
    let h2v = _mm256_set1_pd(h2);
    let mut n = 0usize;
    grid.for_each_run(
        xa,
        #[inline(always)]
        |lo, hi| {
            if slots.len() < n + (hi - lo) + 4 {
                slots.resize(n + (hi - lo) + 4, 0);
            }
            // A raw pointer held in a register: through the Vec, every store would reload it.
            let out = slots.as_mut_ptr();
            // The lanes' mask of candidates inside the support, and the slot numbers of the
            // group's lanes (the running `first` vector saves a broadcast per group).
            let keep = |i: usize| {
                // SAFETY: i < hi <= points, and each coordinate array has SOA_PAD >= 3 entries
                // beyond the points.
                unsafe {
                    let dx = _mm256_sub_pd(ax, _mm256_loadu_pd(sx.as_ptr().add(i)));
                    let dy = _mm256_sub_pd(ay, _mm256_loadu_pd(sy.as_ptr().add(i)));
                    let dz = _mm256_sub_pd(az, _mm256_loadu_pd(sz.as_ptr().add(i)));
                    // (dx^2 + dy^2) + dz^2, unfused: nalgebra's norm_squared to the bit.
                    let r2 = _mm256_add_pd(
                        _mm256_add_pd(_mm256_mul_pd(dx, dx), _mm256_mul_pd(dy, dy)),
                        _mm256_mul_pd(dz, dz),
                    );
                    _mm256_movemask_pd(_mm256_cmp_pd::<_CMP_NGE_UQ>(r2, h2v)) as usize
                }
            };
            let put = |n: usize, first: __m128i, m: usize| {
                // SAFETY: `slots` has room for 4 more at n (resized above), and n only grows
                // by the accepted candidates of this run.
                unsafe {
                    let idx = _mm_add_epi32(first, _mm_loadu_si128(COMPRESS[m].as_ptr() as *const __m128i));
                    _mm_storeu_si128(out.add(n) as *mut __m128i, idx);
                }
                n + m.count_ones() as usize
            };
            let mut first = _mm_set1_epi32(lo as i32);
            let mut i = lo;
            // Whole groups without a tail mask; the last, partial group masked once.
            while i + 4 <= hi {
                n = put(n, first, keep(i));
                first = _mm_add_epi32(first, _mm_set1_epi32(4));
                i += 4;
            }
            if i < hi {
                n = put(n, first, keep(i) & ((1 << (hi - i)) - 1));
            }
        },
    );
    n
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::neighbourhood::grid::bounds;

    fn points(n: usize, seed: u64) -> Vec<Vector3<f64>> {
        let mut s = seed;
        let mut r = || {
            s = s.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            (s >> 11) as f64 / (1u64 << 53) as f64
        };
        (0..n).map(|_| Vector3::new(r(), 0.5 * r(), 0.4 * r())).collect()
    }

    /// Every list against brute force: the same neighbours, fluid targets first, `W` and the
    /// gradient of the kernel at the build positions (bit for bit the scalar evaluation), also
    /// after the caller has moved its particles (the lists keep their own positions).
    fn check(queries: &mut [Vector3<f64>], targets: &[Vector3<f64>], same_set: bool, n_fluid: usize) {
        let kernel = CubicKernel::new(0.09);
        let h = kernel.support();
        let (lo, hi) = bounds(targets, h);
        for reach in 1..=3 {
            let mut grid = Grid::default();
            grid.build_with(targets, lo, hi, h, reach);
            let mut nb = NeighbourLists::default();
            nb.build(queries, &grid, &kernel, n_fluid, same_set);
            let at_build = queries.to_vec();
            // Move the caller's particles: the lists must still describe the build positions.
            queries.iter_mut().for_each(|x| *x += Vector3::new(0.01, -0.02, 0.03));
            assert_eq!(nb.len(), queries.len());
            for (a, xa) in at_build.iter().enumerate() {
                let l = nb.of(a);
                let tx = |b: usize| if same_set { at_build[b] } else { targets[b] };
                let mut found: Vec<usize> = l.j.iter().map(|&b| b as usize).collect();
                assert!(found[..l.n_fluid].iter().all(|&b| b < n_fluid), "query {a}: fluid first");
                assert!(found[l.n_fluid..].iter().all(|&b| b >= n_fluid), "query {a}: solid after");
                for (k, &b) in found.iter().enumerate() {
                    let d = xa - tx(b);
                    let (w, gf) = kernel.w_and_grad_factor(d.norm_squared().sqrt());
                    assert_eq!(l.w[k].to_bits(), w.to_bits(), "query {a}, pair {k}: W");
                    let g = l.g(k);
                    assert_eq!(g.map(f64::to_bits), (d * gf).map(f64::to_bits), "query {a}, pair {k}: grad W");
                    assert!((g - kernel.grad(&d)).norm() <= 1e-12 * kernel.grad(&d).norm().max(1.0));
                }
                found.sort_unstable();
                let brute: Vec<usize> = (0..targets.len())
                    .filter(|&b| !(same_set && b == a) && (xa - tx(b)).norm_squared() < h * h)
                    .collect();
                assert_eq!(found, brute, "query {a}, reach {reach}");
            }
            queries.copy_from_slice(&at_build);
        }
    }

    #[test]
    fn lists_match_brute_force_with_their_own_positions() {
        let mut pts = points(1500, 7);
        let targets = pts.clone();
        check(&mut pts, &targets, true, 900);
        let mut queries = points(700, 11);
        check(&mut queries, &points(1200, 13), false, 400);
    }
}
