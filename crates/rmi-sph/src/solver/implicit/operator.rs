//! The step's implicit system: the operator `A y = m y - dt F_lin(y)` at the current
//! positions, its per-pair coefficient cache, its rows (also applied to the coarse unit
//! translations), its block-Jacobi preconditioner and its coarse level.

use super::constraints::{constraint_field, stress_rows, Filter, VelocityConstraint};
use super::elasticity::{coarse_strain, coarse_stress_times, diagonal_block, linear_row};
use crate::config::{Preconditioner, ViscosityMode};
use crate::neighbourhood::lists::{Nb, CHUNK};
use crate::solver::ctx::Ctx;
use crate::solver::density::DensityFields;
use crate::solver::elasticity::ElasticFields;
use crate::solver::linalg::coarse::{coarse_rows, Aggregates, BlockRows, RowBuilder, TwoLevel, NONE};
use crate::solver::linalg::System;
use nalgebra::{Matrix3, Vector3};
use rayon::prelude::*;
use std::sync::Arc;

/// Free skeleton particles from which [`Preconditioner::Auto`] uses the two-level
/// preconditioner. Assembling and factoring `E` costs about three CG iterations, once every
/// `cg.coarse_steps` steps; the two-level CG saves about 40 % of the iterations on a fine
/// skeleton (16,000 particles at r = 2.5 mm) and also shortens the step of the medium
/// sponge at r = 5 mm (2,000), below this threshold, which is kept so that the results of
/// smaller scenes stay as they were (docs/benchmark-history.md, "Porous anchor: a two-level
/// preconditioner for the implicit CG" and "The two-level preconditioner applied additively,
/// its coarse matrix kept for ten steps"). Trials resolve `auto` to block Jacobi themselves
/// (`TrialConfig::sim_config`).
pub const TWO_LEVEL_MIN_SOLIDS: usize = 4000;

/// Settings resolved from the config.
#[derive(Clone, Copy, Debug)]
pub struct NonPressureSettings {
    /// Fluid kinematic viscosity (m^2/s).
    pub viscosity: f64,
    /// Fluid-boundary kinematic viscosity (m^2/s).
    pub boundary_viscosity: f64,
    /// Viscosity in the implicit solve or explicit.
    pub viscosity_mode: ViscosityMode,
    /// CG relative tolerance.
    pub tolerance: f64,
    /// CG iteration cap.
    pub max_iterations: u32,
    /// Preconditioner.
    pub preconditioner: Preconditioner,
    /// Warm start from the previous velocity change.
    pub warm_start: bool,
    /// Aggregate edge length of the two-level preconditioner (m).
    pub coarse_cell: f64,
    /// Steps one coarse matrix serves ([`crate::config::CgConfig::coarse_steps`]).
    pub coarse_steps: u32,
    /// Steps completed before this one: the age of a kept coarse matrix.
    pub step: u64,
}

/// What one step's [`Op`] hands to the next: the storage of its per-step caches (pair
/// coefficients, preconditioner blocks, adhesion forces; a fresh allocation of this size
/// each step costs more than filling it, as the allocator returns the memory to the system
/// and takes it back zeroed) and its coarse level, which serves
/// [`NonPressureSettings::coarse_steps`] steps. The coarse level is state: a snapshot keeps
/// it, so that a restored run continues with the same one.
#[derive(Debug, Default)]
pub struct OpBuffers {
    coef: Vec<Vec<[f64; 2]>>,
    minv: Vec<Matrix3<f64>>,
    adhesion_force: Vec<Vector3<f64>>,
    pub(crate) coarse: Option<Arc<TwoLevel>>,
}

