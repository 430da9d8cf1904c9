//! The next step's systems built at the current state without stepping, for the solvers'
//! tests.

use super::nonpressure_settings;
use crate::contact;
use crate::simulation::Simulation;
use crate::solver::ctx::Ctx;
use crate::solver::density;
use crate::solver::elasticity;
use crate::solver::implicit;
use nalgebra::Vector3;

impl Simulation {
    /// Builds the next step's implicit system (neighbours, fields, contacts, operator) at the
    /// current state and hands it to `f`, without stepping.
    pub(crate) fn with_operator<R>(&mut self, f: impl FnOnce(&implicit::Op) -> R) -> R {
        self.with_operator_from(|_| {}, |op| f(op))
    }

    /// [`Simulation::with_operator`] with the detected contact constraints passed through
    /// `edit` first (e.g. to make them sticks), and the operator handed over mutable.
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
    pub(crate) fn with_pressure_problem<R>(
        &mut self,
        f: impl FnOnce(&Ctx, &density::DensityFields, &[f64], &[Vector3<f64>], &[f64]) -> R,
    ) -> R {
        self.build_neighbours();
        let ctx = Ctx::new(&self.p, &self.nb, &self.nbb, &self.bnd, &self.objects, &self.rest, &self.kernel, &self.cfg);
        density::compute(&ctx, &mut self.dens);
        f(&ctx, &self.dens, &self.rho0, &self.p.v, &self.kappa_dt2)
    }
}
