//! Uniform grid with cell size >= the kernel support, built by a stable counting sort.
//!
//! Cells are numbered x-fastest, so the three cells of one (y, z) row are contiguous in the
//! sorted arrays and a neighbour query scans 9 contiguous runs instead of 27 cells.

use nalgebra::Vector3;
use rayon::prelude::*;

/// Points sorted by cell. Sorted copies of the positions keep the candidate scan sequential.
#[derive(Clone, Debug, Default)]
pub struct Grid {
    origin: Vector3<f64>,
    inv_cell: f64,
    dims: [usize; 3],
    /// Cells searched on each side of the query cell (cell size = support / reach).
    reach: usize,
    /// `cell_start[c]..cell_start[c+1]` indexes `sorted_*` for cell `c`.
    cell_start: Vec<u32>,
    /// Original index of each sorted point.
    pub sorted_idx: Vec<u32>,
    /// Positions of the sorted points by coordinate (x, y, z), each followed by [`SOA_PAD`]
    /// zeros, so that a neighbour scan can test four candidates per instruction, reading past
    /// the end of a run without bounds checks. [`Grid::point`] reads one point back.
    soa: [Vec<f64>; 3],
    cell_of: Vec<u32>,
    /// Per cell, whether a query there has any candidate (empty: not computed, scan always).
    /// Worth it for sparse, rarely rebuilt point sets such as the walls, where most water
    /// particles would otherwise scan nine empty runs.
    near: Vec<bool>,
    /// Number of this build, unique in the process (0: never built): lets users of the sorted
    /// points tell whether they changed since they last read them (static walls).
    build_id: u64,
}

/// Source of [`Grid::build_id`] values.
static BUILDS: std::sync::atomic::AtomicU64 = std::sync::atomic::AtomicU64::new(1);

/// Padding after each coordinate array of [`Grid::soa`]: a 4-wide load at the last point stays
/// inside the allocation.
pub const SOA_PAD: usize = 3;

/// Points per parallel task when computing cell numbers.
const POINT_CHUNK: usize = 4096;

/// Cell ranges of the parallel scatter (fixed; the sorted order does not depend on it).
const SCATTER_PARTS: usize = 4;

/// Cap on cells per point so that a few far-flung particles cannot blow up memory.
const MAX_CELLS_PER_POINT: usize = 8;

impl Grid {
    /// Rebuilds the grid over `points` (which must lie in `[lo, hi]`) for queries of radius `h`.
    pub fn build(&mut self, points: &[Vector3<f64>], lo: Vector3<f64>, hi: Vector3<f64>, h: f64) {
        self.build_with(points, lo, hi, h, 1);
    }

    /// As [`Grid::build`] with cells of size `h / reach`, searched `reach` cells to each side:
    /// `reach = 2` scans a 5^3 block of half-size cells, about 40 % fewer candidates for dense
    /// particle sets than 3^3 cells of size `h`.
    pub fn build_with(&mut self, points: &[Vector3<f64>], lo: Vector3<f64>, hi: Vector3<f64>, h: f64, reach: usize) {
        self.build_id = BUILDS.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
        self.reach = reach.max(1);
        let h = h / self.reach as f64;
        let ext = (hi - lo).map(|e| e.max(h));
        let budget = (MAX_CELLS_PER_POINT * points.len()).max(1 << 16) as f64;
        let mut cell = h;
        let cells = |c: f64| ext.iter().map(|e| (e / c).floor() + 1.0).product::<f64>();
        while cells(cell) > budget {
            cell *= 1.25;
        }
        self.near.clear();
        self.origin = lo;
        self.inv_cell = 1.0 / cell;
        for k in 0..3 {
            self.dims[k] = (ext[k] / cell).floor() as usize + 1;
        }
        let ncell = self.dims[0] * self.dims[1] * self.dims[2];
        self.cell_start.clear();
        self.cell_start.resize(ncell + 1, 0);
        let mut cell_of = std::mem::take(&mut self.cell_of);
        cell_of.resize(points.len(), 0);
        {
            let this = &*self;
            cell_of.par_chunks_mut(POINT_CHUNK).zip(points.par_chunks(POINT_CHUNK)).for_each(|(out, pts)| {
                // The AVX2 copy rounds with one instruction where baseline x86-64 calls floor().
                rmi_par::cpu::hot(
                    #[inline(always)]
                    || {
                        for (o, p) in out.iter_mut().zip(pts) {
                            *o = this.cell_index(p) as u32;
                        }
                    },
                )
            });
        }
        self.cell_of = cell_of;
        for &c in &self.cell_of {
            self.cell_start[c as usize + 1] += 1;
        }
        for c in 0..ncell {
            self.cell_start[c + 1] += self.cell_start[c];
        }
        self.sorted_idx.clear();
        self.sorted_idx.resize(points.len(), 0);
        for c in &mut self.soa {
            c.clear();
            c.resize(points.len() + SOA_PAD, 0.0);
        }
        self.scatter(points);
    }

