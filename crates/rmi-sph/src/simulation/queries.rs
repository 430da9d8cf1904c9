//! Queries on the current state: contact loads, coupling and buoyancy forces, sponge and
//! pore volumes, pore water, retained water, motion of a porous object and pressure.

use super::Simulation;
use crate::neighbourhood::grid::{bounds, Grid};
use crate::neighbourhood::lists::NeighbourLists;
use crate::solver::{elasticity, implicit};
use crate::world::retention;
use nalgebra::Vector3;
use rayon::prelude::*;

impl Simulation {
    /// Force (N) that skeleton particles exerted on body `bi` through their normal contacts
    /// in the last step. The body's total force (`boundary().bodies[bi].force`) adds the
    /// water's pressure and viscosity, fluid contacts and friction; the difference tells how
    /// much of a plate's load the water carries instead of the skeleton.
    pub fn skeleton_contact_force(&self, bi: usize) -> Vector3<f64> {
        let nf = self.p.n_fluid as u32;
        self.contacts
            .iter()
            .filter(|c| c.body as usize == bi && c.particle >= nf)
            .map(|c| -c.normal * c.normal_force)
            .sum()
    }

    /// Drag plus adhesion force (N) per dynamic particle at the current velocities; requires
    /// [`Simulation::update_fields`] at the current positions. Sums to zero (momentum check).
    pub fn coupling_forces(&mut self) -> Vec<Vector3<f64>> {
        self.update_fields();
        let pool = self.pool.clone();
        pool.install(|| implicit::coupling_forces(&self.ctx(), &self.dens, &self.p.v))
    }

    /// Total buoyancy force (N) on porous object `k` from the last pressure solve.
    pub fn buoyancy_force(&mut self, k: usize) -> Vector3<f64> {
        self.update_fields();
        let pool = self.pool.clone();
        let f = pool.install(|| implicit::buoyancy_forces(&self.ctx(), &self.kappa));
        let nf = self.p.n_fluid;
        self.objects
            .get(k)
            .map_or(Vector3::zeros(), |o| o.range.clone().map(|a| f[a - nf]).fold(Vector3::zeros(), |s, x| s + x))
    }
    /// Skeleton coverage `sum_s V W(x_f - x_s)` of every fluid particle (dimensionless), at
    /// the positions of the last step's start (or of [`Simulation::update_fields`]).
    pub fn skeleton_cover(&self) -> &[f64] {
        let nf = self.p.n_fluid;
        &self.dens.skeleton_cover[..nf.min(self.dens.skeleton_cover.len())]
    }

    /// The part (in [0, 1]) of each fluid particle that lies inside a sponge's deformed
    /// volume (see [`cube_inside`](crate::world::cube_inside)) at the current positions;
    /// empty before the first step or [`Simulation::update_fields`]. Where the water is, particle by particle (e.g.
    /// for output); the retained water a trial reports is [`Simulation::pore_water`].
    /// Computed on demand, with neighbour lists of its own (about a step's neighbour search).
    pub fn retained(&self) -> Vec<f64> {
        if self.dens.rho_ratio.len() != self.p.len() {
            return Vec::new();
        }
        self.pool.install(|| {
            let h = self.kernel.support();
            let (lo, hi) = bounds(&self.p.x, h);
            let mut grid = Grid::default();
            grid.build_with(&self.p.x, lo, hi, h, self.cfg.neighbour_reach as usize);
            let mut nb = NeighbourLists::default();
            nb.build(&self.p.x, &grid, &self.kernel, self.p.n_fluid, true);
            let d = self.cfg.spacing();
            retention::retained_parts(&self.p, &nb, &self.rest, &self.solid, &self.objects, &self.kernel, d)
        })
    }

