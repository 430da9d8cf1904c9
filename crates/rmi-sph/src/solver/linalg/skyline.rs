//! Envelope (skyline) Cholesky factorisation of a small sparse symmetric matrix made of 3x3
//! blocks, in reverse Cuthill-McKee order: the coarse solve of the two-level preconditioner.
//!
//! The coarse matrix of a sponge is a 3D grid graph of a few hundred blocks; reverse
//! Cuthill-McKee keeps its envelope to about one cross-section, so the factorisation costs
//! `n b^2` with b the cross-section's size instead of `n^3`. Everything is sequential and in a
//! fixed order, so the result does not depend on the thread count.
//!
//! The matrix may be positive *semi*-definite: a coarse direction that no fine vector carries
//! (an aggregate whose particles are all held along one contact normal) gives a zero pivot.
//! Such a degree of freedom is dropped (its solution component is zero), which is exact for
//! the consistent right-hand sides the preconditioner produces.

use nalgebra::Matrix3;

/// A pivot below this fraction of its original diagonal entry counts as zero.
const PIVOT_TOLERANCE: f64 = 1e-10;

/// Cholesky factor `L` (with `P A P^T = L L^T`) in row-wise envelope storage.
#[derive(Clone, Debug, Default)]
pub struct Skyline {
    /// Block position in the factor of each original block.
    pos: Vec<u32>,
    /// First stored column of each row (scalar index, factor order).
    first: Vec<u32>,
    /// Offset of each row's entries in `val` (length n + 1); the last entry is the diagonal.
    start: Vec<usize>,
    val: Vec<f64>,
    /// Degrees of freedom dropped for a zero pivot.
    dead: Vec<bool>,
}

impl Skyline {
    /// Factors the symmetric block matrix whose block row `i` is `rows[i]`: (column block,
    /// 3x3 block) pairs, both triangles present, at most one entry per column block.
    pub fn factor(rows: &[Vec<(u32, Matrix3<f64>)>]) -> Skyline {
        let nb = rows.len();
        let order = reverse_cuthill_mckee(rows);
        let mut pos = vec![0u32; nb];
        for (p, &i) in order.iter().enumerate() {
            pos[i as usize] = p as u32;
        }
        // Envelope: a row's first column is that of the lowest-numbered block it touches.
        let n = 3 * nb;
        let mut first = vec![0u32; n];
        for (i, row) in rows.iter().enumerate() {
            let p = pos[i] as usize;
            let lo = row.iter().map(|(j, _)| pos[*j as usize] as usize).fold(p, usize::min);
            for t in 0..3 {
                first[3 * p + t] = 3 * lo as u32;
            }
        }
        let mut start = Vec::with_capacity(n + 1);
        start.push(0usize);
        for i in 0..n {
            start.push(start[i] + i + 1 - first[i] as usize);
        }
        let mut val = vec![0.0; start[n]];
        for (i, row) in rows.iter().enumerate() {
            let p = pos[i] as usize;
            for (j, m) in row {
                let q = pos[*j as usize] as usize;
                if q > p {
                    continue;
                }
                for t in 0..3 {
                    let r = 3 * p + t;
                    for u in 0..3 {
                        let c = 3 * q + u;
                        if c <= r {
                            val[start[r] + c - first[r] as usize] = m[(t, u)];
                        }
                    }
                }
            }
        }
        let mut dead = vec![false; n];
        for i in 0..n {
            let fi = first[i] as usize;
            let (done, rest) = val.split_at_mut(start[i]);
            let row_i = &mut rest[..start[i + 1] - start[i]];
            for j in fi..i {
                let k = j - fi;
                if dead[j] {
                    row_i[k] = 0.0;
                    continue;
                }
                let fj = first[j] as usize;
                let k0 = fi.max(fj);
                let row_j = &done[start[j]..start[j + 1]];
                let s = row_i[k] - dot(&row_i[k0 - fi..k], &row_j[k0 - fj..j - fj]);
                row_i[k] = s / row_j[j - fj];
            }
            let diag = row_i[i - fi];
            let d = diag - dot(&row_i[..i - fi], &row_i[..i - fi]);
            if diag <= 0.0 || d <= PIVOT_TOLERANCE * diag {
                dead[i] = true;
                row_i.iter_mut().for_each(|v| *v = 0.0);
                row_i[i - fi] = 1.0;
            } else {
                row_i[i - fi] = d.sqrt();
            }
        }
        Skyline { pos, first, start, val, dead }
    }