    /// Stable counting-sort scatter: points of one cell stay in index order (deterministic
    /// lists). The cells are split into [`SCATTER_PARTS`] ranges of about equal point counts;
    /// each range owns its contiguous block of slots and reads all cell numbers, writing only
    /// its own points, so the result does not depend on how many threads run the parts.
    fn scatter(&mut self, points: &[Vector3<f64>]) {
        let n = points.len();
        let ncell = self.cell_start.len() - 1;
        let starts = &self.cell_start;
        let cuts: Vec<usize> = (0..=SCATTER_PARTS)
            .map(|k| {
                if k == SCATTER_PARTS {
                    ncell
                } else {
                    starts.partition_point(|&s| (s as usize) < k * n / SCATTER_PARTS)
                }
            })
            .collect();
        // Disjoint slot blocks, one per part, cut from the front of each output array.
        let mut blocks = Vec::with_capacity(SCATTER_PARTS);
        let (mut idx, [mut sx, mut sy, mut sz]) = (&mut self.sorted_idx[..], self.soa.each_mut().map(|c| &mut c[..n]));
        for k in 0..SCATTER_PARTS {
            let len = (starts[cuts[k + 1]] - starts[cuts[k]]) as usize;
            let (i0, i1) = idx.split_at_mut(len);
            let (x0, x1) = sx.split_at_mut(len);
            let (y0, y1) = sy.split_at_mut(len);
            let (z0, z1) = sz.split_at_mut(len);
            blocks.push((cuts[k]..cuts[k + 1], i0, x0, y0, z0));
            (idx, sx, sy, sz) = (i1, x1, y1, z1);
        }
        let cell_of = &self.cell_of;
        blocks.into_par_iter().for_each(|(cells, idx, sx, sy, sz)| {
            let base = starts[cells.start];
            let mut fill: Vec<u32> = starts[cells.clone()].iter().map(|s| s - base).collect();
            for (i, &c) in cell_of.iter().enumerate() {
                let c = c as usize;
                if !cells.contains(&c) {
                    continue;
                }
                let slot = fill[c - cells.start] as usize;
                fill[c - cells.start] += 1;
                idx[slot] = i as u32;
                (sx[slot], sy[slot], sz[slot]) = (points[i].x, points[i].y, points[i].z);
            }
        });
    }

    /// Position of the point in sorted slot `slot`.
    #[inline(always)]
    pub fn point(&self, slot: usize) -> Vector3<f64> {
        Vector3::new(self.soa[0][slot], self.soa[1][slot], self.soa[2][slot])
    }

    /// Identifies the points of the last build: equal ids mean the same sorted points (a
    /// clone keeps its original's id). 0 before the first build.
    #[inline]
    pub fn build_id(&self) -> u64 {
        self.build_id
    }

    /// Sorted positions by coordinate, each array [`SOA_PAD`] entries longer than the point set.
    #[inline(always)]
    pub fn soa(&self) -> [&[f64]; 3] {
        [&self.soa[0], &self.soa[1], &self.soa[2]]
    }

