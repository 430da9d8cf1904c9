//! Read-only view of everything a solver pass needs during one step.

use crate::neighbourhood::kernel::CubicKernel;
use crate::neighbourhood::lists::NeighbourLists;
use crate::world::boundary::Boundary;
use crate::world::particles::{Particles, PorousObject, SolidRest};

/// Borrowed step context shared by the solver passes.
pub struct Ctx<'a> {
    /// Dynamic particles (positions at the start of the step).
    pub p: &'a Particles,
    /// Dynamic-dynamic neighbours.
    pub nb: &'a NeighbourLists,
    /// Dynamic-boundary neighbours.
    pub nbb: &'a NeighbourLists,
    /// Boundary particles.
    pub bnd: &'a Boundary,
    /// Porous objects.
    pub objects: &'a [PorousObject],
    /// Skeleton rest data.
    pub rest: &'a SolidRest,
    /// Kernel.
    pub kernel: &'a CubicKernel,
    /// Sampling volume V = d^3 (m^3).
    pub vol: f64,
    /// Time step (s).
    pub dt: f64,
    /// Fluid rest density (kg/m^3).
    pub rho0_f: f64,
}

impl<'a> Ctx<'a> {
    /// Bundles the step's borrowed data; the time step, volume and water density come from `cfg`.
    #[allow(clippy::too_many_arguments)]
    pub fn new(
        p: &'a Particles,
        nb: &'a NeighbourLists,
        nbb: &'a NeighbourLists,
        bnd: &'a Boundary,
        objects: &'a [PorousObject],
        rest: &'a SolidRest,
        kernel: &'a CubicKernel,
        cfg: &crate::config::SimConfig,
    ) -> Self {
        Ctx {
            p,
            nb,
            nbb,
            bnd,
            objects,
            rest,
            kernel,
            vol: cfg.spacing().powi(3),
            dt: cfg.dt,
            rho0_f: cfg.fluid.density,
        }
    }

    /// Porous object of a solid dynamic index.
    #[inline]
    pub fn object(&self, a: usize) -> &PorousObject {
        &self.objects[self.p.material[a] as usize - 1]
    }

    /// Volume factor `f(a <- b)` of docs/physics.md §1 for dynamic particles a, b.
    #[inline]
    pub fn volume_factor(&self, a: usize, b: usize) -> f64 {
        let p = self.p;
        match (p.is_fluid(a), p.is_fluid(b)) {
            (true, true) => 1.0,
            (true, false) => 1.0 - self.object(b).material.porosity,
            (false, true) => 0.0,
            (false, false) => {
                let o = self.object(a);
                if p.material[a] == p.material[b] && o.material.compressible {
                    1.0 - o.material.porosity
                } else {
                    1.0
                }
            }
        }
    }
}
