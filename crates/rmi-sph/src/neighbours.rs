//! Per-step neighbour lists with cached kernel values.
//!
//! Lists are built once per step and reused by every solver pass (densities, CG, Jacobi).
//! They are stored in fixed-size chunks of particles so that they can be built in parallel
//! without a global prefix sum, and so that the layout does not depend on the thread count.
//! For each particle the fluid neighbours come first, then the solid ones (`split`).

use crate::grid::Grid;
use crate::kernel::CubicKernel;
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
    /// `grad W(x_a - x_b)`.
    pub g: Vec<Vector3<f64>>,
}

/// Neighbours of one particle: slices into its chunk.
pub struct Nb<'a> {
    /// Neighbour indices (fluid ones first).
    pub j: &'a [u32],
    /// Kernel values.
    pub w: &'a [f64],
    /// Kernel gradients (w.r.t. the centre particle).
    pub g: &'a [Vector3<f64>],
    /// Number of fluid neighbours at the front of the slices.
    pub n_fluid: usize,
}

/// Neighbour lists of all dynamic particles.
#[derive(Clone, Debug, Default)]
pub struct NeighbourLists {
    chunks: Vec<NbChunk>,
}

impl NeighbourLists {
    /// Neighbours of particle `a`.
    #[inline(always)]
    pub fn of(&self, a: usize) -> Nb<'_> {
        let c = &self.chunks[a / CHUNK];
        let l = a % CHUNK;
        let s = c.start[l] as usize;
        let e = c.start[l + 1] as usize;
        Nb { j: &c.j[s..e], w: &c.w[s..e], g: &c.g[s..e], n_fluid: (c.split[l] as usize) - s }
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
                    + c.g.capacity() * 24
                    + (c.start.capacity() + c.split.capacity()) * 4
            })
            .sum()
    }

    /// Rebuilds the lists of `queries` against the points in `grid`.
    ///
    /// `n_fluid_targets`: target indices below it count as fluid (sorted to the front).
    /// `exclude_self`: skip the pair (a, a) (when queries and targets are the same set).
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
        self.chunks.par_iter_mut().enumerate().for_each(|(ci, ch)| {
            crate::cpu::hot(
                #[inline(always)]
                || {
                    ch.start.clear();
                    ch.split.clear();
                    ch.j.clear();
                    ch.w.clear();
                    ch.g.clear();
                    let mut solid: Vec<(u32, f64, Vector3<f64>)> = Vec::with_capacity(64);
                    let lo = ci * CHUNK;
                    let hi = (lo + CHUNK).min(queries.len());
                    for a in lo..hi {
                        let xa = queries[a];
                        ch.start.push(ch.j.len() as u32);
                        solid.clear();
                        grid.for_each_run(
                            &xa,
                            #[inline(always)]
                            |lo, hi| {
                                let xs = &grid.sorted_x[lo..hi];
                                let ids = &grid.sorted_idx[lo..hi];
                                for (xb, &b) in xs.iter().zip(ids) {
                                    let d = xa - xb;
                                    let r2 = d.norm_squared();
                                    if r2 >= h2 || (exclude_self && b as usize == a) {
                                        continue;
                                    }
                                    let (w, gf) = kernel.w_and_grad_factor(r2.sqrt());
                                    let g = d * gf;
                                    if (b as usize) < n_fluid_targets {
                                        ch.j.push(b);
                                        ch.w.push(w);
                                        ch.g.push(g);
                                    } else {
                                        solid.push((b, w, g));
                                    }
                                }
                            },
                        );
                        ch.split.push(ch.j.len() as u32);
                        for &(b, w, g) in &solid {
                            ch.j.push(b);
                            ch.w.push(w);
                            ch.g.push(g);
                        }
                    }
                    ch.start.push(ch.j.len() as u32);
                },
            )
        });
    }
}