    /// Computes the per-cell "has candidates" flags that let [`Grid::for_each_run`] skip
    /// queries with nothing around them; valid until the next build.
    pub fn mark_near(&mut self) {
        let [nx, ny, nz] = self.dims;
        let k = self.reach;
        self.near.clear();
        self.near.resize(nx * ny * nz, false);
        for z in 0..nz {
            for y in 0..ny {
                for x in 0..nx {
                    let c = x + nx * (y + ny * z);
                    if self.cell_start[c] == self.cell_start[c + 1] {
                        continue;
                    }
                    for zz in z.saturating_sub(k)..=(z + k).min(nz - 1) {
                        for yy in y.saturating_sub(k)..=(y + k).min(ny - 1) {
                            let row = nx * (yy + ny * zz);
                            for xx in x.saturating_sub(k)..=(x + k).min(nx - 1) {
                                self.near[row + xx] = true;
                            }
                        }
                    }
                }
            }
        }
    }

    #[inline(always)]
    fn coord(&self, p: &Vector3<f64>) -> [usize; 3] {
        let mut c = [0usize; 3];
        for k in 0..3 {
            let f = ((p[k] - self.origin[k]) * self.inv_cell).floor();
            c[k] = if f.is_nan() || f < 0.0 { 0 } else { (f as usize).min(self.dims[k] - 1) };
        }
        c
    }

    /// Linear cell index of a position (clamped into the grid).
    #[inline(always)]
    pub fn cell_index(&self, p: &Vector3<f64>) -> usize {
        self.linear(self.coord(p))
    }

    #[inline(always)]
    fn linear(&self, c: [usize; 3]) -> usize {
        c[0] + self.dims[0] * (c[1] + self.dims[1] * c[2])
    }

    /// Calls `f(sorted_slot)` for every point in the 27 cells around `p`, in a fixed order.
    #[inline]
    pub fn for_each_candidate(&self, p: &Vector3<f64>, mut f: impl FnMut(usize)) {
        self.for_each_run(p, |lo, hi| {
            for slot in lo..hi {
                f(slot);
            }
        });
    }

    /// Calls `f(lo, hi)` for the 9 contiguous sorted-slot runs covering the 27 cells around `p`.
    // Always inlined: the caller's loop body lives in `f`, and must end up in the caller's
    // (possibly AVX2-dispatched, see `rmi_par::cpu`) code.
    #[inline(always)]
    pub fn for_each_run(&self, p: &Vector3<f64>, mut f: impl FnMut(usize, usize)) {
        if self.sorted_idx.is_empty() {
            return;
        }
        let c = self.coord(p);
        if !self.near.is_empty() && !self.near[self.linear(c)] {
            return;
        }
        let k = self.reach;
        let x0 = c[0].saturating_sub(k);
        let x1 = (c[0] + k).min(self.dims[0] - 1);
        for z in c[2].saturating_sub(k)..=(c[2] + k).min(self.dims[2] - 1) {
            for y in c[1].saturating_sub(k)..=(c[1] + k).min(self.dims[1] - 1) {
                let row = self.dims[0] * (y + self.dims[1] * z);
                f(self.cell_start[row + x0] as usize, self.cell_start[row + x1 + 1] as usize);
            }
        }
    }
}