    /// Number of scalar unknowns.
    pub fn len(&self) -> usize {
        self.first.len()
    }

    /// Solves `A x = b` in place (`b` in the original block order, 3 entries per block).
    pub fn solve(&self, b: &mut [f64]) {
        let n = self.len();
        let mut y = vec![0.0; n];
        for (i, &p) in self.pos.iter().enumerate() {
            for t in 0..3 {
                y[3 * p as usize + t] = b[3 * i + t];
            }
        }
        for i in 0..n {
            if self.dead[i] {
                y[i] = 0.0;
                continue;
            }
            let fi = self.first[i] as usize;
            let row = &self.val[self.start[i]..self.start[i + 1]];
            let mut s = y[i];
            for m in fi..i {
                s -= row[m - fi] * y[m];
            }
            y[i] = s / row[i - fi];
        }
        for i in (0..n).rev() {
            if self.dead[i] {
                y[i] = 0.0;
                continue;
            }
            let fi = self.first[i] as usize;
            let row = &self.val[self.start[i]..self.start[i + 1]];
            let xi = y[i] / row[i - fi];
            y[i] = xi;
            for m in fi..i {
                y[m] -= row[m - fi] * xi;
            }
        }
        for (i, &p) in self.pos.iter().enumerate() {
            for t in 0..3 {
                b[3 * i + t] = y[3 * p as usize + t];
            }
        }
    }
}

/// Dot product in four interleaved partial sums (a fixed order, so the same bits on every run).
#[inline(always)]
fn dot(a: &[f64], b: &[f64]) -> f64 {
    let n = a.len().min(b.len());
    let (a, b) = (&a[..n], &b[..n]);
    let mut acc = [0.0f64; 4];
    let mut ca = a.chunks_exact(4);
    let mut cb = b.chunks_exact(4);
    for (x, y) in (&mut ca).zip(&mut cb) {
        for t in 0..4 {
            acc[t] += x[t] * y[t];
        }
    }
    let mut s = (acc[0] + acc[1]) + (acc[2] + acc[3]);
    for (x, y) in ca.remainder().iter().zip(cb.remainder()) {
        s += x * y;
    }
    s
}

