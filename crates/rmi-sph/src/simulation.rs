//! The simulation: owns the particles, the bodies, a rayon pool and the per-step solver order.

use crate::boundary::{BodyState, Boundary};
use crate::config::SimConfig;
use crate::contact::{self, Contact, Friction, HeldFriction};
use crate::ctx::Ctx;
use crate::density::{self, DensityFields};
use crate::elasticity::{self, ElasticFields};
use crate::error::{Result, RmiError};
use crate::grid::{bounds, Grid};
use crate::kernel::CubicKernel;
use crate::neighbours::NeighbourLists;
use crate::nonpressure::{self, CgStats, CgWork, NonPressureSettings};
use crate::particles::{Particles, PorousObject, SolidRest, SolidState};
use crate::pressure::{self, PressureSettings, PressureStats, PressureWork};
use crate::retention;
use crate::scene;
use crate::snapshot::Snapshot;
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
    /// `pressure.drag_coupled` is off or there is no skeleton).
    pub pressure_response: CgStats,
    /// Implicit response that let held sticks slide whose force left the static cone
    /// (zero iterations when none did).
    pub slip_response: CgStats,
    /// Dynamic-dynamic neighbour pairs stored.
    pub neighbour_pairs: usize,
    /// Particle-body contacts resolved.
    pub contacts: usize,
    /// Wall-clock seconds per phase: neighbours, fields, implicit solve, pressure solve,
    /// pressure response, rest.
    pub seconds: [f64; 6],
}

/// Factor by which [`Simulation::soak`] raises every skeleton's permeability: the pore water
/// settles within half a second instead of minutes (Darcy flow, slowed by the drag in
/// proportion to it).
pub const SOAK_PERMEABILITY_FACTOR: f64 = 1000.0;

/// Largest thread pool a simulation accepts.
pub const MAX_THREADS: usize = 1024;

/// The error for a thread count outside 1 to [`MAX_THREADS`] (any integer: bindings pass
/// negative ones on).
pub fn threads_error(value: impl ToString) -> RmiError {
    RmiError::config("num_threads", value, format!("an integer in [1, {MAX_THREADS}]"))
}

/// `threads` if it is a pool size a simulation accepts (1 to [`MAX_THREADS`]).
pub fn check_threads(threads: usize) -> Result<usize> {
    if threads == 0 || threads > MAX_THREADS {
        return Err(threads_error(threads));
    }
    Ok(threads)
}

/// A porous-flow SPH simulation. All quantities SI; z is up by convention of the presets.
pub struct Simulation {
    cfg: SimConfig,
    kernel: CubicKernel,
    pool: std::sync::Arc<rayon::ThreadPool>,
    threads: usize,
    pub(crate) p: Particles,
    pub(crate) rest: SolidRest,
    pub(crate) solid: SolidState,
    pub(crate) objects: Vec<PorousObject>,
    pub(crate) bnd: Boundary,
    grid: Grid,
    nb: NeighbourLists,
    nbb: NeighbourLists,
    pub(crate) dens: DensityFields,
    ef: ElasticFields,
    pub(crate) kappa: Vec<f64>,
    pub(crate) kappa_dt2: Vec<f64>,
    pub(crate) dv_prev: Vec<Vector3<f64>>,
    /// Drag correction of the last pressure response (m/s; its warm start).
    pub(crate) response_prev: Vec<Vector3<f64>>,
    acc: Vec<Vector3<f64>>,
    rho0: Vec<f64>,
    pwork: PressureWork,
    cgwork: CgWork,
    pub(crate) time: f64,
    pub(crate) step: u64,
    stats: StepStats,
    contacts: Vec<Contact>,
    /// Skeleton particles whose contact pushed in the last step (contact hysteresis).
    pub(crate) contact_active: Vec<bool>,
}

/// The implicit solve's settings from the config.
fn nonpressure_settings(cfg: &SimConfig) -> NonPressureSettings {
    NonPressureSettings {
        viscosity: cfg.fluid.viscosity,
        boundary_viscosity: cfg.fluid.boundary_viscosity,
        viscosity_mode: cfg.fluid.viscosity_mode,
        tolerance: cfg.cg.tolerance,
        max_iterations: cfg.cg.max_iterations,
        preconditioner: cfg.cg.preconditioner,
        warm_start: cfg.cg.warm_start,
        coarse_cell: cfg.cg.coarse_cell * cfg.spacing(),
    }
}

