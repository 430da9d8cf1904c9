//! The velocity solves of a step (docs/physics.md §2.3-2.8): the strongly coupled implicit
//! solve with the skeleton's contacts as constraints, the explicit forces, the
//! pressure solve, the implicit response to its impulse and the release of sticks that left
//! the friction cone. Under `pressure.single_solve` the pressure is solved first and its
//! impulse joins the implicit solve instead of a response of its own.

use super::nonpressure_settings;
use crate::contact::{self, release_slipping_sticks, slide_sticks, Contact, Friction, HeldFriction};
use crate::simulation::Simulation;
use crate::solver::ctx::Ctx;
use crate::solver::density::DensityFields;
use crate::solver::implicit::{self, CgStats, CgWork, NonPressureSettings, Op, VelocityConstraint};
use crate::solver::pressure::{self, BodyLoad, PressureSettings, PressureStats, PressureWork};
use nalgebra::Vector3;
use rayon::prelude::*;
use std::time::Instant;

/// A contact found before the solves: its constraint, its body and its point (m).
type Detected = (VelocityConstraint, u16, Vector3<f64>);

/// What the velocity solves hand to the rest of the step.
pub(super) struct Velocities {
    /// Velocities after the solves, the pinned skeleton at rest (m/s).
    pub v: Vec<Vector3<f64>>,
    /// The constraint contacts, with the impulses the solves gave them.
    pub contacts: Vec<Contact>,
    /// Per body, the pressure's force and torque on it.
    pub reactions: Vec<BodyLoad>,
    /// Pressure solve.
    pub pressure: PressureStats,
    /// Implicit non-pressure solve.
    pub cg: CgStats,
    /// Implicit response to the pressure impulse.
    pub pressure_response: CgStats,
    /// Implicit response of the sticks released after the pressure response.
    pub slip_response: CgStats,
    /// Wall-clock seconds of the implicit solve (with the explicit forces), the pressure
    /// solve and the responses.
    pub seconds: [f64; 3],
}

/// The pressure solved before the implicit solve (`pressure.single_solve`).
struct FirstPressure {
    solved: (PressureStats, Vec<BodyLoad>),
    /// Its velocity change, zero on the pinned skeleton (m/s).
    impulse: Vec<Vector3<f64>>,
    seconds: f64,
}

/// One step's solves: what they read (the step's context, fields and settings) and the
/// simulation's solver memory they write, borrowed field by field.
struct Solves<'s> {
    ctx: &'s Ctx<'s>,
    dens: &'s DensityFields,
    rho0: &'s [f64],
    /// The last step's normal force per skeleton particle (N).
    contact_load: &'s [f64],
    pressure: PressureSettings,
    gravity: Vector3<f64>,
    dt: f64,
    kappa: &'s mut Vec<f64>,
    kappa_dt2: &'s mut Vec<f64>,
    pwork: &'s mut PressureWork,
    dv_prev: &'s mut Vec<Vector3<f64>>,
    vstar_prev: &'s mut Vec<Vector3<f64>>,
    response_prev: &'s mut Vec<Vector3<f64>>,
    cgwork: &'s mut CgWork,
    acc: &'s mut Vec<Vector3<f64>>,
}

