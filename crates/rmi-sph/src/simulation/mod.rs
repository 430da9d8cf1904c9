//! The simulation: owns the particles, the bodies, a rayon pool and the solver's memory
//! between steps.
//!
//! - this file: the state, its construction (scene sampling, then the pore water's soak) and
//!   its accessors;
//! - [`step`](Simulation::step) and its variants: the step, stage by stage (`step.rs`);
//! - [`Snapshot`]: persistence, bit-identical continuation from a saved state (`io.rs`);
//! - what a snapshot must satisfy before a simulation continues from it (`snapshot_check.rs`);
//! - queries on the current state: sponge volumes, pore water, retained water, motion,
//!   pressure and coupling forces (`queries.rs`).

mod io;
mod queries;
mod snapshot_check;
mod step;

pub use io::{fnv1a64, read_limited, read_state, seal, unseal, write_atomic, CoarseMatrix, Snapshot};
pub use step::StepStats;

use crate::config::SimConfig;
use crate::contact::Contact;
use crate::error::{Result, RmiError};
use crate::neighbourhood::grid::Grid;
use crate::neighbourhood::kernel::CubicKernel;
use crate::neighbourhood::lists::NeighbourLists;
use crate::solver::density::DensityFields;
use crate::solver::elasticity::ElasticFields;
use crate::solver::implicit::{self, CgWork};
use crate::solver::pressure::PressureWork;
use crate::world::boundary::Boundary;
use crate::world::particles::{Particles, PorousObject, SolidRest, SolidState};
use crate::world::scene;
use nalgebra::Vector3;

/// Factor by which the soak of [`Simulation::new`] raises every skeleton's permeability: the
/// pore water settles within half a second instead of minutes (Darcy flow, slowed by the drag
/// in proportion to it).
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
    /// The density pass's fields of the step before (its output buffer for the next step),
    /// what a diverged step puts back.
    dens_last: DensityFields,
    ef: ElasticFields,
    pub(crate) kappa: Vec<f64>,
    pub(crate) kappa_dt2: Vec<f64>,
    pub(crate) dv_prev: Vec<Vector3<f64>>,
    /// The last pressure response (m/s; the next one's initial guess).
    pub(crate) response_prev: Vec<Vector3<f64>>,
    /// The last implicit solve's v* (m/s; part of the next one's guess).
    pub(crate) vstar_prev: Vec<Vector3<f64>>,
    acc: Vec<Vector3<f64>>,
    rho0: Vec<f64>,
    pwork: PressureWork,
    cgwork: CgWork,
    /// The last step's operator caches, reused by the next (scratch, not state).
    op_buffers: implicit::OpBuffers,
    pub(crate) time: f64,
    pub(crate) step: u64,
    stats: StepStats,
    contacts: Vec<Contact>,
    /// Per skeleton particle, the normal force (N) its body contact pushed with in the last
    /// step, zero for none: the contact hysteresis, and the load cap of sticks released
    /// before the pressure response.
    pub(crate) contact_load: Vec<f64>,
}

/// Default thread count: `RMI_NUM_THREADS`, else `RAYON_NUM_THREADS`, else the core count.
///
/// A set, non-empty `RMI_NUM_THREADS` that is not an integer in 1 to [`MAX_THREADS`] is an
/// error naming the variable (rather than silently ignored); `RAYON_NUM_THREADS` is rayon's
/// and keeps rayon's reading (a value that is not a positive integer means the default).
pub fn default_threads() -> Result<usize> {
    if let Some(text) = std::env::var_os("RMI_NUM_THREADS").filter(|t| !t.is_empty()) {
        let text = text.to_string_lossy();
        return text.trim().parse::<usize>().ok().filter(|n| (1..=MAX_THREADS).contains(n)).ok_or_else(|| {
            RmiError::config(
                "RMI_NUM_THREADS",
                format!("{text:?}"),
                format!("an integer in [1, {MAX_THREADS}] (worker threads), or unset"),
            )
        });
    }
    if let Some(n) = std::env::var("RAYON_NUM_THREADS").ok().and_then(|s| s.parse::<usize>().ok()).filter(|&n| n > 0) {
        return Ok(n);
    }
    Ok(std::thread::available_parallelism().map(|n| n.get()).unwrap_or(1))
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
    pub fn build(cfg: SimConfig, threads: Option<usize>) -> Result<Self> {
        cfg.validate()?;
        let threads = check_threads(match threads {
            Some(n) => n,
            None => default_threads()?,
        })?;
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
            dens_last: DensityFields::default(),
            ef: ElasticFields::default(),
            kappa: vec![0.0; n],
            kappa_dt2: vec![0.0; n],
            dv_prev: vec![Vector3::zeros(); n],
            response_prev: vec![Vector3::zeros(); n],
            vstar_prev: vec![Vector3::zeros(); n],
            acc: vec![Vector3::zeros(); n],
            pwork: PressureWork::default(),
            cgwork: CgWork::default(),
            op_buffers: implicit::OpBuffers::default(),
            time: 0.0,
            step: 0,
            stats: StepStats::default(),
            contacts: Vec::new(),
            contact_load: Vec::new(),
            cfg,
        };
        sim.refresh_rho0();
        sim.contact_load = vec![0.0; sim.p.n_solid()];
        sim.rest.hg_k =
            sim.pool.install(|| implicit::hourglass_constants(&sim.rest, &sim.p, &sim.objects, &sim.kernel));
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
        for buf in [&mut self.dv_prev, &mut self.response_prev, &mut self.vstar_prev] {
            buf.iter_mut().for_each(|v| *v = Vector3::zeros());
        }
        self.kappa_dt2.iter_mut().for_each(|k| *k = 0.0);
        self.contact_load.iter_mut().for_each(|a| *a = 0.0);
        self.time = 0.0;
        self.step = 0;
        // The soak's coarse level was assembled with its own drag and pins.
        self.op_buffers.coarse = None;
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

    /// Bytes held by particle data, neighbour lists and solver work arrays (approximate).
    pub fn memory_bytes(&self) -> usize {
        let n = self.p.len();
        // The last terms: the density pass's water and wall gradient sums and wall flux, the
        // pressure solve's shifted positions and two 32-byte records (`pairsum`), and the
        // density pass's second buffer (the last step's fields, for a rollback).
        let per_particle =
            24 * 2 + 8 + 2 + 4 + 8 * 6 + 24 * 2 + 24 * 6 + 8 * 4 + (24 * 2 + 8) + (24 + 32 * 2) + (8 * 6 + 24 * 2);
        // Per rest pair: neighbour index, rest gradient, hourglass constant.
        let solid = self.rest.nbr.len() * (4 + 24 + 8) + self.p.n_solid() * (24 + 8 * 2 + 72 * 3 + 32 + 24 + 16);
        n * per_particle + self.nb.bytes() + self.nbb.bytes() + solid + self.bnd.x.len() * (24 * 3 + 8 + 2)
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

/// Skeleton rest data.
impl Simulation {
    /// Skeleton rest data.
    pub fn rest(&self) -> &SolidRest {
        &self.rest
    }
}
