//! Two-level (additive coarse-grid) preconditioner of the implicit CG.
//!
//! Under block Jacobi the stiff skeleton leaves the CG about ten iterations per decade of
//! residual: the smooth modes, in which neighbouring particles (skeleton and the pore water
//! dragged along with it) move together, have almost no elastic or drag energy next to the
//! diagonal blocks, so their eigenvalues sit near `1 / (1 + dt^2 k / m)`. The coarse space
//! holds exactly those modes: the dynamic particles are grouped into aggregates (cubic cells
//! of the grid), and an aggregate's translations are three coarse unknowns. Pinned and
//! contact-constrained particles stay out of every aggregate, so the coarse vectors satisfy
//! the constraints as they are. With `Z` the piecewise-constant prolongation,
//! `E = Z^T A Z` the Galerkin coarse matrix and `y = M^-1 r` the block-Jacobi step, the
//! preconditioner is the additive two-level one (the "AD" of Tang, Nabben, Vuik and
//! Erlangga 2009, "Comparison of two-level preconditioners derived from deflation, domain
//! decomposition and multigrid methods"):
//!
//! `z = y + Z E^-1 Z^T r`.
//!
//! It is symmetric and positive definite for any symmetric positive definite `E`, so it needs
//! neither a special starting guess nor `A Z` itself: `E` is assembled straight from the
//! operator's terms, and since an older `E` keeps the preconditioner valid, one serves
//! several steps ([`CoarseMatrix`]). An iteration adds a sum over each aggregate's members
//! and one envelope solve ([`Skyline`]). The deflation variants (A-DEF2), which keep the
//! residual orthogonal to the coarse space, save a few per cent of the iterations here but
//! need the rows of `A Z` every step and a product with them every iteration, which cost
//! more than those iterations (docs/benchmark-history.md, "The two-level preconditioner
//! applied additively, its coarse matrix kept for ten steps").

use crate::solver::linalg::skyline::Skyline;
use nalgebra::{Matrix3, Vector3};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use std::collections::HashMap;
use std::ops::AddAssign;

/// Aggregate index of a particle outside every aggregate (pinned skeleton).
pub const NONE: u32 = u32::MAX;

/// Particles grouped into aggregates (grid cells); ids in order of first appearance.
#[derive(Clone, Debug, Default)]
pub struct Aggregates {
    /// Aggregate of each dynamic particle, [`NONE`] for particles left out.
    pub of: Vec<u32>,
    start: Vec<u32>,
    members: Vec<u32>,
}

impl Aggregates {
    /// Groups the particles with `included(a)` by the cubic cell (`cell` m wide) holding them.
    pub fn build(x: &[Vector3<f64>], cell: f64, included: impl Fn(usize) -> bool) -> Aggregates {
        let mut ids: HashMap<[i64; 3], u32> = HashMap::new();
        let mut of = vec![NONE; x.len()];
        for (a, xa) in x.iter().enumerate() {
            if included(a) {
                let key = [0, 1, 2].map(|k| (xa[k] / cell).floor() as i64);
                let next = ids.len() as u32;
                of[a] = *ids.entry(key).or_insert(next);
            }
        }
        let n = ids.len();
        Aggregates::from_ids(of, n)
    }

    /// Aggregates from each particle's id (`0..n`, [`NONE`] outside).
    pub fn from_ids(of: Vec<u32>, n: usize) -> Aggregates {
        let (start, members) = group(n, of.iter().enumerate().filter(|e| *e.1 != NONE).map(|(a, &i)| (i, a as u32)));
        Aggregates { of, start, members }
    }

    /// Number of aggregates.
    pub fn len(&self) -> usize {
        self.start.len().saturating_sub(1)
    }

    /// Whether there is no aggregate.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Particles of aggregate `i`, in increasing order.
    pub fn members(&self, i: usize) -> &[u32] {
        &self.members[self.start[i] as usize..self.start[i + 1] as usize]
    }
}

/// CSR grouping of `(group, item)` pairs (`n` groups), items kept in the order given: a
/// counting sort, so the result is deterministic.
fn group<I: Copy + Default>(n: usize, pairs: impl Iterator<Item = (u32, I)> + Clone) -> (Vec<u32>, Vec<I>) {
    let mut start = vec![0u32; n + 1];
    for (g, _) in pairs.clone() {
        start[g as usize + 1] += 1;
    }
    for i in 0..n {
        start[i + 1] += start[i];
    }
    let mut fill = start.clone();
    let mut items = vec![I::default(); start[n] as usize];
    for (g, item) in pairs {
        items[fill[g as usize] as usize] = item;
        fill[g as usize] += 1;
    }
    (start, items)
}