impl Simulation {
    /// §2.3-2.8 at the step's neighbours and fields: the velocities the step will
    /// integrate, the constraint contacts and the pressure's loads on the bodies.
    pub(super) fn solve_velocities(&mut self, friction: Option<&Friction>) -> Velocities {
        let t2 = Instant::now();
        let cfg = &self.cfg;
        let nf = self.p.n_fluid;
        // Field-wise borrows: the solves write other fields of `self` while these live.
        let ctx = Ctx::new(&self.p, &self.nb, &self.nbb, &self.bnd, &self.objects, &self.rest, &self.kernel, cfg);
        let nps = nonpressure_settings(cfg, self.step);
        // §2.3 Skeleton-body contacts enter the implicit solve as velocity constraints, so that
        // the contact force is the constraint reaction of the stiff elastic system.
        let detected =
            contact::detect(&self.p, &self.nbb, &self.bnd, cfg.particle_radius, cfg.dt, &self.contact_load, friction);
        let cons: Vec<_> = detected.iter().map(|d| d.0).collect();
        let buffers = std::mem::take(&mut self.op_buffers);
        let mut system = implicit::needed(&ctx, &nps)
            .then(|| implicit::Op::with_buffers(&ctx, &self.dens, &self.ef, &nps, cons, buffers));
        let coupled = cfg.pressure.drag_coupled && system.is_some() && self.p.n_solid() > 0 && nf > 0;
        let mut s = Solves {
            ctx: &ctx,
            dens: &self.dens,
            rho0: &self.rho0,
            contact_load: &self.contact_load,
            pressure: PressureSettings::from(&cfg.pressure),
            gravity: Vector3::from(cfg.gravity),
            dt: cfg.dt,
            kappa: &mut self.kappa,
            kappa_dt2: &mut self.kappa_dt2,
            pwork: &mut self.pwork,
            dv_prev: &mut self.dv_prev,
            vstar_prev: &mut self.vstar_prev,
            response_prev: &mut self.response_prev,
            cgwork: &mut self.cgwork,
            acc: &mut self.acc,
        };
        let mut v = self.p.v.clone();
        // §2.4 The implicit non-pressure solve (after the pressure under a single solve).
        let kappa_prev = s.buoyancy_pressure(system.is_some());
        let first = (coupled && cfg.pressure.single_solve).then(|| s.pressure_first(&v));
        let impulse = first.as_ref().map(|f| f.impulse.as_slice());
        let (cg, mut contacts) = match &system {
            Some(op) => s.implicit_solve(op, &detected, &kappa_prev, &mut v, impulse),
            None => (CgStats::default(), Vec::new()),
        };
        // §2.5 Explicit accelerations (and gravity when there was no implicit solve), predict.
        s.explicit_forces(&nps, system.is_some(), &mut v);
        let t3 = Instant::now();
        // §2.6-2.7 Pressure solve (done already under a single solve), then the response to it.
        let v_pre = (coupled && first.is_none()).then(|| v.clone());
        let first_seconds = first.as_ref().map_or(0.0, |f| f.seconds);
        let (pressure, reactions) = match first {
            Some(done) => done.solved,
            None => s.pressure_solve(&mut v),
        };
        let t3p = Instant::now();
        let pressure_response = match (v_pre, &mut system) {
            (Some(v_pre), Some(op)) => s.pressure_response(op, friction, &mut contacts, &v_pre, &mut v),
            _ => CgStats::default(),
        };
        let slip_response = match (&mut system, friction) {
            (Some(op), Some(f)) => {
                // §2.8 A correction to the pressure response (or, without one, the implicit solve).
                let floor = if pressure_response.rhs_norm > 0.0 { pressure_response.rhs_norm } else { cg.rhs_norm };
                release_slipping_sticks(op, &mut contacts, f, &ctx.p.mass, s.dt, &mut v, s.cgwork, floor)
            }
            _ => CgStats::default(),
        };
        if let Some(op) = system {
            self.op_buffers = op.into_buffers();
        }
        hold_pinned(&ctx, &mut v);
        let t4 = Instant::now();
        Velocities {
            v,
            contacts,
            reactions,
            pressure,
            cg,
            pressure_response,
            slip_response,
            seconds: [
                (t3 - t2).as_secs_f64() - first_seconds,
                (t3p - t3).as_secs_f64() + first_seconds,
                (t4 - t3p).as_secs_f64(),
            ],
        }
    }
}

/// Zeroes the velocities of the pinned skeleton particles.
fn hold_pinned(ctx: &Ctx, v: &mut [Vector3<f64>]) {
    let (nf, fixed) = (ctx.p.n_fluid, &ctx.rest.fixed);
    for (a, vi) in v.iter_mut().enumerate().skip(nf) {
        if fixed[a - nf] {
            *vi = Vector3::zeros();
        }
    }
}