    /// Current sponge volume, pore volume (m^3) and pore-volume-weighted mean saturation of
    /// porous object `k`. Each skeleton particle occupies its sampling volume `d^3` times
    /// `J = det F` at the current positions (`elasticity::volume_ratio`, exact for affine
    /// deformation also at the faces), of which the solid part `(1 - phi) d^3` does not
    /// change; saturation from the last step's fields.
    pub fn sponge_volumes(&self, k: usize) -> (f64, f64, f64) {
        let Some(o) = self.objects.get(k) else { return (0.0, 0.0, 0.0) };
        if self.dens.porosity.len() != self.p.len() {
            let n = o.range.len() as f64 * self.volume();
            return (n, o.material.porosity * n, 0.0);
        }
        let phi = o.material.porosity;
        let v0 = self.volume();
        let (mut vs, mut vp, mut sw) = (0.0, 0.0, 0.0);
        let nf = self.p.n_fluid;
        // The volume ratios in parallel (a deformation gradient each), summed in order; in the
        // simulation's pool, as every parallel pass (a forked process has no global one).
        let ratios: Vec<f64> = self.pool.install(|| {
            o.range
                .clone()
                .into_par_iter()
                .map(|a| elasticity::volume_ratio(&self.rest, &self.p.x, nf, a - nf))
                .collect()
        });
        for (a, j) in o.range.clone().zip(ratios) {
            // The solid volume (1 - phi) v0 does not change; a particle compressed below it
            // (J < 1 - phi, never seen) keeps no pore volume.
            let vol = v0 * j.max(1.0 - phi);
            let cur = 1.0 - v0 * (1.0 - phi) / vol;
            vs += vol;
            vp += cur * vol;
            sw += cur * vol * self.dens.saturation[a];
        }
        (vs, vp, if vp > 0.0 { sw / vp } else { 0.0 })
    }

    /// The water the pores of porous object `k` hold (kg): the water's rest density times
    /// the sum over its skeleton particles of current pore volume times saturation, i.e.
    /// `rho_f V_pore S` of [`Simulation::sponge_volumes`] (last step).
    ///
    /// A squeeze pushes water out of the pores first into a film on the sponge's faces, a
    /// fraction of a millimetre thick where the pores closed a few cm^3; particles of several
    /// millimetres cannot form it and instead stand a fraction of a spacing further out,
    /// still within the sponge's outline (see [`Simulation::retained`]). Counting the pores'
    /// water instead sees the release at every resolution: a saturated cube squeezed 10 %
    /// between frictionless plates releases the drained answer `rho_f (1 - 2 nu) eps V` within
    /// 7 % at r = 2.5 mm by both counts, but only this one holds at r = 5 mm (validation).
    pub fn pore_water(&self, k: usize) -> f64 {
        let (_, v_pore, saturation) = self.sponge_volumes(k);
        self.pore_water_of(v_pore, saturation)
    }

    /// [`Simulation::pore_water`] from a pore volume (m^3) and its saturation, as
    /// [`Simulation::sponge_volumes`] returns them (kg): for callers that need both, so that
    /// the skeleton is summed once.
    pub fn pore_water_of(&self, v_pore: f64, saturation: f64) -> f64 {
        self.cfg.fluid.density * v_pore * saturation
    }

    /// Mass (kg), centre of mass (m) and centre-of-mass velocity (m/s) of porous object `k`.
    pub fn object_motion(&self, k: usize) -> (f64, Vector3<f64>, Vector3<f64>) {
        let Some(o) = self.objects.get(k) else { return (0.0, Vector3::zeros(), Vector3::zeros()) };
        let (mut m, mut x, mut v) = (0.0, Vector3::zeros(), Vector3::zeros());
        for a in o.range.clone() {
            let ma = self.p.mass[a];
            m += ma;
            x += ma * self.p.x[a];
            v += ma * self.p.v[a];
        }
        if m > 0.0 {
            (m, x / m, v / m)
        } else {
            (0.0, x, v)
        }
    }

    /// Pressure (Pa) of every dynamic particle from the last pressure solve:
    /// `p = rho0 * rho_ratio * kappa` with `kappa = kappa_dt2 / dt^2` (the copy of kappa that
    /// snapshots carry, so a restored state reports the same values) and `rho0` the rest
    /// density of the particle's material (water; the dry density for skeleton particles, whose
    /// value is the skeleton's pressure unknown in the same form). Zero before the first step.
    pub fn pressure(&self) -> Vec<f64> {
        let dt2 = self.cfg.dt * self.cfg.dt;
        let nf = self.p.n_fluid;
        (0..self.p.len())
            .map(|a| {
                let object = if a < nf { None } else { (self.p.material[a] as usize).checked_sub(1) };
                let rho0 =
                    object.and_then(|k| self.objects.get(k)).map_or(self.cfg.fluid.density, |o| o.material.dry_density);
                let ratio = self.dens.rho_ratio.get(a).copied().unwrap_or(1.0);
                rho0 * ratio * self.kappa_dt2.get(a).copied().unwrap_or(0.0) / dt2
            })
            .collect()
    }
}