/// Default thread count: `RMI_NUM_THREADS`, else `RAYON_NUM_THREADS`, else the core count.
pub fn default_threads() -> usize {
    for var in ["RMI_NUM_THREADS", "RAYON_NUM_THREADS"] {
        if let Some(n) = std::env::var(var).ok().and_then(|s| s.parse::<usize>().ok()).filter(|&n| n > 0) {
            return n;
        }
    }
    std::thread::available_parallelism().map(|n| n.get()).unwrap_or(1)
}

impl Simulation {
    /// Builds the scene of `cfg` (validated first) with `threads` worker threads (None:
    /// default) and soaks its pore water for `cfg.scene.soak_time`.
    pub fn new(cfg: SimConfig, threads: Option<usize>) -> Result<Self> {
        let mut sim = Self::build(cfg, threads)?;
        sim.soak(sim.cfg.scene.soak_time)?;
        Ok(sim)
    }

    /// The scene of `cfg` as sampled, without the soak (for states restored over it).
    pub(crate) fn build(cfg: SimConfig, threads: Option<usize>) -> Result<Self> {
        cfg.validate()?;
        let threads = check_threads(threads.unwrap_or_else(default_threads))?;
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .map_err(|e| RmiError::config("num_threads", threads, format!("a thread count the OS accepts ({e})")))?;
        let kernel = CubicKernel::new(cfg.support());
        let pool = std::sync::Arc::new(pool);
        // Every parallel pass runs in the simulation's own pool, never in rayon's global one:
        // a process forked after the global pool started has no workers for it.
        let (built, bnd) = pool.install(|| {
            (scene::build(&cfg, &kernel), Boundary::new(&cfg.scene.bodies, cfg.spacing(), &kernel, cfg.wall_layer))
        });
        let n = built.particles.len();
        let mut sim = Simulation {
            kernel,
            pool,
            threads,
            rho0: Vec::new(),
            p: built.particles,
            rest: built.rest,
            solid: built.solid_state,
            objects: built.objects,
            bnd,
            grid: Grid::default(),
            nb: NeighbourLists::default(),
            nbb: NeighbourLists::default(),
            dens: DensityFields::default(),
            ef: ElasticFields::default(),
            kappa: vec![0.0; n],
            kappa_dt2: vec![0.0; n],
            dv_prev: vec![Vector3::zeros(); n],
            response_prev: vec![Vector3::zeros(); n],
            acc: vec![Vector3::zeros(); n],
            pwork: PressureWork::default(),
            cgwork: CgWork::default(),
            time: 0.0,
            step: 0,
            stats: StepStats::default(),
            contacts: Vec::new(),
            contact_active: Vec::new(),
            cfg,
        };
        sim.refresh_rho0();
        sim.contact_active = vec![false; sim.p.n_solid()];
        sim.rest.hg_k =
            sim.pool.install(|| elasticity::hourglass_constants(&sim.rest, &sim.p, &sim.objects, &sim.kernel));
        Ok(sim)
    }

