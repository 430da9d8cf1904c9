//! The step, stage by stage (docs/physics.md §2): neighbours; densities, porosity,
//! saturation and elastic stress; the strongly coupled implicit solve with the skeleton's
//! contacts as constraints; explicit forces; the pressure solve and the implicit response to
//! its impulse; the release of sticks that left the friction cone; the safety projection and
//! the caller's hook; the divergence guard; advection.

use super::Simulation;
use crate::config::SimConfig;
use crate::contact::{self, release_slipping_sticks, slide_sticks, Contact, ContactStage, Friction, HeldFriction};
use crate::error::{Result, RmiError};
use crate::neighbourhood::grid::{bounds, Grid};
use crate::solver::ctx::Ctx;
use crate::solver::density;
use crate::solver::elasticity;
use crate::solver::implicit::{self, CgStats, NonPressureSettings};
use crate::solver::pressure::{self, PressureSettings, PressureStats};
use nalgebra::Vector3;
use rayon::prelude::*;
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

/// Solver memory and fields of the last good step, restored when a step diverges.
struct Undo {
    dv_prev: Vec<Vector3<f64>>,
    response_prev: Vec<Vector3<f64>>,
    vstar_prev: Vec<Vector3<f64>>,
    rotation: Vec<nalgebra::UnitQuaternion<f64>>,
    kappa: Vec<f64>,
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