impl Solves<'_> {
    /// Whether particle `a` is pinned skeleton.
    fn pinned(&self, a: usize) -> bool {
        let nf = self.ctx.p.n_fluid;
        a >= nf && self.ctx.rest.fixed[a - nf]
    }

    /// The previous step's pressure (Pa), which buoyancy reads in the implicit solve (read
    /// before a single solve overwrites it); empty without an implicit solve.
    fn buoyancy_pressure(&self, implicit: bool) -> Vec<f64> {
        let dt = self.dt;
        if implicit {
            self.kappa_dt2.iter().map(|k| k / (dt * dt)).collect()
        } else {
            Vec::new()
        }
    }

    /// The pressure solve on `v` (its velocities corrected in place) with `kappa dt^2` as
    /// the warm start.
    fn pressure_solve(&mut self, v: &mut [Vector3<f64>]) -> (PressureStats, Vec<BodyLoad>) {
        pressure::solve(
            self.ctx,
            self.dens,
            &self.pressure,
            self.rho0,
            v,
            self.kappa,
            self.kappa_dt2,
            self.pwork,
            1 + self.ctx.objects.len(),
        )
    }

    /// Single solve: the pressure first, on the velocities `v` with gravity alone; its
    /// impulse then joins the implicit solve's right-hand side.
    fn pressure_first(&mut self, v: &[Vector3<f64>]) -> FirstPressure {
        let tp = Instant::now();
        let (dt, g) = (self.dt, self.gravity);
        let v_pred: Vec<Vector3<f64>> =
            v.iter().enumerate().map(|(a, vi)| if self.pinned(a) { Vector3::zeros() } else { vi + dt * g }).collect();
        let mut v_p = v_pred.clone();
        let solved = self.pressure_solve(&mut v_p);
        let impulse: Vec<Vector3<f64>> = v_p
            .iter()
            .zip(&v_pred)
            .enumerate()
            .map(|(a, (p, q))| if self.pinned(a) { Vector3::zeros() } else { p - q })
            .collect();
        FirstPressure { solved, impulse, seconds: tp.elapsed().as_secs_f64() }
    }

    /// The implicit non-pressure solve of `op` on `v`, and the detected contacts with the
    /// impulses their constraints took.
    fn implicit_solve(
        &mut self,
        op: &Op,
        detected: &[Detected],
        kappa_prev: &[f64],
        v: &mut [Vector3<f64>],
        pressure_impulse: Option<&[Vector3<f64>]>,
    ) -> (CgStats, Vec<Contact>) {
        let (cg, impulses) = implicit::solve(
            op,
            kappa_prev,
            &self.gravity,
            v,
            self.dv_prev,
            self.vstar_prev,
            self.cgwork,
            pressure_impulse,
        );
        let mut contacts: Vec<Contact> = Vec::with_capacity(detected.len());
        for ((con, body, point), j) in detected.iter().zip(impulses) {
            let mut c = Contact {
                particle: con.particle,
                body: *body,
                normal: con.normal,
                point: *point,
                normal_force: 0.0,
                held: con.tangential.map(|_| HeldFriction { force: Vector3::zeros(), stuck: true }),
            };
            c.add_impulse(&j, self.dt);
            contacts.push(c);
        }
        (cg, contacts)
    }

    /// The explicit accelerations at the step's starting velocities (gravity too when there
    /// was no implicit solve), integrated into `v`; the pinned skeleton stays at rest.
    fn explicit_forces(&mut self, nps: &NonPressureSettings, implicit: bool, v: &mut [Vector3<f64>]) {
        let (dt, g) = (self.dt, self.gravity);
        self.acc.par_iter_mut().for_each(|a| *a = if implicit { Vector3::zeros() } else { g });
        implicit::explicit_accelerations(self.ctx, self.dens, nps, &self.ctx.p.v, self.acc);
        let (nf, fixed) = (self.ctx.p.n_fluid, &self.ctx.rest.fixed);
        v.par_iter_mut().zip(self.acc.par_iter()).enumerate().for_each(|(a, (vi, ai))| {
            if a >= nf && fixed[a - nf] {
                *vi = Vector3::zeros();
            } else {
                *vi += dt * ai;
            }
        });
    }

    /// The implicit response to the pressure impulse `v - v_pre`, with the sticks that the
    /// implicit solve's load already pushes out of the static cone sliding within it (one
    /// solve instead of two); `v` becomes `v_pre` plus the response, and what the
    /// constraints took of the impulse reaches the contacts.
    fn pressure_response(
        &mut self,
        op: &mut Op,
        friction: Option<&Friction>,
        contacts: &mut [Contact],
        v_pre: &[Vector3<f64>],
        v: &mut [Vector3<f64>],
    ) -> CgStats {
        let dt = self.dt;
        let mut dv: Vec<Vector3<f64>> = v.iter().zip(v_pre).map(|(a, b)| a - b).collect();
        let previous = Some(self.contact_load);
        if let Some(slip) = friction.and_then(|f| slide_sticks(op, contacts, f, &self.ctx.p.mass, dt, previous)) {
            dv.iter_mut().zip(&slip).for_each(|(d, s)| *d += s);
        }
        let (st, impulses) =
            implicit::pressure_response(op, &mut dv, Some(self.response_prev.as_mut_slice()), self.cgwork, 0.0);
        v.iter_mut().zip(v_pre.iter().zip(&dv)).for_each(|(vi, (p, d))| *vi = p + d);
        for (c, j) in contacts.iter_mut().zip(&impulses) {
            c.add_impulse(j, dt);
        }
        st
    }
}
