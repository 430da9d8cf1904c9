//! The step, stage by stage (docs/physics.md §2): neighbours; densities, porosity,
//! saturation and elastic stress; the velocity solves (`solves.rs`: the strongly coupled
//! implicit solve with the skeleton's contacts as constraints, explicit forces, the pressure
//! solve and the implicit response to its impulse, the release of sticks that left the
//! friction cone); the safety projection and the caller's hook; the divergence guard;
//! advection (`commit.rs`); the fluid's periodic re-sort (`reorder.rs`).

mod commit;
#[cfg(test)]
mod inspect;
mod reorder;
mod solves;

use super::Simulation;
use crate::config::SimConfig;
use crate::contact::{Contact, ContactStage, Friction};
use crate::error::Result;
use crate::neighbourhood::grid::bounds;
use crate::solver::ctx::Ctx;
use crate::solver::density;
use crate::solver::elasticity;
use crate::solver::implicit::{CgStats, NonPressureSettings};
use crate::solver::pressure::PressureStats;
use commit::Undo;
use nalgebra::Vector3;
use std::time::Instant;

/// Figures of the last step.
#[derive(Clone, Debug, Default)]
pub struct StepStats {
    /// Pressure solve.
    pub pressure: PressureStats,
    /// Implicit non-pressure solve.
    pub cg: CgStats,
    /// Implicit response to the pressure impulse (zero iterations when
    /// `pressure.drag_coupled` is off, under `pressure.single_solve`, or without a skeleton).
    pub pressure_response: CgStats,
    /// Implicit response that let held sticks slide whose force left the static cone only
    /// after the pressure response (zero iterations when none did; sticks that the implicit
    /// solve's load already pushed out slide within the pressure response).
    pub slip_response: CgStats,
    /// Dynamic-dynamic neighbour pairs stored.
    pub neighbour_pairs: usize,
    /// Particle-body contacts resolved.
    pub contacts: usize,
    /// Wall-clock seconds per phase: neighbours, fields, implicit solve, pressure solve,
    /// pressure response, rest.
    pub seconds: [f64; 6],
}

/// The implicit solve's settings from the config, for the step that follows `step` completed ones.
fn nonpressure_settings(cfg: &SimConfig, step: u64) -> NonPressureSettings {
    NonPressureSettings {
        viscosity: cfg.fluid.viscosity,
        boundary_viscosity: cfg.fluid.boundary_viscosity,
        viscosity_mode: cfg.fluid.viscosity_mode,
        tolerance: cfg.cg.tolerance,
        max_iterations: cfg.cg.max_iterations,
        preconditioner: cfg.cg.preconditioner,
        warm_start: cfg.cg.warm_start,
        coarse_cell: cfg.cg.coarse_cell * cfg.spacing(),
        coarse_steps: cfg.cg.coarse_steps,
        step,
    }
}

impl Simulation {
    /// Advances one time step.
    pub fn step(&mut self) -> Result<&StepStats> {
        self.step_with(|_| {})
    }

