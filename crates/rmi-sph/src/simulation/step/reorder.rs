//! The fluid particles re-sorted along the neighbour grid every `reorder_every` committed
//! steps, so that neighbours sit close in memory.

use crate::neighbourhood::grid::{bounds, Grid};
use crate::simulation::Simulation;

impl Simulation {
    /// Re-sorts the fluid when `reorder_every` committed steps have passed since the last
    /// sort.
    pub(super) fn reorder_if_due(&mut self) {
        if self.cfg.reorder_every > 0 && self.step.is_multiple_of(self.cfg.reorder_every as u64) {
            self.reorder_fluid();
        }
    }

    /// Permutes the fluid particles, with every per-particle array of the solver's memory and
    /// the last step's fields, into the grid's cell order.
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
}