    /// Lets the pore water settle into the skeleton for `duration` (s) before the run starts:
    /// the skeleton pinned at rest, no gravity, bodies still, permeability raised by
    /// [`SOAK_PERMEABILITY_FACTOR`]. Then time, step, velocities and solver memory start from
    /// zero.
    ///
    /// Pore water sampled on a lattice is thinner than the rest density in the kernel's
    /// reach of a sponge's faces (truncated sums: about 9 % of the water's mass short at
    /// r = 8 mm, 3 % at 2.5 mm), and the pressure only resists compression. Adhesion pulls it
    /// in over seconds at the sponges' permeability, so that a squeeze starting from the
    /// lattice fills that deficit instead of expelling water. Soaked, the faces' pore water
    /// starts at the rest density the pressure holds.
    fn soak(&mut self, duration: f64) -> Result<()> {
        let steps = (duration / self.cfg.dt).round() as u64;
        if steps == 0 || self.p.n_fluid == 0 || self.p.n_solid() == 0 {
            return Ok(());
        }
        let gravity = std::mem::replace(&mut self.cfg.gravity, [0.0; 3]);
        let fixed = std::mem::replace(&mut self.rest.fixed, vec![true; self.p.n_solid()]);
        let velocities: Vec<_> = self.bnd.bodies.iter().map(|b| (b.state.velocity, b.state.angular_velocity)).collect();
        for b in &mut self.bnd.bodies {
            b.state.velocity = Vector3::zeros();
            b.state.angular_velocity = Vector3::zeros();
        }
        let betas: Vec<f64> = self.objects.iter().map(|o| o.drag_beta).collect();
        for o in &mut self.objects {
            o.drag_beta /= SOAK_PERMEABILITY_FACTOR;
        }
        let run = self.run(steps);
        for (o, beta) in self.objects.iter_mut().zip(betas) {
            o.drag_beta = beta;
        }
        for (b, (v, w)) in self.bnd.bodies.iter_mut().zip(velocities) {
            b.state.velocity = v;
            b.state.angular_velocity = w;
        }
        self.rest.fixed = fixed;
        self.cfg.gravity = gravity;
        run?;
        self.p.v.iter_mut().for_each(|v| *v = Vector3::zeros());
        for buf in [&mut self.dv_prev, &mut self.response_prev] {
            buf.iter_mut().for_each(|v| *v = Vector3::zeros());
        }
        self.kappa_dt2.iter_mut().for_each(|k| *k = 0.0);
        self.contact_active.iter_mut().for_each(|a| *a = false);
        self.time = 0.0;
        self.step = 0;
        self.update_fields();
        Ok(())
    }

    fn refresh_rho0(&mut self) {
        let nf = self.p.n_fluid;
        let objects = &self.objects;
        let f = self.cfg.fluid.density;
        self.rho0 = (0..self.p.len())
            .map(|a| if a < nf { f } else { objects[self.p.material[a] as usize - 1].material.dry_density })
            .collect();
    }

    /// The configuration.
    pub fn config(&self) -> &SimConfig {
        &self.cfg
    }

    /// Worker threads of this simulation's pool.
    pub fn threads(&self) -> usize {
        self.threads
    }

    /// Simulated time in s.
    pub fn time(&self) -> f64 {
        self.time
    }

    /// Completed steps.
    pub fn step_count(&self) -> u64 {
        self.step
    }

    /// Time step in s.
    pub fn dt(&self) -> f64 {
        self.cfg.dt
    }

    /// Dynamic particles (read only).
    pub fn particles(&self) -> &Particles {
        &self.p
    }

    /// Porous objects.
    pub fn objects(&self) -> &[PorousObject] {
        &self.objects
    }

    /// Boundary bodies and particles.
    pub fn boundary(&self) -> &Boundary {
        &self.bnd
    }

    /// Density ratio, porosity and saturation fields of the last step.
    pub fn fields(&self) -> &DensityFields {
        &self.dens
    }

    /// Pressure unknown kappa (m^2/s^2) of the last step; physical pressure is `rho * kappa`.
    pub fn kappa(&self) -> &[f64] {
        &self.kappa
    }

    /// Figures of the last step.
    pub fn stats(&self) -> &StepStats {
        &self.stats
    }

    /// Contacts of the last step.
    pub fn contacts(&self) -> &[Contact] {
        &self.contacts
    }

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

    /// Particle radius r in m.
    pub fn radius(&self) -> f64 {
        self.cfg.particle_radius
    }

    /// Sampling volume V = (2r)^3 in m^3.
    pub fn volume(&self) -> f64 {
        self.cfg.spacing().powi(3)
    }

    /// Sets the linear and angular velocity (m/s, rad/s) of a kinematic body.
    pub fn set_body_velocity(&mut self, body: usize, v: Vector3<f64>, w: Vector3<f64>) -> Result<()> {
        let b =
            self.bnd.bodies.get_mut(body).ok_or_else(|| RmiError::config("body", body, "an existing body index"))?;
        if !b.kinematic {
            return Err(RmiError::config(format!("scene.bodies[{body}].kinematic"), false, "true to move the body"));
        }
        if !(v.iter().chain(w.iter()).all(|c| c.is_finite())) {
            return Err(RmiError::config("body velocity", format!("{v:?}"), "finite components (m/s, rad/s)"));
        }
        b.state.velocity = v;
        b.state.angular_velocity = w;
        Ok(())
    }