/// Axis-aligned bounds of a point set, expanded by `margin` (m). Empty sets give a unit box.
pub fn bounds(points: &[Vector3<f64>], margin: f64) -> (Vector3<f64>, Vector3<f64>) {
    if points.is_empty() {
        return (Vector3::zeros(), Vector3::repeat(1.0));
    }
    let mut lo = Vector3::repeat(f64::INFINITY);
    let mut hi = Vector3::repeat(f64::NEG_INFINITY);
    for p in points {
        if p.iter().all(|c| c.is_finite()) {
            lo = lo.inf(p);
            hi = hi.sup(p);
        }
    }
    if !lo[0].is_finite() {
        return (Vector3::zeros(), Vector3::repeat(1.0));
    }
    (lo.add_scalar(-margin), hi.add_scalar(margin))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn candidates_include_all_neighbours() {
        let mut pts = Vec::new();
        let mut s = 12345u64;
        for _ in 0..2000 {
            let mut r = || {
                s = s.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
                (s >> 11) as f64 / (1u64 << 53) as f64
            };
            pts.push(Vector3::new(r(), r(), r() * 0.5));
        }
        let h = 0.07;
        let (lo, hi) = bounds(&pts, 0.0);
        let mut g = Grid::default();
        for reach in 1..=3 {
            g.build_with(&pts, lo, hi, h, reach);
            for (i, p) in pts.iter().enumerate().step_by(37) {
                let mut found = Vec::new();
                g.for_each_candidate(p, |slot| {
                    if (g.point(slot) - p).norm() < h {
                        found.push(g.sorted_idx[slot] as usize);
                    }
                });
                found.sort();
                let brute: Vec<usize> = (0..pts.len()).filter(|&j| (pts[j] - p).norm() < h).collect();
                assert_eq!(found, brute, "point {i}, reach {reach}");
            }
        }
    }

    /// The split scatter gives the order of a serial stable sort by cell (index order within a
    /// cell), for point sets where some of its four parts are empty or hold one crowded cell,
    /// and on 1 and 2 threads.
    #[test]
    fn sorted_order_is_a_stable_sort_by_cell() {
        let mut s = 777u64;
        let mut r = || {
            s = s.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            (s >> 11) as f64 / (1u64 << 53) as f64
        };
        let spread: Vec<Vector3<f64>> = (0..3000).map(|_| Vector3::new(r(), r(), 0.3 * r())).collect();
        let crowded: Vec<Vector3<f64>> = (0..500)
            .map(|i| if i % 5 == 0 { Vector3::new(0.9, 0.9, 0.9) } else { Vector3::new(0.01, 0.02, 0.03) })
            .collect();
        for pts in [spread, crowded, vec![Vector3::new(0.5, 0.5, 0.5)], Vec::new()] {
            let (lo, hi) = bounds(&pts, 0.05);
            for threads in [1, 2] {
                let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap();
                let mut g = Grid::default();
                pool.install(|| g.build_with(&pts, lo, hi, 0.05, 2));
                let mut want: Vec<u32> = (0..pts.len() as u32).collect();
                want.sort_by_key(|&i| g.cell_index(&pts[i as usize]));
                assert_eq!(g.sorted_idx, want, "{} points, {threads} threads", pts.len());
                for (slot, &i) in g.sorted_idx.iter().enumerate() {
                    assert_eq!(g.point(slot), pts[i as usize]);
                }
            }
        }
    }

    #[test]
    fn near_flags_skip_only_empty_neighbourhoods() {
        // Sparse points on two faces of a box (like walls), dense queries everywhere.
        let mut pts = Vec::new();
        for i in 0..40 {
            for j in 0..40 {
                pts.push(Vector3::new(i as f64 * 0.025, j as f64 * 0.025, 0.0));
                pts.push(Vector3::new(0.0, i as f64 * 0.025, j as f64 * 0.025));
            }
        }
        let h = 0.07;
        let (lo, hi) = bounds(&pts, h);
        let mut g = Grid::default();
        g.build(&pts, lo, hi, h);
        g.mark_near();
        let mut skipped = 0;
        for q in 0..3000 {
            let f = |k: u64| ((q * 7919 + k * 104729) % 1000) as f64 / 1000.0 - 0.1;
            let p = Vector3::new(f(1), f(2), f(3));
            let mut found = Vec::new();
            g.for_each_candidate(&p, |slot| {
                if (g.point(slot) - p).norm() < h {
                    found.push(g.sorted_idx[slot] as usize);
                }
            });
            found.sort();
            let brute: Vec<usize> = (0..pts.len()).filter(|&j| (pts[j] - p).norm() < h).collect();
            assert_eq!(found, brute, "query {p:?}");
            let mut any = false;
            g.for_each_run(&p, |_, _| any = true);
            skipped += usize::from(!any);
        }
        assert!(skipped > 1000, "the flags should skip most interior queries, skipped {skipped}");
    }
}