    /// Advances one step; `hook` may modify velocities after the pressure solve and contact
    /// projection, before positions are integrated (e.g. friction applied after the solves,
    /// [`ContactMemory::apply`](crate::contact::ContactMemory::apply)).
    pub fn step_with<F>(&mut self, hook: F) -> Result<&StepStats>
    where
        F: FnOnce(&mut ContactStage<'_>) + Send,
    {
        self.step_with_friction(None, hook)
    }

    /// [`Simulation::step_with`] with Coulomb friction between the skeleton and the bodies
    /// solved inside the implicit system ([`Friction`]): each such contact holds its whole
    /// velocity in the non-pressure solve and the pressure response, so that the drag
    /// couples its pore water to it; contacts whose holding force left the static cone then
    /// slide with the kinetic force, passed through the same operator. The friction of each
    /// contact ([`Contact::held`]) is applied and in the body's load before the hook runs.
    pub fn step_with_friction<F>(&mut self, friction: Option<&Friction>, hook: F) -> Result<&StepStats>
    where
        F: FnOnce(&mut ContactStage<'_>) + Send,
    {
        let pool = self.pool.clone();
        pool.install(|| self.step_inner(friction, hook))?;
        Ok(&self.stats)
    }

    /// Runs `n` steps.
    pub fn run(&mut self, n: u64) -> Result<()> {
        for _ in 0..n {
            self.step()?;
        }
        Ok(())
    }

    /// Rebuilds neighbour lists and density, porosity and saturation fields at the current
    /// positions (what observations read). Called by every step; call it directly after
    /// restoring or editing a state to read fields without stepping.
    pub fn update_fields(&mut self) {
        let pool = self.pool.clone();
        pool.install(|| {
            self.build_neighbours();
            let mut dens = std::mem::take(&mut self.dens);
            density::compute(&self.ctx(), &mut dens);
            self.dens = dens;
        });
    }

    pub(super) fn build_neighbours(&mut self) {
        let h = self.kernel.support();
        self.bnd.ensure_grid(h);
        let (lo, hi) = bounds(&self.p.x, h);
        self.grid.build_with(&self.p.x, lo, hi, h, self.cfg.neighbour_reach as usize);
        self.nb.build(&self.p.x, &self.grid, &self.kernel, self.p.n_fluid, true);
        self.nbb.build(&self.p.x, &self.bnd.grid, &self.kernel, 0, false);
    }

    pub(super) fn ctx(&self) -> Ctx<'_> {
        Ctx::new(&self.p, &self.nb, &self.nbb, &self.bnd, &self.objects, &self.rest, &self.kernel, &self.cfg)
    }

    /// The step as its sequence of stages; a step that diverges commits nothing.
    fn step_inner<F>(&mut self, friction: Option<&Friction>, hook: F) -> Result<()>
    where
        F: FnOnce(&mut ContactStage<'_>),
    {
        let t0 = Instant::now();
        // What the step mutates in place before its divergence guard, so that a diverged
        // step restores the last good state exactly (a retry then fails the same way).
        let undo = Undo::of(self);
        // §2.1 Neighbours.
        self.build_neighbours();
        let t1 = Instant::now();
        // §2.1-2.2 Densities, alpha, porosity, saturation; rotations and elastic stress.
        self.compute_fields();
        let t2 = Instant::now();
        // §2.3-2.8 Contacts, implicit solve, explicit forces, pressure solve, the responses.
        let solved = self.solve_velocities(friction);
        let t4 = Instant::now();
        let mut v = solved.v;
        // §2.9 Safety projection (deep fluid penetration, contacts the pressure solve pushed in),
        // merged with the constraint contacts; then the caller's hook (friction).
        let contacts = self.project_contacts(&mut v, solved.contacts);
        let mut forces = self.body_forces(solved.reactions, &contacts);
        self.run_hook(hook, &mut v, &contacts, &mut forces);
        // Divergence guard before anything is committed.
        if let Err(e) = self.check_velocities(&v) {
            self.roll_back(undo);
            return Err(e);
        }
        // Commit: contact loads, advection, bodies, clock.
        self.commit(v, forces, &contacts);
        let t5 = Instant::now();
        let [implicit_s, pressure_s, response_s] = solved.seconds;
        self.stats = StepStats {
            pressure: solved.pressure,
            cg: solved.cg,
            pressure_response: solved.pressure_response,
            slip_response: solved.slip_response,
            neighbour_pairs: self.nb.pairs(),
            contacts: contacts.len(),
            seconds: [
                (t1 - t0).as_secs_f64(),
                (t2 - t1).as_secs_f64(),
                implicit_s,
                pressure_s,
                response_s,
                (t5 - t4).as_secs_f64(),
            ],
        };
        self.contacts = contacts;
        // Re-sort only after a committed step, so that a failed step changes nothing.
        self.reorder_if_due();
        Ok(())
    }

    /// The fields at the step's neighbours (docs/physics.md §2.1-2.2): densities, alpha,
    /// porosity, saturation, and the skeleton's rotations and elastic stress. The density pass overwrites every value,
    /// so it writes into the spare buffer and the last step's fields stay there for a
    /// rollback, without a copy.
    fn compute_fields(&mut self) {
        let ctx = Ctx::new(&self.p, &self.nb, &self.nbb, &self.bnd, &self.objects, &self.rest, &self.kernel, &self.cfg);
        std::mem::swap(&mut self.dens, &mut self.dens_last);
        density::compute(&ctx, &mut self.dens);
        if self.p.n_solid() > 0 {
            elasticity::rotations(&ctx, &mut self.solid.rotation, &mut self.ef.ftil);
            elasticity::prepare(&ctx, &self.solid.rotation, &self.dens.saturation, &mut self.ef);
        }
    }

    /// Hands the velocities to be integrated, the contacts and the bodies' loads to the
    /// caller's `hook` (e.g. friction applied after the solves).
    fn run_hook<F>(
        &self,
        hook: F,
        v: &mut [Vector3<f64>],
        contacts: &[Contact],
        forces: &mut [(Vector3<f64>, Vector3<f64>)],
    ) where
        F: FnOnce(&mut ContactStage<'_>),
    {
        let mut stage = ContactStage {
            particles: &self.p,
            v,
            contacts,
            boundary: &self.bnd,
            body_forces: forces,
            dt: self.cfg.dt,
            rest_fixed: &self.rest.fixed,
        };
        hook(&mut stage);
    }
}