/// The step's implicit system: the operator `A y = m y - dt F_lin(y)` at the current
/// positions, the skeleton-body contact constraints it honours and its block-Jacobi
/// preconditioner. Built once per step; [`solve`] and [`pressure_response`] share it.
pub struct Op<'a> {
    pub(super) c: &'a Ctx<'a>,
    pub(super) dens: &'a DensityFields,
    pub(super) ef: &'a ElasticFields,
    pub(super) s: &'a NonPressureSettings,
    /// Current densities (kg/m^3).
    pub(super) rho: Vec<f64>,
    /// Softening of the pair denominators `|x|^2 + eps`, `0.01 H^2` (m^2).
    pub(super) eps_h: f64,
    /// Whether the operator holds the fluid viscosity.
    pub(super) implicit_visc: bool,
    /// Per pair (aligned with the neighbour chunks): [Laplacian coefficient / (|x|^2 + eps)
    /// times the kernel's gradient factor g(|x|) (1/m^5), adhesion coefficient c_is]; the
    /// Laplacian one is viscosity (fluid-fluid) or drag.
    pub(super) coef: Vec<Vec<[f64; 2]>>,
    /// Contact constraints, and per particle the components they hold.
    pub(super) constraints: Vec<VelocityConstraint>,
    /// Per solid, whether a constrained row reads its linearised stress.
    pub(super) impulse_stress: Vec<bool>,
    pub(super) filters: Vec<Filter>,
    /// Inverted preconditioner blocks.
    pub(super) minv: Vec<Matrix3<f64>>,
    /// Position part of adhesion per particle, `-sum c_ab (x_a - x_b)` (N): a term of the
    /// implicit solve's right-hand side.
    pub(super) adhesion_force: Vec<Vector3<f64>>,
    /// Coarse level of the two-level preconditioner.
    pub(super) coarse: Option<Arc<TwoLevel>>,
}
impl<'a> Op<'a> {
    /// The system of this step: current densities, the per-pair coefficient cache, the
    /// constraint normals and the preconditioner.
    pub fn new(
        c: &'a Ctx<'a>,
        dens: &'a DensityFields,
        ef: &'a ElasticFields,
        s: &'a NonPressureSettings,
        constraints: Vec<VelocityConstraint>,
    ) -> Self {
        Self::with_buffers(c, dens, ef, s, constraints, OpBuffers::default())
    }

    /// [`Op::new`] with its caches in `buffers` (the last step's, from [`Op::into_buffers`]);
    /// every value is overwritten.
    pub fn with_buffers(
        c: &'a Ctx<'a>,
        dens: &'a DensityFields,
        ef: &'a ElasticFields,
        s: &'a NonPressureSettings,
        constraints: Vec<VelocityConstraint>,
        buffers: OpBuffers,
    ) -> Self {
        let nf = c.p.n_fluid;
        let rho = (0..c.p.len())
            .map(|a| dens.rho_ratio[a] * if a < nf { c.rho0_f } else { c.object(a).material.dry_density })
            .collect();
        let h = c.kernel.support();
        let mut op = Op {
            c,
            dens,
            ef,
            s,
            rho,
            eps_h: 0.01 * h * h,
            implicit_visc: s.viscosity_mode == ViscosityMode::Implicit && s.viscosity > 0.0,
            coef: buffers.coef,
            filters: constraint_field(c.p.len(), &constraints),
            impulse_stress: stress_rows(c, &constraints),
            constraints,
            minv: buffers.minv,
            adhesion_force: buffers.adhesion_force,
            coarse: None,
        };
        op.fill();
        let two_level = match s.preconditioner {
            Preconditioner::TwoLevel => true,
            Preconditioner::Auto => c.rest.fixed.iter().filter(|f| !**f).count() >= TWO_LEVEL_MIN_SOLIDS,
            _ => false,
        };
        if two_level {
            // The kept coarse level while it is young enough and no constrained particle sits
            // in one of its aggregates (the coarse space must lie in the admissible set).
            op.coarse = buffers
                .coarse
                .filter(|tl| {
                    s.step < tl.step() + u64::from(s.coarse_steps)
                        && tl.aggregates().of.len() == c.p.len()
                        && op.filters.iter().zip(&tl.aggregates().of).all(|(f, &i)| *f == Filter::Free || i == NONE)
                })
                .or_else(|| op.coarse_level().map(Arc::new));
        }
        op
    }

    /// The storage of the caches, for the next step's operator.
    pub fn into_buffers(self) -> OpBuffers {
        OpBuffers { coef: self.coef, minv: self.minv, adhesion_force: self.adhesion_force, coarse: self.coarse }
    }