/// Reverse Cuthill-McKee order of the block graph: breadth-first from a node of least
/// degree, neighbours by increasing degree (ties by index), each component in turn.
fn reverse_cuthill_mckee(rows: &[Vec<(u32, Matrix3<f64>)>]) -> Vec<u32> {
    let n = rows.len();
    let degree: Vec<usize> = rows.iter().map(|r| r.len()).collect();
    let mut by_degree: Vec<u32> = (0..n as u32).collect();
    by_degree.sort_by_key(|&i| (degree[i as usize], i));
    let mut seen = vec![false; n];
    let mut order = Vec::with_capacity(n);
    let mut next = Vec::new();
    for &root in &by_degree {
        if seen[root as usize] {
            continue;
        }
        seen[root as usize] = true;
        let mut head = order.len();
        order.push(root);
        while head < order.len() {
            let i = order[head] as usize;
            head += 1;
            next.clear();
            next.extend(rows[i].iter().map(|(j, _)| *j).filter(|&j| !seen[j as usize]));
            next.sort_by_key(|&j| (degree[j as usize], j));
            next.dedup();
            for &j in &next {
                seen[j as usize] = true;
                order.push(j);
            }
        }
    }
    order.reverse();
    order
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{DMatrix, DVector};

    /// A 3D grid Laplacian-like block matrix plus a mass term, with random-ish couplings.
    fn grid_matrix(nx: usize, ny: usize, nz: usize) -> Vec<Vec<(u32, Matrix3<f64>)>> {
        let id = |i: usize, j: usize, k: usize| (i + nx * (j + ny * k)) as u32;
        let mut rows: Vec<Vec<(u32, Matrix3<f64>)>> = vec![Vec::new(); nx * ny * nz];
        for k in 0..nz {
            for j in 0..ny {
                for i in 0..nx {
                    let a = id(i, j, k) as usize;
                    let mut diag = Matrix3::identity() * 0.1;
                    for (di, dj, dk) in [(1, 0, 0), (0, 1, 0), (0, 0, 1)] {
                        let (i2, j2, k2) = (i + di, j + dj, k + dk);
                        if i2 >= nx || j2 >= ny || k2 >= nz {
                            continue;
                        }
                        let b = id(i2, j2, k2) as usize;
                        let s = 1.0 + 0.1 * ((a * 7 + b * 3) % 5) as f64;
                        let d = nalgebra::Vector3::new(di as f64 + 0.2, dj as f64 + 0.1, dk as f64 + 0.3);
                        let m = s * (Matrix3::identity() + d * d.transpose());
                        rows[a].push((b as u32, -m));
                        rows[b].push((a as u32, -m));
                        diag += m;
                        let bb = rows[b].iter().position(|e| e.0 == b as u32);
                        match bb {
                            Some(p) => rows[b][p].1 += m,
                            None => rows[b].push((b as u32, m)),
                        }
                    }
                    match rows[a].iter().position(|e| e.0 == a as u32) {
                        Some(p) => rows[a][p].1 += diag,
                        None => rows[a].push((a as u32, diag)),
                    }
                }
            }
        }
        rows
    }

    fn dense(rows: &[Vec<(u32, Matrix3<f64>)>]) -> DMatrix<f64> {
        let n = 3 * rows.len();
        let mut a = DMatrix::zeros(n, n);
        for (i, row) in rows.iter().enumerate() {
            for (j, m) in row {
                for t in 0..3 {
                    for u in 0..3 {
                        a[(3 * i + t, 3 * *j as usize + u)] += m[(t, u)];
                    }
                }
            }
        }
        a
    }

    #[test]
    fn solves_a_grid_system_like_a_dense_cholesky() {
        let rows = grid_matrix(4, 3, 7);
        let a = dense(&rows);
        let b = DVector::from_fn(a.nrows(), |i, _| ((i * 37 % 11) as f64 - 5.0) / 3.0);
        let want = a.clone().cholesky().unwrap().solve(&b);
        let f = Skyline::factor(&rows);
        let mut x: Vec<f64> = b.iter().copied().collect();
        f.solve(&mut x);
        let err = (DVector::from_vec(x) - &want).norm() / want.norm();
        assert!(err < 1e-12, "relative error {err}");
        // The envelope of a 4 x 3 x 7 grid in RCM order is far below the dense triangle.
        assert!(f.val.len() < a.nrows() * a.nrows() / 4, "{} entries", f.val.len());
    }

    #[test]
    fn drops_a_direction_that_no_vector_carries() {
        // Block 1 has a zero row and column along y (an aggregate held along y): the system is
        // singular but consistent for right-hand sides without a y component there.
        let mut rows = grid_matrix(2, 1, 1);
        for (j, m) in rows[1].iter_mut() {
            m.set_row(1, &nalgebra::RowVector3::zeros());
            if *j == 1 {
                m.set_column(1, &nalgebra::Vector3::zeros());
            }
        }
        for (j, m) in rows[0].iter_mut() {
            if *j == 1 {
                m.set_column(1, &nalgebra::Vector3::zeros());
            }
        }
        let a = dense(&rows);
        let mut b = vec![1.0, -2.0, 0.5, 0.25, 0.0, 3.0];
        let f = Skyline::factor(&rows);
        let b0 = b.clone();
        f.solve(&mut b);
        assert_eq!(b[4], 0.0);
        let ax = &a * DVector::from_vec(b.clone());
        for i in 0..6 {
            assert!((ax[i] - b0[i]).abs() < 1e-12, "row {i}: {} vs {}", ax[i], b0[i]);
        }
    }
}