/// Sparse block rows: per row a list of (column, block), built in parallel; the coarse
/// strains are one (aggregate, vector) list per solid.
#[derive(Clone, Debug)]
pub struct BlockRows<T = Matrix3<f64>> {
    start: Vec<u32>,
    col: Vec<u32>,
    blk: Vec<T>,
}

impl<T> Default for BlockRows<T> {
    fn default() -> Self {
        BlockRows { start: vec![0], col: Vec::new(), blk: Vec::new() }
    }
}

impl<T: Copy + AddAssign + Send + Sync> BlockRows<T> {
    /// Builds the rows of particles `0..n` in parallel: `row(a, out)` pushes particle `a`'s
    /// blocks into `out` (a column may repeat; repeats are summed in push order). Each chunk
    /// runs through [`rmi_par::cpu::hot`]: pass `row` marked `#[inline(always)]`.
    pub fn build<F>(n: usize, row: F) -> BlockRows<T>
    where
        F: Fn(usize, &mut RowBuilder<T>) + Sync,
    {
        const CHUNK: usize = 256;
        let chunks: Vec<BlockRows<T>> = (0..n.div_ceil(CHUNK))
            .into_par_iter()
            .map(|c| {
                let mut out = BlockRows::default();
                let mut b = RowBuilder::new();
                rmi_par::cpu::hot(
                    #[inline(always)]
                    || {
                        for a in c * CHUNK..((c + 1) * CHUNK).min(n) {
                            b.clear();
                            row(a, &mut b);
                            out.col.extend_from_slice(&b.cols);
                            out.blk.extend_from_slice(&b.blks);
                            out.start.push(out.col.len() as u32);
                        }
                    },
                );
                out
            })
            .collect();
        let mut rows = BlockRows::default();
        for c in chunks {
            let base = rows.col.len() as u32;
            rows.start.extend(c.start[1..].iter().map(|s| s + base));
            rows.col.extend(c.col);
            rows.blk.extend(c.blk);
        }
        rows
    }

    /// Blocks of row `a`.
    #[inline(always)]
    pub fn row(&self, a: usize) -> impl Iterator<Item = (u32, &T)> {
        let r = self.start[a] as usize..self.start[a + 1] as usize;
        self.col[r.clone()].iter().copied().zip(&self.blk[r])
    }

    /// Number of stored blocks.
    #[cfg(test)]
    pub fn blocks(&self) -> usize {
        self.col.len()
    }
}

/// One row under construction: blocks summed per column, in order of first appearance.
/// `slot` maps a column to its place in the row ([`NONE`] when absent), so that adding a
/// block is a lookup rather than a scan of the row; [`RowBuilder::clear`] resets only the
/// entries the row used.
pub struct RowBuilder<T = Matrix3<f64>> {
    cols: Vec<u32>,
    blks: Vec<T>,
    slot: Vec<u32>,
}

impl<T: Copy + AddAssign> RowBuilder<T> {
    fn new() -> Self {
        RowBuilder { cols: Vec::new(), blks: Vec::new(), slot: Vec::new() }
    }

    /// Adds `m` to the block of column `j` ([`NONE`] columns are ignored).
    #[inline(always)]
    pub fn add(&mut self, j: u32, m: T) {
        if j == NONE {
            return;
        }
        let ju = j as usize;
        if ju >= self.slot.len() {
            self.slot.resize(ju + 1, NONE);
        }
        match self.slot[ju] {
            NONE => {
                self.slot[ju] = self.cols.len() as u32;
                self.cols.push(j);
                self.blks.push(m);
            }
            k => self.blks[k as usize] += m,
        }
    }

    /// Empties the row, keeping its buffers.
    fn clear(&mut self) {
        for &c in &self.cols {
            self.slot[c as usize] = NONE;
        }
        self.cols.clear();
        self.blks.clear();
    }

    /// Replaces every block `m` by `f(m)`.
    pub fn map(&mut self, f: impl Fn(&T) -> T) {
        for b in &mut self.blks {
            *b = f(b);
        }
    }
}