    /// Places a kinematic body (pose only; velocities unchanged).
    pub fn set_body_pose(
        &mut self,
        body: usize,
        position: Vector3<f64>,
        rotation: nalgebra::UnitQuaternion<f64>,
    ) -> Result<()> {
        let b =
            self.bnd.bodies.get_mut(body).ok_or_else(|| RmiError::config("body", body, "an existing body index"))?;
        if !b.kinematic {
            return Err(RmiError::config(format!("scene.bodies[{body}].kinematic"), false, "true to move the body"));
        }
        b.state.position = position;
        b.state.rotation = rotation;
        self.bnd.invalidate();
        Ok(())
    }

    /// Advances one time step.
    pub fn step(&mut self) -> Result<&StepStats> {
        self.step_with(|_| {})
    }

    /// Advances one step; `hook` may modify velocities after the pressure solve and contact
    /// projection (the robot layer's friction), before positions are integrated.
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
    pub(crate) fn with_operator<R>(&mut self, f: impl FnOnce(&nonpressure::Op) -> R) -> R {
        self.build_neighbours();
        let cfg = &self.cfg;
        let ctx = Ctx::new(&self.p, &self.nb, &self.nbb, &self.bnd, &self.objects, &self.rest, &self.kernel, cfg);
        density::compute(&ctx, &mut self.dens);
        elasticity::rotations(&ctx, &mut self.solid.rotation);
        elasticity::prepare(&ctx, &self.solid.rotation, &self.dens.saturation, &mut self.ef);
        let nps = nonpressure_settings(cfg);
        let detected =
            contact::detect(&self.p, &self.nbb, &self.bnd, cfg.particle_radius, cfg.dt, &self.contact_active, None);
        let cons: Vec<_> = detected.iter().map(|d| d.0).collect();
        let op = nonpressure::Op::new(&ctx, &self.dens, &self.ef, &nps, cons);
        f(&op)
    }

    fn build_neighbours(&mut self) {
        let h = self.kernel.support();
        self.bnd.ensure_grid(h);
        let (lo, hi) = bounds(&self.p.x, h);
        self.grid.build_with(&self.p.x, lo, hi, h, self.cfg.neighbour_reach as usize);
        self.nb.build(&self.p.x, &self.grid, &self.kernel, self.p.n_fluid, true);
        self.nbb.build(&self.p.x, &self.bnd.grid, &self.kernel, 0, false);
    }