    /// Aggregates and the factored coarse matrix (None without aggregates). Pinned and
    /// constrained particles stay out of the aggregates: the coarse space then lies in the
    /// constraints' admissible set without a filter on its columns.
    fn coarse_level(&self) -> Option<TwoLevel> {
        let c = self.c;
        let nf = c.p.n_fluid;
        let free = |a: usize| (a < nf || !c.rest.fixed[a - nf]) && self.filters[a] == Filter::Free;
        let agg = Aggregates::build(&c.p.x, self.s.coarse_cell, free);
        if agg.is_empty() {
            return None;
        }
        let rows = self.coarse_matrix(&agg);
        Some(TwoLevel::new(agg, rows, self.s.step))
    }

    /// The block rows of `E = Z^T A Z` over the aggregates `agg`, assembled from the
    /// operator's terms without forming `A Z`.
    pub(super) fn coarse_matrix(&self, agg: &Aggregates) -> Vec<Vec<(u32, Matrix3<f64>)>> {
        let strain = coarse_strain(self.c, self.ef, &agg.of);
        coarse_rows(
            agg.len(),
            || vec![NONE; self.c.p.n_solid()],
            |i, row, seen| self.coarse_matrix_row(i, agg, &strain, seen, row),
        )
    }

    /// Row `i` of `E = Z^T A Z`: the operator of [`Op::row`] between the unit translations of
    /// aggregate `i` and of every other (`e_k` on each of its particles), term by term:
    /// mass, pair terms, wall viscosity, hourglass springs and elasticity. Not filtered: `Z`
    /// is zero on constrained particles. `seen` (per solid) marks the solids already counted
    /// for this row.
    ///
    /// Elasticity enters through the coarse strains `h_rJ` of [`coarse_strain`]: a unit
    /// translation of aggregate `J` gives solid `r` the displacement gradient
    /// `dt e_k (x) h_rJ`, and the elastic energy pairs the strains of two translations at
    /// every solid, so the block is `sum_r (dt V_r0) P(h_rJ) h_rI` ([`coarse_stress_times`]
    /// is `P(h) w`) over the solids `r` whose strain translation `i` moves (its solids and
    /// their rest neighbours); for solids of `i` the terms of their own force and of their
    /// neighbours' cancel to that.
    fn coarse_matrix_row(
        &self,
        i: usize,
        agg: &Aggregates,
        strain: &BlockRows<Vector3<f64>>,
        seen: &mut [u32],
        row: &mut RowBuilder,
    ) {
        let c = self.c;
        let nf = c.p.n_fluid;
        let dt = c.dt;
        let of = &agg.of;
        let iu = i as u32;
        let rest = c.rest;
        // Terms on i's own translation are summed apart and added once.
        let mut own = Matrix3::zeros();
        for &a in agg.members(i) {
            let a = a as usize;
            own += Matrix3::from_diagonal_element(c.p.mass[a]);
            // Pair terms f_a = K_ab (u_a - u_b), K = lap g x x^T - dt c I. A pair within the
            // aggregate adds -dt K_ab and +dt K_ab to the same block: nothing, so it is
            // skipped (as are the hourglass springs within it below).
            let nb = c.nb.of(a);
            let cf = self.coefs(a);
            let xa = c.p.x[a];
            for k in self.coupled(a, &nb) {
                let b = nb.j[k] as usize;
                if of[b] == iu {
                    continue;
                }
                let [lap_g, adh] = cf[k];
                let xab = xa - c.p.x[b];
                let kab = lap_g * xab * xab.transpose() - Matrix3::from_diagonal_element(dt * adh);
                own -= dt * kab;
                row.add(of[b], dt * kab);
            }
            if c.p.is_fluid(a) && self.implicit_visc && self.s.boundary_viscosity > 0.0 {
                self.boundary_visc_terms(a, |_, coef, xak, g| own -= (dt * coef) * g * xak.transpose());
            }
            if a < nf {
                continue;
            }
            let s = a - nf;
            let edges = rest.start[s] as usize..rest.start[s + 1] as usize;
            for e in edges.clone() {
                let r = rest.nbr[e] as usize;
                if of[r] != iu {
                    let hk = dt * dt * rest.hg_k[e];
                    own += Matrix3::from_diagonal_element(hk);
                    row.add(of[r], Matrix3::from_diagonal_element(-hk));
                }
            }
            for r in std::iter::once(s).chain(rest.nbr[edges].iter().map(|&r| r as usize - nf)) {
                if seen[r] == iu {
                    continue;
                }
                seen[r] = iu;
                let Some(hi) = strain.row(r).find(|e| e.0 == iu).map(|e| *e.1) else { continue };
                let w = (dt * rest.v0[r]) * hi;
                for (j, h) in strain.row(r) {
                    row.add(j, coarse_stress_times(h, &w, self.ef.moduli[r], dt));
                }
            }
        }
        row.add(iu, own);
    }