    fn reorder_fluid(&mut self) {
        let nf = self.p.n_fluid;
        if nf < 2 {
            return;
        }
        let (lo, hi) = bounds(&self.p.x[..nf], self.kernel.support());
        let mut g = Grid::default();
        g.build(&self.p.x[..nf], lo, hi, self.kernel.support());
        let perm: Vec<usize> = g.sorted_idx.iter().map(|&i| i as usize).collect();
        fn apply<T: Copy>(v: &mut [T], perm: &[usize]) {
            let old: Vec<T> = v[..perm.len()].to_vec();
            for (new, &o) in perm.iter().enumerate() {
                v[new] = old[o];
            }
        }
        apply(&mut self.p.x, &perm);
        apply(&mut self.p.v, &perm);
        apply(&mut self.p.mass, &perm);
        apply(&mut self.p.id, &perm);
        apply(&mut self.kappa_dt2, &perm);
        apply(&mut self.dv_prev, &perm);
        apply(&mut self.response_prev, &perm);
        apply(&mut self.vstar_prev, &perm);
        if let Some(tl) = &mut self.op_buffers.coarse {
            std::sync::Arc::make_mut(tl).permute(&perm);
        }
        // Fields of the last step, so that accessors stay aligned with the particles.
        for f in [
            &mut self.kappa,
            &mut self.dens.rho_ratio,
            &mut self.dens.alpha,
            &mut self.dens.porosity,
            &mut self.dens.saturation,
            &mut self.dens.skeleton_cover,
        ] {
            if f.len() >= perm.len() {
                apply(f, &perm);
            }
        }
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

    /// Builds the next step's implicit system (neighbours, fields, contacts, operator) at the
    /// current state and hands it to `f`, without stepping.
    #[cfg(test)]
    pub(crate) fn with_operator<R>(&mut self, f: impl FnOnce(&implicit::Op) -> R) -> R {
        self.with_operator_from(|_| {}, |op| f(op))
    }

    /// [`Simulation::with_operator`] with the detected contact constraints passed through
    /// `edit` first (e.g. to make them sticks), and the operator handed over mutable.
    #[cfg(test)]
    pub(crate) fn with_operator_from<R>(
        &mut self,
        edit: impl FnOnce(&mut Vec<implicit::VelocityConstraint>),
        f: impl FnOnce(&mut implicit::Op) -> R,
    ) -> R {
        self.build_neighbours();
        let cfg = &self.cfg;
        let ctx = Ctx::new(&self.p, &self.nb, &self.nbb, &self.bnd, &self.objects, &self.rest, &self.kernel, cfg);
        density::compute(&ctx, &mut self.dens);
        elasticity::rotations(&ctx, &mut self.solid.rotation, &mut self.ef.ftil);
        elasticity::prepare(&ctx, &self.solid.rotation, &self.dens.saturation, &mut self.ef);
        let nps = nonpressure_settings(cfg, self.step);
        let detected =
            contact::detect(&self.p, &self.nbb, &self.bnd, cfg.particle_radius, cfg.dt, &self.contact_load, None);
        let mut cons: Vec<_> = detected.iter().map(|d| d.0).collect();
        edit(&mut cons);
        let mut op = implicit::Op::new(&ctx, &self.dens, &self.ef, &nps, cons);
        f(&mut op)
    }

    /// The next step's pressure problem at the current state (neighbours, fields, the current
    /// velocities as the predicted ones, the last step's kappa dt^2 as the warm start), handed
    /// to `f` as (context, fields, rest densities, velocities, kappa dt^2), without stepping.
    #[cfg(test)]
    pub(crate) fn with_pressure_problem<R>(
        &mut self,
        f: impl FnOnce(&Ctx, &density::DensityFields, &[f64], &[Vector3<f64>], &[f64]) -> R,
    ) -> R {
        self.build_neighbours();
        let ctx = Ctx::new(&self.p, &self.nb, &self.nbb, &self.bnd, &self.objects, &self.rest, &self.kernel, &self.cfg);
        density::compute(&ctx, &mut self.dens);
        f(&ctx, &self.dens, &self.rho0, &self.p.v, &self.kappa_dt2)
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

    fn step_inner<F>(&mut self, friction: Option<&Friction>, hook: F) -> Result<()>
    where
        F: FnOnce(&mut ContactStage<'_>),
    {
        let t0 = Instant::now();
        let dt = self.cfg.dt;
        // What the step mutates in place before its divergence guard, so that a diverged
        // step restores the last good state exactly (a retry then fails the same way).
        let undo = Undo {
            dv_prev: self.dv_prev.clone(),
            response_prev: self.response_prev.clone(),
            vstar_prev: self.vstar_prev.clone(),
            rotation: self.solid.rotation.clone(),
            kappa: self.kappa.clone(),
        };
        // 1. Neighbours.
        self.build_neighbours();
        let t1 = Instant::now();
        let cfg = &self.cfg;
        // Field-wise borrows: later passes mutate other fields of `self` while this lives.
        let ctx = Ctx::new(&self.p, &self.nb, &self.nbb, &self.bnd, &self.objects, &self.rest, &self.kernel, cfg);
        // 2-5. Densities, alpha, porosity, saturation; rotations and elastic stress. The pass
        // overwrites every value, so it writes into the spare buffer and the last step's
        // fields stay there for a rollback, without a copy.
        std::mem::swap(&mut self.dens, &mut self.dens_last);
        density::compute(&ctx, &mut self.dens);
        if self.p.n_solid() > 0 {
            elasticity::rotations(&ctx, &mut self.solid.rotation, &mut self.ef.ftil);
            elasticity::prepare(&ctx, &self.solid.rotation, &self.dens.saturation, &mut self.ef);
        }
        let t2 = Instant::now();
        // 6. Strongly coupled implicit non-pressure solve.
        let nps = nonpressure_settings(cfg, self.step);
        let v_old = self.p.v.clone();
        let kappa_dt2_old = self.kappa_dt2.clone();
        let mut v = self.p.v.clone();
        let g = Vector3::from(cfg.gravity);
        // Skeleton-body contacts enter the implicit solve as velocity constraints, so that
        // the contact force is the constraint reaction of the stiff elastic system.
        let detected =
            contact::detect(&self.p, &self.nbb, &self.bnd, cfg.particle_radius, dt, &self.contact_load, friction);
        let implicit = implicit::needed(&ctx, &nps);
        let mut contacts: Vec<Contact> = Vec::with_capacity(detected.len());
        let cons: Vec<_> = detected.iter().map(|d| d.0).collect();
        let buffers = std::mem::take(&mut self.op_buffers);
        let coarse_before = buffers.coarse.clone();
        let mut system = implicit.then(|| implicit::Op::with_buffers(&ctx, &self.dens, &self.ef, &nps, cons, buffers));
        let nf = self.p.n_fluid;
        let fixed = &self.rest.fixed;
        let ps = PressureSettings::from(&cfg.pressure);
        let coupled = cfg.pressure.drag_coupled && system.is_some() && self.p.n_solid() > 0 && nf > 0;
        // Buoyancy reads the previous step's pressure (before a single solve overwrites it).
        let kappa_prev: Vec<f64> = match system {
            Some(_) => self.kappa_dt2.iter().map(|k| k / (dt * dt)).collect(),
            None => Vec::new(),
        };
        // Single solve: the pressure first, on the velocities with gravity alone; its impulse
        // then joins the implicit solve's right-hand side.
        let mut solved_first = None;
        let mut pressure_impulse = None;
        let mut first_seconds = 0.0;
        if coupled && cfg.pressure.single_solve {
            let tp = Instant::now();
            let still = |a: usize| a >= nf && fixed[a - nf];
            let v_pred: Vec<Vector3<f64>> =
                v.iter().enumerate().map(|(a, vi)| if still(a) { Vector3::zeros() } else { vi + dt * g }).collect();
            let mut v_p = v_pred.clone();
            solved_first = Some(pressure::solve(
                &ctx,
                &self.dens,
                &ps,
                &self.rho0,
                &mut v_p,
                &mut self.kappa,
                &mut self.kappa_dt2,
                &mut self.pwork,
                1 + self.objects.len(),
            ));
            let dv: Vec<Vector3<f64>> = v_p
                .iter()
                .zip(&v_pred)
                .enumerate()
                .map(|(a, (p, q))| if still(a) { Vector3::zeros() } else { p - q })
                .collect();
            pressure_impulse = Some(dv);
            first_seconds = tp.elapsed().as_secs_f64();
        }
        let cg = if let Some(op) = &system {
            let (cg, impulses) = implicit::solve(
                op,
                &kappa_prev,
                &g,
                &mut v,
                &mut self.dv_prev,
                &mut self.vstar_prev,
                &mut self.cgwork,
                pressure_impulse.as_deref(),
            );
            for ((con, body, point), j) in detected.iter().zip(impulses) {
                let mut c = Contact {
                    particle: con.particle,
                    body: *body,
                    normal: con.normal,
                    point: *point,
                    normal_force: 0.0,
                    held: con.tangential.map(|_| HeldFriction { force: Vector3::zeros(), stuck: true }),
                };
                c.add_impulse(&j, dt);
                contacts.push(c);
            }
            cg
        } else {
            CgStats::default()
        };
        // 7-9. Explicit accelerations (and gravity when there was no implicit solve), predict.
        self.acc.par_iter_mut().for_each(|a| *a = if implicit { Vector3::zeros() } else { g });
        implicit::explicit_accelerations(&ctx, &self.dens, &nps, &v_old, &mut self.acc);
        v.par_iter_mut().zip(self.acc.par_iter()).enumerate().for_each(|(a, (vi, ai))| {
            if a >= nf && fixed[a - nf] {
                *vi = Vector3::zeros();
            } else {
                *vi += dt * ai;
            }
        });
        let t3 = Instant::now();
        // 10. Pressure solve (done already under a single solve), then the response to it.
        let v_pre = (coupled && solved_first.is_none()).then(|| v.clone());
        let (pstats, reactions) = match solved_first {
            Some(done) => done,
            None => pressure::solve(
                &ctx,
                &self.dens,
                &ps,
                &self.rho0,
                &mut v,
                &mut self.kappa,
                &mut self.kappa_dt2,
                &mut self.pwork,
                1 + self.objects.len(),
            ),
        };
        let t3p = Instant::now();
        let pressure_response = match (v_pre, &mut system) {
            (Some(v_pre), Some(op)) => {
                let mut dv: Vec<Vector3<f64>> = v.iter().zip(&v_pre).map(|(a, b)| a - b).collect();
                // Sticks that the implicit solve's load already pushes out of the static cone
                // slide within the pressure response: one solve instead of two.
                let previous = Some(self.contact_load.as_slice());
                if let Some(slip) =
                    friction.and_then(|f| slide_sticks(op, &mut contacts, f, &self.p.mass, dt, previous))
                {
                    dv.iter_mut().zip(&slip).for_each(|(d, s)| *d += s);
                }
                let (st, impulses) =
                    implicit::pressure_response(op, &mut dv, Some(&mut self.response_prev), &mut self.cgwork, 0.0);
                v.iter_mut().zip(v_pre.iter().zip(&dv)).for_each(|(vi, (p, d))| *vi = p + d);
                // What the constraints took of the pressure impulse reaches the bodies.
                for (c, j) in contacts.iter_mut().zip(&impulses) {
                    c.add_impulse(j, dt);
                }
                st
            }
            _ => CgStats::default(),
        };
        let slip_response = match (&mut system, friction) {
            (Some(op), Some(f)) => {
                // A correction to the pressure response (or, without one, the implicit solve).
                let floor = if pressure_response.rhs_norm > 0.0 { pressure_response.rhs_norm } else { cg.rhs_norm };
                release_slipping_sticks(op, &mut contacts, f, &self.p.mass, dt, &mut v, &mut self.cgwork, floor)
            }
            _ => CgStats::default(),
        };
        if let Some(op) = system {
            self.op_buffers = op.into_buffers();
        }
        for (a, vi) in v.iter_mut().enumerate().skip(nf) {
            if fixed[a - nf] {
                *vi = Vector3::zeros();
            }
        }
        let t4 = Instant::now();
        // Safety projection (deep fluid penetration, contacts the pressure solve pushed in),
        // merged with the constraint contacts; then the caller's hook (friction).
        let extra = contact::resolve(&self.p, &mut v, &self.nbb, &self.bnd, cfg.particle_radius, dt);
        contacts = contact::merge(contacts, extra);
        let mut contact_load = vec![0.0; self.contact_load.len()];
        for c in &contacts {
            if c.particle as usize >= nf && c.normal_force > 0.0 {
                contact_load[c.particle as usize - nf] += c.normal_force;
            }
        }
        let mut forces: Vec<(Vector3<f64>, Vector3<f64>)> = reactions;
        for c in &contacts {
            let f = -(c.normal * c.normal_force + c.held.map_or(Vector3::zeros(), |h| h.force));
            let bi = c.body as usize;
            forces[bi].0 += f;
            forces[bi].1 += (c.point - self.bnd.bodies[bi].state.position).cross(&f);
        }
        let mut stage = ContactStage {
            particles: &self.p,
            v: &mut v,
            contacts: &contacts,
            boundary: &self.bnd,
            body_forces: &mut forces,
            dt,
            rest_fixed: &self.rest.fixed,
        };
        hook(&mut stage);
        // Divergence guard before anything is committed.
        let vmax = rmi_par::max(v.len(), |a| v[a].norm());
        if !vmax.is_finite() || vmax > cfg.max_velocity {
            self.p.v = v_old;
            self.kappa_dt2 = kappa_dt2_old;
            self.dv_prev = undo.dv_prev;
            self.response_prev = undo.response_prev;
            self.vstar_prev = undo.vstar_prev;
            self.solid.rotation = undo.rotation;
            self.kappa = undo.kappa;
            self.op_buffers.coarse = coarse_before;
            std::mem::swap(&mut self.dens, &mut self.dens_last);
            let reason = if vmax.is_finite() {
                format!("particle speed {vmax:.3} m/s exceeds max_velocity = {} m/s", cfg.max_velocity)
            } else {
                "non-finite particle velocity".to_string()
            };
            return Err(RmiError::Unstable { step: self.step, time: self.time, max_velocity: vmax, reason });
        }
        self.contact_load = contact_load;
        // 11. Advect.
        self.p.x.par_iter_mut().zip(v.par_iter()).for_each(|(x, vi)| *x += dt * vi);
        self.p.v = v;
        for (b, f) in self.bnd.bodies.iter_mut().zip(forces) {
            b.force = f.0;
            b.torque = f.1;
        }
        self.bnd.advance(dt);
        self.time += dt;
        self.step += 1;
        let t5 = Instant::now();
        self.stats = StepStats {
            pressure: pstats,
            cg,
            pressure_response,
            slip_response,
            neighbour_pairs: self.nb.pairs(),
            contacts: contacts.len(),
            seconds: [
                (t1 - t0).as_secs_f64(),
                (t2 - t1).as_secs_f64(),
                (t3 - t2).as_secs_f64() - first_seconds,
                (t3p - t3).as_secs_f64() + first_seconds,
                (t4 - t3p).as_secs_f64(),
                (t5 - t4).as_secs_f64(),
            ],
        };
        self.contacts = contacts;
        // Re-sort only after a committed step, so that a failed step changes nothing.
        if self.cfg.reorder_every > 0 && self.step.is_multiple_of(self.cfg.reorder_every as u64) {
            self.reorder_fluid();
        }
        Ok(())
    }
}