/// A coarse matrix as assembled: the step it was assembled in (steps completed before it),
/// each particle's aggregate (`u32::MAX` outside; ids `0..rows.len()`) and the block rows of
/// `E = Z^T A Z` (each column once per row). What a snapshot keeps of the coarse level.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct CoarseMatrix {
    /// Steps completed when it was assembled.
    pub step: u64,
    /// Aggregate of each dynamic particle.
    pub of: Vec<u32>,
    /// Block rows of `E`: (aggregate, 3x3 block).
    pub rows: Vec<Vec<(u32, Matrix3<f64>)>>,
}

impl CoarseMatrix {
    /// Whether its aggregate ids and columns are in range for `n` particles, each column once
    /// per row, and every block finite; the problem in words otherwise (a snapshot's matrix is
    /// checked before it is factored).
    pub fn check(&self, n: usize) -> Result<(), String> {
        let m = self.rows.len();
        if self.of.len() != n {
            return Err(format!("its aggregates cover {} particles, expected {n}", self.of.len()));
        }
        if self.of.iter().any(|&i| i != NONE && i as usize >= m) {
            return Err(format!("a particle's aggregate is outside 0..{m}"));
        }
        for row in &self.rows {
            if row.iter().any(|(j, b)| *j as usize >= m || !b.iter().all(|x| x.is_finite())) {
                return Err(format!("a block is non-finite or its column outside 0..{m}"));
            }
            let mut cols: Vec<u32> = row.iter().map(|e| e.0).collect();
            cols.sort_unstable();
            if cols.windows(2).any(|w| w[0] == w[1]) {
                return Err("a row holds a column twice".into());
            }
        }
        Ok(())
    }
}

/// The coarse level: the aggregates and the factor of `E = Z^T A Z`, with the block rows it
/// was factored from and the step they were assembled in (what [`TwoLevel::matrix`] saves).
#[derive(Clone, Debug, Default)]
pub struct TwoLevel {
    agg: Aggregates,
    factor: Skyline,
    rows: Vec<Vec<(u32, Matrix3<f64>)>>,
    step: u64,
}

impl TwoLevel {
    /// Factors `E` from its block rows over the aggregates `agg` (each column once per row),
    /// symmetrised first: `A` is symmetric, `E` as assembled only up to round-off. `step`:
    /// steps completed when the rows were assembled.
    pub fn new(agg: Aggregates, rows: Vec<Vec<(u32, Matrix3<f64>)>>, step: u64) -> TwoLevel {
        let sym: Vec<Vec<(u32, Matrix3<f64>)>> = rows
            .iter()
            .enumerate()
            .map(|(i, row)| {
                row.iter()
                    .map(|(j, m)| {
                        let back = rows[*j as usize].iter().find(|e| e.0 == i as u32).map(|e| e.1.transpose());
                        (*j, back.map_or(*m, |t| 0.5 * (m + t)))
                    })
                    .collect()
            })
            .collect();
        let factor = Skyline::factor(&sym);
        TwoLevel { agg, factor, rows, step }
    }

    /// The coarse level of a saved matrix, which must pass [`CoarseMatrix::check`].
    pub fn from_matrix(m: CoarseMatrix) -> TwoLevel {
        let agg = Aggregates::from_ids(m.of, m.rows.len());
        TwoLevel::new(agg, m.rows, m.step)
    }

    /// The matrix it was factored from, with its aggregates and step (for a snapshot).
    pub fn matrix(&self) -> CoarseMatrix {
        CoarseMatrix { step: self.step, of: self.agg.of.clone(), rows: self.rows.clone() }
    }

    /// Steps completed when its matrix was assembled.
    pub fn step(&self) -> u64 {
        self.step
    }

    /// The aggregates.
    pub fn aggregates(&self) -> &Aggregates {
        &self.agg
    }

    /// Follows a permutation of the particles (`perm[new] = old` over the first `perm.len()`
    /// particles): members move with their particles; `E` is unchanged.
    pub fn permute(&mut self, perm: &[usize]) {
        let mut of = self.agg.of.clone();
        for (new, &old) in perm.iter().enumerate() {
            of[new] = self.agg.of[old];
        }
        self.agg = Aggregates::from_ids(of, self.rows.len());
    }