    /// Pairs of `a` that carry implicit terms: for water, its skeleton neighbours (and its
    /// water neighbours when viscosity is implicit); for the skeleton, its water neighbours.
    #[inline(always)]
    pub(super) fn coupled(&self, a: usize, nb: &Nb) -> std::ops::Range<usize> {
        if !self.c.p.is_fluid(a) {
            0..nb.n_fluid
        } else if self.implicit_visc {
            0..nb.j.len()
        } else {
            nb.n_fluid..nb.j.len()
        }
    }
    /// Fills the per-pair coefficient cache (once per step; the operator runs every CG pass)
    /// and, with each particle's coefficients while its pairs are in cache, its
    /// preconditioner block and the position part of its adhesion: one pass over the pairs.
    fn fill(&mut self) {
        let c = self.c;
        let n = c.p.len();
        let sizes = c.nb.chunk_pairs();
        let factors = PairFactors::new(self);
        // Every value below is overwritten: the particles' blocks by index, the pairs' by
        // appending to emptied chunks.
        let mut minv = std::mem::take(&mut self.minv);
        let mut adhesion_force = std::mem::take(&mut self.adhesion_force);
        let mut coef = std::mem::take(&mut self.coef);
        minv.resize(n, Matrix3::zeros());
        adhesion_force.resize(n, Vector3::zeros());
        coef.resize_with(sizes.len(), Vec::new);
        let this: &Op = self;
        minv.par_chunks_mut(CHUNK)
            .zip(adhesion_force.par_chunks_mut(CHUNK))
            .zip(coef.par_iter_mut())
            .enumerate()
            .for_each(|(ci, ((minv, adh), out))| {
                let lo = ci * CHUNK;
                out.clear();
                out.reserve(sizes[ci]);
                rmi_par::cpu::hot(
                    #[inline(always)]
                    || {
                        for a in lo..(lo + CHUNK).min(n) {
                            let start = out.len();
                            this.pair_coefficients(a, &factors, out);
                            let cf = &out[start..];
                            minv[a - lo] = this.preconditioner_block(a, cf);
                            adh[a - lo] = this.adhesion_position_force(a, cf);
                        }
                    },
                );
                debug_assert_eq!(out.len(), sizes[ci]);
            });
        self.coef = coef;
        self.minv = minv;
        self.adhesion_force = adhesion_force;
    }

    /// Appends the coefficients of particle `a`'s pairs to `out`, in the order of its list:
    /// [Laplacian coefficient / (|x|^2 + eps) times g(|x|), adhesion coefficient], zero for
    /// pairs without an implicit term.
    #[inline(always)]
    fn pair_coefficients(&self, a: usize, f: &PairFactors, out: &mut Vec<[f64; 2]>) {
        let c = self.c;
        let nf = c.p.n_fluid;
        let nb = c.nb.of(a);
        let obj = |s: usize| c.p.material[s] as usize - 1;
        for k in 0..nb.j.len() {
            let b = nb.j[k] as usize;
            // The lists were built at the current positions: their offsets and gradient factors
            // are this step's. grad W = g(|x|) x: the pair term lap (y_ab . x_ab) grad W is
            // stored as lap g (y_ab . x_ab) x_ab, so the CG passes need no gradient per pair.
            let (xab, gf) = nb.d_and_gf(k);
            let r2 = xab.norm_squared() + self.eps_h;
            out.push(match (a < nf, k < nb.n_fluid) {
                (true, true) if self.implicit_visc => [self.viscosity(f.volume[a], f.volume[b]) / r2 * gf, 0.0],
                (true, false) => {
                    let io = a * f.objects + obj(b);
                    let adh = self.adhesion(a, b, f.strength[b - nf], f.density[io], nb.w[k]);
                    [f.drag[io] / r2 * gf, adh]
                }
                (false, true) => {
                    let io = b * f.objects + obj(a);
                    let adh = self.adhesion(b, a, f.strength[a - nf], f.density[io], nb.w[k]);
                    [f.drag[io] / r2 * gf, adh]
                }
                _ => [0.0, 0.0],
            });
        }
    }