    fn ctx(&self) -> Ctx<'_> {
        Ctx::new(&self.p, &self.nb, &self.nbb, &self.bnd, &self.objects, &self.rest, &self.kernel, &self.cfg)
    }

    /// Drag plus adhesion force (N) per dynamic particle at the current velocities; requires
    /// [`Simulation::update_fields`] at the current positions. Sums to zero (momentum check).
    pub fn coupling_forces(&mut self) -> Vec<Vector3<f64>> {
        self.update_fields();
        let pool = self.pool.clone();
        pool.install(|| nonpressure::coupling_forces(&self.ctx(), &self.dens, &self.p.v))
    }

    /// Total buoyancy force (N) on porous object `k` from the last pressure solve.
    pub fn buoyancy_force(&mut self, k: usize) -> Vector3<f64> {
        self.update_fields();
        let pool = self.pool.clone();
        let f = pool.install(|| nonpressure::buoyancy_forces(&self.ctx(), &self.kappa));
        let nf = self.p.n_fluid;
        self.objects
            .get(k)
            .map_or(Vector3::zeros(), |o| o.range.clone().map(|a| f[a - nf]).fold(Vector3::zeros(), |s, x| s + x))
    }

    fn step_inner<F>(&mut self, friction: Option<&Friction>, hook: F) -> Result<()>
    where
        F: FnOnce(&mut ContactStage<'_>),
    {
        let t0 = Instant::now();
        let dt = self.cfg.dt;
        // 1. Neighbours.
        self.build_neighbours();
        let t1 = Instant::now();
        let cfg = &self.cfg;
        // Field-wise borrows: later passes mutate other fields of `self` while this lives.
        let ctx = Ctx::new(&self.p, &self.nb, &self.nbb, &self.bnd, &self.objects, &self.rest, &self.kernel, cfg);
        // 2-5. Densities, alpha, porosity, saturation; rotations and elastic stress.
        density::compute(&ctx, &mut self.dens);
        if self.p.n_solid() > 0 {
            elasticity::rotations(&ctx, &mut self.solid.rotation);
            elasticity::prepare(&ctx, &self.solid.rotation, &self.dens.saturation, &mut self.ef);
        }
        let t2 = Instant::now();
        // 6. Strongly coupled implicit non-pressure solve.
        let nps = nonpressure_settings(cfg);
        let v_old = self.p.v.clone();
        let kappa_dt2_old = self.kappa_dt2.clone();
        let mut v = self.p.v.clone();
        let g = Vector3::from(cfg.gravity);
        // Skeleton-body contacts enter the implicit solve as velocity constraints, so that
        // the contact force is the constraint reaction of the stiff elastic system.
        let detected =
            contact::detect(&self.p, &self.nbb, &self.bnd, cfg.particle_radius, dt, &self.contact_active, friction);
        let implicit = nonpressure::needed(&ctx, &nps);
        let mut contacts: Vec<Contact> = Vec::with_capacity(detected.len());
        let cons: Vec<_> = detected.iter().map(|d| d.0).collect();
        let mut system = implicit.then(|| nonpressure::Op::new(&ctx, &self.dens, &self.ef, &nps, cons));
        let cg = if let Some(op) = &system {
            let kappa_prev: Vec<f64> = self.kappa_dt2.iter().map(|k| k / (dt * dt)).collect();
            let (cg, impulses) = nonpressure::solve(op, &kappa_prev, &g, &mut v, &mut self.dv_prev, &mut self.cgwork);
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
        nonpressure::explicit_accelerations(&ctx, &self.dens, &nps, &v_old, &mut self.acc);
        let nf = self.p.n_fluid;
        let fixed = &self.rest.fixed;
        v.par_iter_mut().zip(self.acc.par_iter()).enumerate().for_each(|(a, (vi, ai))| {
            if a >= nf && fixed[a - nf] {
                *vi = Vector3::zeros();
            } else {
                *vi += dt * ai;
            }
        });
        let t3 = Instant::now();
        // 10. Pressure solve.
        let ps = PressureSettings {
            max_error: cfg.pressure.max_error,
            min_iterations: cfg.pressure.min_iterations,
            max_iterations: cfg.pressure.max_iterations,
            omega: cfg.pressure.omega,
            warm_start: cfg.pressure.warm_start,
            warm_start_factor: cfg.pressure.warm_start_factor,
        };
        let v_pre =
            (cfg.pressure.drag_coupled && system.is_some() && self.p.n_solid() > 0 && nf > 0).then(|| v.clone());
        let (pstats, reactions) = pressure::solve(
            &ctx,
            &self.dens,
            &ps,
            &self.rho0,
            &mut v,
            &mut self.kappa,
            &mut self.kappa_dt2,
            &mut self.pwork,
            1 + self.objects.len(),
        );
        let t3p = Instant::now();
        let pressure_response = match (v_pre, &system) {
            (Some(v_pre), Some(op)) => {
                let mut dv: Vec<Vector3<f64>> = v.iter().zip(&v_pre).map(|(a, b)| a - b).collect();
                let (st, impulses) =
                    nonpressure::pressure_response(op, &mut dv, Some(&mut self.response_prev), &mut self.cgwork);
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
                release_slipping_sticks(op, &mut contacts, f, &self.p.mass, dt, &mut v, &mut self.cgwork)
            }
            _ => CgStats::default(),
        };
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
        for a in self.contact_active.iter_mut() {
            *a = false;
        }
        for c in &contacts {
            if c.particle as usize >= nf && c.normal_force > 0.0 {
                self.contact_active[c.particle as usize - nf] = true;
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
        let vmax = crate::par::max(v.len(), |a| v[a].norm());
        if !vmax.is_finite() || vmax > cfg.max_velocity {
            self.p.v = v_old;
            self.kappa_dt2 = kappa_dt2_old;
            let reason = if vmax.is_finite() {
                format!("particle speed {vmax:.3} m/s exceeds max_velocity = {} m/s", cfg.max_velocity)
            } else {
                "non-finite particle velocity".to_string()
            };
            return Err(RmiError::Unstable { step: self.step, time: self.time, max_velocity: vmax, reason });
        }
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
                (t3 - t2).as_secs_f64(),
                (t3p - t3).as_secs_f64(),
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

    /// Bytes held by particle data, neighbour lists and solver work arrays (approximate).
    pub fn memory_bytes(&self) -> usize {
        let n = self.p.len();
        // The last terms: the density pass's water and wall gradient sums and wall flux, the
        // pressure solve's shifted positions and two 32-byte records (`pairsum`).
        let per_particle = 24 * 2 + 8 + 2 + 4 + 8 * 6 + 24 * 2 + 24 * 6 + 8 * 4 + (24 * 2 + 8) + (24 + 32 * 2);
        // Per rest pair: neighbour index, rest gradient, hourglass constant.
        let solid = self.rest.nbr.len() * (4 + 24 + 8) + self.p.n_solid() * (24 + 8 * 2 + 72 * 3 + 32 + 24 + 16);
        n * per_particle + self.nb.bytes() + self.nbb.bytes() + solid + self.bnd.x.len() * (24 * 3 + 8 + 2)
    }

    /// Captures the full state needed for a bit-identical continuation.
    pub fn snapshot(&self) -> Snapshot {
        Snapshot {
            version: crate::snapshot::VERSION,
            config: self.cfg.clone(),
            time: self.time,
            step: self.step,
            particles: self.p.clone(),
            rest_positions: self.rest.x0.clone(),
            fixed: self.rest.fixed.clone(),
            solid: self.solid.clone(),
            kappa_dt2: self.kappa_dt2.clone(),
            dv_prev: self.dv_prev.clone(),
            response_prev: self.response_prev.clone(),
            contact_active: self.contact_active.clone(),
            bodies: self.bnd.bodies.iter().map(|b| b.state.clone()).collect(),
        }
    }

    /// Restores a snapshot taken from a simulation of the same configuration.
    pub fn restore(&mut self, s: Snapshot) -> Result<()> {
        s.check()?;
        let threads = self.threads;
        let mut fresh = Simulation::build(s.config.clone(), Some(threads))?;
        if fresh.bnd.bodies.len() != s.bodies.len() {
            return Err(RmiError::State(format!(
                "snapshot has {} bodies, its config {}",
                s.bodies.len(),
                fresh.bnd.bodies.len()
            )));
        }
        let n = s.particles.len();
        let mut rest_p = s.particles.clone();
        rest_p.x[s.particles.n_fluid..].copy_from_slice(&s.rest_positions);
        let pool = fresh.pool.clone();
        pool.install(|| {
            fresh.rest = scene::rest_data(&rest_p, &s.fixed, &fresh.kernel);
            fresh.rest.hg_k = elasticity::hourglass_constants(&fresh.rest, &rest_p, &fresh.objects, &fresh.kernel);
        });
        fresh.p = s.particles;
        fresh.solid = s.solid;
        fresh.kappa_dt2 = s.kappa_dt2;
        fresh.dv_prev = s.dv_prev;
        fresh.response_prev = s.response_prev;
        fresh.contact_active = s.contact_active;
        fresh.kappa = vec![0.0; n];
        fresh.acc = vec![Vector3::zeros(); n];
        for (b, st) in fresh.bnd.bodies.iter_mut().zip(s.bodies) {
            b.state = st;
        }
        fresh.bnd.invalidate();
        fresh.time = s.time;
        fresh.step = s.step;
        fresh.refresh_rho0();
        *self = fresh;
        Ok(())
    }

    /// Writes a snapshot file (atomically: temporary name, then rename).
    pub fn save(&self, path: &std::path::Path) -> Result<()> {
        self.snapshot().save(path)
    }

    /// Loads a snapshot file into a new simulation with `threads` workers.
    pub fn load(path: &std::path::Path, threads: Option<usize>) -> Result<Self> {
        let s = Snapshot::load(path)?;
        let mut sim = Simulation::build(s.config.clone(), threads)?;
        sim.restore(s)?;
        Ok(sim)
    }
}

/// Lets the held sticks whose friction left the static cone `mu_st N` slide within the step
/// (Coulomb's bound inside the coupled system): each one's tangential force becomes the
/// kinetic force `mu_kin N` along it, the difference passes through the implicit operator
/// with that particle's tangential velocity released (the other constraints held), and its
/// contact records the kinetic force. `contacts` are aligned with the operator's
/// constraints. One pass: a stick that the release overloads in turn slides from the next
/// step on. Returns the response's statistics (zero iterations when no stick slid).
fn release_slipping_sticks(
    op: &mut nonpressure::Op,
    contacts: &mut [Contact],
    friction: &Friction,
    mass: &[f64],
    dt: f64,
    v: &mut [Vector3<f64>],
    work: &mut CgWork,
) -> CgStats {
    let mut dv: Vec<Vector3<f64>> = Vec::new();
    for (k, c) in contacts.iter_mut().enumerate() {
        let Some(h) = c.held.as_mut() else { continue };
        let normal = c.normal_force.max(0.0);
        let f = h.force.norm();
        if f <= friction.mu_static * normal {
            continue;
        }
        let kinetic = h.force * (friction.mu_kinetic * normal / f);
        if dv.is_empty() {
            dv = vec![Vector3::zeros(); v.len()];
        }
        let a = c.particle as usize;
        dv[a] += dt / mass[a] * (kinetic - h.force);
        *h = HeldFriction { force: kinetic, stuck: false };
        op.release_tangential(k);
    }
    if dv.is_empty() {
        return CgStats::default();
    }
    let (stats, impulses) = nonpressure::pressure_response(op, &mut dv, None, work);
    v.iter_mut().zip(&dv).for_each(|(vi, d)| *vi += d);
    for (c, j) in contacts.iter_mut().zip(&impulses) {
        c.add_impulse(j, dt);
    }
    stats
}

/// What the per-step hook may touch: velocities after pressure and contact projection.
pub struct ContactStage<'a> {
    /// Dynamic particles (positions at the start of the step).
    pub particles: &'a Particles,
    /// Velocities to be integrated (m/s); modify to apply impulses.
    pub v: &'a mut [Vector3<f64>],
    /// Contacts found this step.
    pub contacts: &'a [Contact],
    /// Bodies (poses at the start of the step).
    pub boundary: &'a Boundary,
    /// Force and torque on each body this step (N, N m); add reactions of applied impulses.
    pub body_forces: &'a mut [(Vector3<f64>, Vector3<f64>)],
    /// Time step (s).
    pub dt: f64,
    /// Pinned skeleton particles (by solid index).
    pub rest_fixed: &'a [bool],
}

impl ContactStage<'_> {
    /// The state of body `i`.
    pub fn body(&self, i: usize) -> &BodyState {
        &self.boundary.bodies[i].state
    }
}

impl std::fmt::Debug for Simulation {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Simulation")
            .field("fluid", &self.p.n_fluid)
            .field("solid", &self.p.n_solid())
            .field("boundary", &self.bnd.x.len())
            .field("time", &self.time)
            .field("threads", &self.threads)
            .finish()
    }
}

/// Solid rest data accessor for the robot layer and tests.
impl Simulation {
    /// Skeleton rest data.
    pub fn rest(&self) -> &SolidRest {
        &self.rest
    }
}

/// Aggregates of the porous skeleton that the robot layer observes.
impl Simulation {
    /// Skeleton coverage `sum_s V W(x_f - x_s)` of every fluid particle (dimensionless), at
    /// the positions of the last step's start (or of [`Simulation::update_fields`]).
    pub fn skeleton_cover(&self) -> &[f64] {
        let nf = self.p.n_fluid;
        &self.dens.skeleton_cover[..nf.min(self.dens.skeleton_cover.len())]
    }

    /// The part (in [0, 1]) of each fluid particle that lies inside a sponge's deformed
    /// volume (see [`crate::retention`]) at the current positions; empty before the first
    /// step or [`Simulation::update_fields`]. Where the water is, particle by particle (e.g.
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
    /// `J = det F` at the current positions ([`elasticity::volume_ratio`], exact for affine
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
        for a in o.range.clone() {
            // The solid volume (1 - phi) v0 does not change; a particle compressed below it
            // (J < 1 - phi, never seen) keeps no pore volume.
            let j = elasticity::volume_ratio(&self.rest, &self.p.x, nf, a - nf);
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
}

/// Pressure read-back for bindings and output (added for the Python binding).
impl Simulation {
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