    /// `c = E^-1 Z^T r`, three entries per aggregate; `r` already filtered. Each aggregate sums
    /// its members in order, so the result does not depend on the thread count.
    pub fn coarse_correction(&self, r: &[Vector3<f64>]) -> Vec<f64> {
        let mut g = vec![0.0; 3 * self.agg.len()];
        g.par_chunks_mut(3).enumerate().for_each(|(i, gi)| {
            let sum = self.agg.members(i).iter().fold(Vector3::zeros(), |acc, &a| acc + r[a as usize]);
            gi.copy_from_slice(sum.as_slice());
        });
        self.factor.solve(&mut g);
        g
    }

    /// `(Z c)_a`: the coarse value of `a`'s aggregate (zero outside the aggregates).
    #[inline(always)]
    pub fn prolong(&self, a: usize, c: &[f64]) -> Vector3<f64> {
        match self.agg.of[a] {
            NONE => Vector3::zeros(),
            i => Vector3::new(c[3 * i as usize], c[3 * i as usize + 1], c[3 * i as usize + 2]),
        }
    }
}

/// The block rows of a coarse matrix, built in parallel: `row(i, out, scratch)` pushes the
/// blocks of aggregate `i`'s row into `out` (a column may repeat; repeats are summed in push
/// order), with `scratch` a worker's own work space from `scratch()`. A row depends only on
/// its own pushes, so the result does not depend on the thread count.
pub fn coarse_rows<S, F>(n: usize, scratch: impl Fn() -> S + Sync + Send, row: F) -> Vec<Vec<(u32, Matrix3<f64>)>>
where
    F: Fn(usize, &mut RowBuilder, &mut S) + Sync,
{
    (0..n)
        .into_par_iter()
        .map_init(
            || (RowBuilder::new(), scratch()),
            |(b, s), i| {
                b.clear();
                row(i, b, s);
                b.cols.iter().copied().zip(b.blks.iter().copied()).collect()
            },
        )
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn aggregates_group_by_cell_and_skip_excluded_particles() {
        let x: Vec<Vector3<f64>> = (0..10).map(|i| Vector3::new(0.3 * i as f64, 0.05, -0.05)).collect();
        let agg = Aggregates::build(&x, 1.0, |a| a != 4);
        // Cells x in [0,1): 0..=3, [1,2): 5,6 (4 excluded), [2,3): 7..=9.
        assert_eq!(agg.len(), 3);
        assert_eq!(agg.members(0), &[0, 1, 2, 3]);
        assert_eq!(agg.members(1), &[5, 6]);
        assert_eq!(agg.members(2), &[7, 8, 9]);
        assert_eq!(agg.of[4], NONE);
    }

    #[test]
    fn coarse_matrix_check_names_what_is_wrong() {
        let good = CoarseMatrix {
            step: 3,
            of: vec![0, NONE, 1],
            rows: vec![
                vec![(0, Matrix3::identity()), (1, -Matrix3::identity())],
                vec![(1, Matrix3::identity()), (0, -Matrix3::identity())],
            ],
        };
        assert_eq!(good.check(3), Ok(()));
        assert!(good.check(4).unwrap_err().contains("expected 4"));
        let mut bad = good.clone();
        bad.of[1] = 2;
        assert!(bad.check(3).unwrap_err().contains("aggregate"));
        let mut bad = good.clone();
        bad.rows[1].push((0, Matrix3::identity()));
        assert!(bad.check(3).unwrap_err().contains("twice"));
        let mut bad = good.clone();
        bad.rows[0][1].1[(2, 2)] = f64::NAN;
        assert!(bad.check(3).unwrap_err().contains("non-finite"));
        let mut bad = good;
        bad.rows[0][0].0 = 5;
        assert!(bad.check(3).unwrap_err().contains("outside"));
    }

    #[test]
    fn row_builder_sums_repeated_columns_in_order() {
        let rows: BlockRows = BlockRows::build(600, |a, b| {
            b.add((a % 3) as u32, Matrix3::identity() * a as f64);
            b.add(NONE, Matrix3::identity());
            b.add((a % 3) as u32, Matrix3::identity());
            b.add(7, Matrix3::identity() * 2.0);
        });
        assert_eq!(rows.blocks(), 1200);
        let r: Vec<_> = rows.row(599).collect();
        assert_eq!(r.len(), 2);
        assert_eq!(r[0].0, 2);
        assert_eq!(r[0].1[(0, 0)], 600.0);
        assert_eq!(r[1].0, 7);
    }
}