    /// Cached pair coefficients of particle `a`.
    #[inline(always)]
    pub(super) fn coefs(&self, a: usize) -> &[[f64; 2]] {
        let (ci, s, e) = self.c.nb.span(a);
        &self.coef[ci][s..e]
    }

    /// `F_lin(y)` at particle a (without elasticity, which needs the PRL pass).
    #[inline(always)]
    pub(super) fn pair_forces(&self, a: usize, y: &[Vector3<f64>]) -> Vector3<f64> {
        let c = self.c;
        let nb = c.nb.of(a);
        let cf = self.coefs(a);
        let xa = c.p.x[a];
        let ya = y[a];
        let dt = c.dt;
        let mut f = Vector3::zeros();
        for k in self.coupled(a, &nb) {
            let b = nb.j[k] as usize;
            let yab = ya - y[b];
            let [lap_g, adh] = cf[k];
            let xab = xa - c.p.x[b];
            f += (lap_g * yab.dot(&xab)) * xab;
            if adh != 0.0 {
                f -= (dt * adh) * yab;
            }
        }
        if c.p.is_fluid(a) && self.implicit_visc && self.s.boundary_viscosity > 0.0 {
            f += self.boundary_visc(a, ya, false);
        }
        f
    }
    /// Row `a` of `A y = m y - dt F_lin(y)`, given the linearised stress `prl` of `y`.
    #[inline(always)]
    pub(super) fn row(&self, a: usize, y: &[Vector3<f64>], prl: &[Matrix3<f64>]) -> Vector3<f64> {
        let c = self.c;
        let nf = c.p.n_fluid;
        let m = c.p.mass[a];
        if a >= nf && c.rest.fixed[a - nf] {
            return m * y[a];
        }
        let mut f = self.pair_forces(a, y);
        if a >= nf {
            f += linear_row(c, a - nf, prl, y);
        }
        m * y[a] - c.dt * f
    }
    /// `A y = m y - dt F_lin(y)`.
    pub(super) fn apply(&self, y: &[Vector3<f64>], out: &mut [Vector3<f64>], prl: &mut [Matrix3<f64>]) {
        self.stress_pass(y, prl);
        let prl: &[Matrix3<f64>] = prl;
        rmi_par::for_each_hot(
            out,
            #[inline(always)]
            |a, o| *o = self.row(a, y, prl),
        );
    }

    /// `out = filter(A y)` and returns `y . out` (the CG step's curvature), in one pass.
    fn apply_filtered_dot(&self, y: &[Vector3<f64>], out: &mut [Vector3<f64>], prl: &mut [Matrix3<f64>]) -> f64 {
        self.stress_pass(y, prl);
        let prl: &[Matrix3<f64>] = prl;
        let filters = &self.filters;
        let [yay] = rmi_par::for_each_sum(
            out,
            #[inline(always)]
            |a, o| {
                *o = self.row(a, y, prl);
                filters[a].apply(o);
                [y[a].dot(o)]
            },
        );
        yay
    }

    /// Inverted block-Jacobi preconditioner block of particle `a`, given its pair
    /// coefficients `cf`.
    #[inline(always)]
    fn preconditioner_block(&self, a: usize, cf: &[[f64; 2]]) -> Matrix3<f64> {
        let c = self.c;
        let nf = c.p.n_fluid;
        let dt = c.dt;
        let m = c.p.mass[a];
        if self.s.preconditioner == Preconditioner::Identity || (a >= nf && c.rest.fixed[a - nf]) {
            return Matrix3::identity() / m;
        }
        let nb = c.nb.of(a);
        let xa = c.p.x[a];
        // d(F_lin)/d(y_a): pair terms coef * grad W x^T and -dt c I.
        let mut jac = Matrix3::zeros();
        for k in self.coupled(a, &nb) {
            let [lap_g, adh] = cf[k];
            let xab = xa - c.p.x[nb.j[k] as usize];
            jac += lap_g * xab * xab.transpose();
            jac -= Matrix3::from_diagonal_element(dt * adh);
        }
        let mut block = Matrix3::from_diagonal_element(m) - dt * jac;
        if a >= nf {
            block += dt * dt * diagonal_block(c, self.ef, a - nf);
        }
        block.try_inverse().unwrap_or_else(|| Matrix3::identity() / m)
    }
}

/// The factors of the pair coefficients that depend on one particle of the pair only,
/// evaluated once per particle rather than once per pair (the same operations, so the same
/// values): per water particle its volume, and per water particle and porous object the drag
/// and the adhesion's mixture density; per skeleton particle the adhesion's strength.
struct PairFactors {
    /// Number of porous objects (the stride of `drag` and `density`).
    objects: usize,
    /// Current volume per water particle (m^3).
    volume: Vec<f64>,
    /// Drag coefficient per water particle and object.
    drag: Vec<f64>,
    /// Adhesion mixture density per water particle and object (kg/m^3).
    density: Vec<f64>,
    /// Adhesion strength per skeleton particle (N/m).
    strength: Vec<f64>,
}

impl PairFactors {
    fn new(op: &Op) -> PairFactors {
        let c = op.c;
        let (nf, objects) = (c.p.n_fluid, c.objects.len());
        let per_object = |f: &dyn Fn(usize, usize) -> f64| -> Vec<f64> {
            (0..nf * objects).map(|io| f(io / objects, io % objects)).collect()
        };
        PairFactors {
            objects,
            volume: (0..nf).map(|a| op.volume(a)).collect(),
            drag: per_object(&|i, o| op.drag(i, o)),
            density: per_object(&|i, o| op.adhesion_density(i, o)),
            strength: (nf..c.p.len()).map(|s| op.adhesion_strength(s)).collect(),
        }
    }
}

impl System for Op<'_> {
    fn apply(&self, y: &[Vector3<f64>], out: &mut [Vector3<f64>], prl: &mut [Matrix3<f64>]) {
        Op::apply(self, y, out, prl)
    }

    fn apply_filtered_dot(&self, y: &[Vector3<f64>], out: &mut [Vector3<f64>], prl: &mut [Matrix3<f64>]) -> f64 {
        Op::apply_filtered_dot(self, y, out, prl)
    }

    #[inline(always)]
    fn filter_at(&self, a: usize, x: &mut Vector3<f64>) {
        self.filters[a].apply(x)
    }

    #[inline(always)]
    fn precondition(&self, a: usize, r: &Vector3<f64>) -> Vector3<f64> {
        super::constraints::precondition(&self.minv, &self.filters, a, r)
    }

    fn coarse(&self) -> Option<&TwoLevel> {
        self.coarse.as_deref()
    }
}

/// True when the step needs the implicit solve at all.
pub fn needed(c: &Ctx, s: &NonPressureSettings) -> bool {
    c.p.n_solid() > 0
        || (s.viscosity_mode == ViscosityMode::Implicit
            && (s.viscosity > 0.0 || s.boundary_viscosity > 0.0)
            && c.p.n_fluid > 0)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::solver::linalg::CgWork;
    use crate::{presets, Simulation};

    /// A 6 x 6 x 10 cm sponge with pore water at r = 5 mm on a floor, pressed by a plate from above
    /// (its contacts become velocity constraints), with aggregates two spacings wide so that
    /// most particles sit next to an aggregate face.
    fn pressed_sponge() -> Simulation {
        let mut sim = Simulation::new(pressed_sponge_config(), Some(2)).unwrap();
        sim.set_body_velocity(1, Vector3::new(0.0, 0.0, -0.2), Vector3::zeros()).unwrap();
        // The sponge first sags away from the plate; it is caught after about 50 steps.
        sim.run(60).unwrap();
        assert!(sim.contacts().len() > 10, "{} contacts", sim.contacts().len());
        sim
    }

    /// The scene of [`pressed_sponge`], before the plate moves.
    fn pressed_sponge_config() -> crate::SimConfig {
        let mut cfg = presets::sponge([0.06, 0.06, 0.1], 0.6, 0.005);
        cfg.cg.preconditioner = Preconditioner::TwoLevel;
        cfg.cg.coarse_cell = 2.0;
        // A tight stop, so that the two preconditioners' answers can be compared closely.
        cfg.cg.tolerance = 1e-4;
        // Every term of the operator: wall viscosity too (off by default).
        cfg.fluid.boundary_viscosity = 0.01;
        cfg.scene.bodies.push(crate::config::BodyConfig {
            name: "plate".into(),
            shape: crate::config::Shape::Box { half_extents: [0.05, 0.05, 0.01] },
            position: [0.0, 0.0, 0.1 + 0.01],
            rotation: [0.0; 3],
            kinematic: true,
        });
        cfg
    }

    /// A coarse matrix kept for many steps is renewed whenever a contact constrains a particle
    /// inside one of its aggregates (the coarse space must satisfy the constraints), and kept
    /// otherwise: the plate catches the sponge and presses it, contacts come and go.
    #[test]
    fn a_kept_coarse_matrix_never_spans_a_constrained_particle() {
        let mut cfg = pressed_sponge_config();
        cfg.cg.coarse_steps = 1000;
        let mut sim = Simulation::new(cfg, Some(2)).unwrap();
        sim.set_body_velocity(1, Vector3::new(0.0, 0.0, -0.2), Vector3::zeros()).unwrap();
        let (mut renewed, mut kept, mut last) = (0, 0, None);
        for _ in 0..90 {
            // The particles the next step's contacts constrain.
            let mut held = Vec::new();
            sim.with_operator(|op| held = op.constraints.iter().map(|c| c.particle as usize).collect());
            sim.step().unwrap();
            let m = sim.snapshot().coarse.expect("the two-level preconditioner is configured");
            for &a in &held {
                assert_eq!(m.of[a], NONE, "step {}: constrained particle {a} inside an aggregate", sim.step_count());
            }
            if last == Some(m.step) {
                kept += 1;
            } else {
                renewed += 1;
            }
            last = Some(m.step);
        }
        assert!(sim.contacts().len() > 10, "{} contacts: the plate must press", sim.contacts().len());
        assert!(renewed >= 3 && kept >= 10, "renewed {renewed} times, kept {kept} times in 90 steps");
    }

    #[test]
    fn coarse_matrix_equals_z_transpose_a_z() {
        let mut sim = pressed_sponge();
        sim.with_operator(|op| {
            let tl = op.coarse.as_ref().expect("two-level preconditioner configured");
            let n = op.c.p.len();
            assert!(op.filters.iter().any(|f| *f != Filter::Free), "the scene must hold contacts");
            let agg = tl.aggregates();
            assert!(agg.len() > 8);
            let rows = op.coarse_matrix(agg);
            let mut prl = vec![Matrix3::zeros(); op.c.p.n_solid()];
            let (mut y, mut out) = (vec![Vector3::zeros(); n], vec![Vector3::zeros(); n]);
            let scale = rows.iter().flatten().map(|(_, m)| m.abs().max()).fold(0.0, f64::max);
            let mut worst: f64 = 0.0;
            for j in 0..agg.len() {
                for k in 0..3 {
                    // Column (j, k) of Z^T A Z: A applied to aggregate j's unit translation e_k,
                    // summed over each aggregate's members.
                    y.iter_mut().for_each(|v| *v = Vector3::zeros());
                    for &a in agg.members(j) {
                        y[a as usize] = Vector3::ith(k, 1.0);
                    }
                    op.apply(&y, &mut out, &mut prl);
                    for (i, row) in rows.iter().enumerate() {
                        let want = agg.members(i).iter().fold(Vector3::zeros(), |acc, &a| acc + out[a as usize]);
                        let got =
                            row.iter().find(|e| e.0 as usize == j).map_or(Vector3::zeros(), |e| e.1.column(k).into());
                        worst = worst.max((want - got).abs().max() / scale);
                    }
                }
            }
            assert!(worst < 1e-12, "largest deviation {worst:e} of the block scale");
        });
    }

    /// Sticks released to sliding after the system was built (the friction's slip release)
    /// hold only their normal velocity from then on; the two-level CG must then solve the
    /// same system as block Jacobi, though the coarse level was built before the release.
    #[test]
    fn two_level_response_stays_exact_after_sticks_are_released() {
        let mut sim = pressed_sponge();
        // Every contact a stick holding its particle at rest tangentially.
        let stick = |cons: &mut Vec<VelocityConstraint>| {
            cons.iter_mut().for_each(|c| c.tangential = Some(Vector3::zeros()));
        };
        sim.with_operator_from(stick, |op| {
            assert!(op.coarse.is_some(), "the two-level preconditioner is configured");
            let settings = NonPressureSettings { preconditioner: Preconditioner::BlockJacobi, ..*op.s };
            let mut bj = Op::new(op.c, op.dens, op.ef, &settings, op.constraints.clone());
            assert!(bj.coarse.is_none());
            let n = op.c.p.len();
            // Release every other stick in both systems, as the slip release does.
            let released: Vec<usize> = (0..op.constraints.len()).step_by(2).collect();
            assert!(released.len() > 5, "{} sticks", op.constraints.len());
            for &k in &released {
                op.release_tangential(k);
                bj.release_tangential(k);
            }
            // A downward kick on every particle, passed through each system.
            let kick: Vec<Vector3<f64>> = vec![Vector3::new(0.01, 0.0, -0.02); n];
            let respond = |o: &Op| {
                let mut w = CgWork::default();
                w.resize(n, o.c.p.n_solid());
                let mut dv = kick.clone();
                let (stats, _) = super::super::pressure_response(o, &mut dv, None, &mut w, 0.0);
                (dv, stats)
            };
            let (x_tl, st_tl) = respond(op);
            let (x_bj, st_bj) = respond(&bj);
            for st in [&st_tl, &st_bj] {
                assert!(st.residual <= op.s.tolerance, "{} iterations, residual {:e}", st.iterations, st.residual);
            }
            let scale = x_bj.iter().map(|v| v.norm()).fold(0.0, f64::max);
            let dx = x_tl.iter().zip(&x_bj).map(|(a, b)| (a - b).norm()).fold(0.0, f64::max);
            // Both stop at a relative residual of 1e-4.
            assert!(dx < 1e-3 * scale, "largest difference {dx} m/s of {scale} m/s ({st_tl:?} / {st_bj:?})");
        });
    }

    #[test]
    fn two_level_and_block_jacobi_reach_the_same_velocities() {
        let mut a = pressed_sponge();
        let mut state = a.snapshot();
        state.config.cg.preconditioner = Preconditioner::BlockJacobi;
        let mut b = Simulation::new(state.config.clone(), Some(2)).unwrap();
        b.restore(state).unwrap();
        let (mut ia, mut ib) = (0, 0);
        for _ in 0..3 {
            a.step().unwrap();
            b.step().unwrap();
            ia += a.stats().cg.iterations + a.stats().pressure_response.iterations;
            ib += b.stats().cg.iterations + b.stats().pressure_response.iterations;
        }
        // Measured 64 against 91 here; the sponge is small, larger ones gain more (about half).
        assert!(10 * ia < 9 * ib, "two-level {ia} iterations, block Jacobi {ib}");
        let vmax = b.particles().v.iter().map(|v| v.norm()).fold(0.0, f64::max);
        let dv = a.particles().v.iter().zip(&b.particles().v).map(|(x, y)| (x - y).norm()).fold(0.0, f64::max);
        // Both stop at a relative residual of 1e-4 of the right-hand side.
        assert!(dv < 1e-3 * vmax, "largest velocity difference {dv} m/s (max speed {vmax})");
    }
}
