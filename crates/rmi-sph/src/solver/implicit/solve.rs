//! The two solves on the step's operator: the implicit non-pressure solve, and the implicit
//! response of the same system to a velocity increment (the pressure impulse, a slip).

use super::constraints::{constraint_impulses, filter};
use super::hourglass::hourglass_force;
use super::Op;
use crate::solver::elasticity;
use crate::solver::linalg::{pcg, CgStats, CgWork};
use nalgebra::{Matrix3, Vector3};
use rayon::prelude::*;

/// Solves for v* and writes it into `v`, honouring `constraints` exactly (filtered PCG).
/// `kappa_prev` (kappa of the previous step) drives buoyancy; `gravity` (m/s^2) is part of
/// the right-hand side so that constraints see it; `dv_prev` is the warm start, updated to
/// v* - v on exit. Returns the statistics and the impulse (N s) each constraint exerted on
/// its particle (along the normal; the whole vector for a sticking contact). `impulse`, when
/// given, is a velocity increment (m/s) per particle whose momentum `m dv` joins the
/// right-hand side (the pressure impulse of [`crate::config::PressureConfig::single_solve`]).
#[allow(clippy::too_many_arguments)]
pub fn solve(
    op: &Op,
    kappa_prev: &[f64],
    gravity: &Vector3<f64>,
    v: &mut [Vector3<f64>],
    dv_prev: &mut [Vector3<f64>],
    w: &mut CgWork,
    impulse: Option<&[Vector3<f64>]>,
) -> (CgStats, Vec<Vector3<f64>>) {
    let (c, ef, s, constraints) = (op.c, op.ef, op.s, &op.constraints);
    let n = c.p.len();
    let nf = c.p.n_fluid;
    for buf in [&mut w.r, &mut w.p, &mut w.ap, &mut w.b] {
        buf.resize(n, Vector3::zeros());
    }
    w.prl.resize(c.p.n_solid(), Matrix3::zeros());
    // Right-hand side m v + dt (F_exp + m g).
    {
        let vv: &[Vector3<f64>] = v;
        rmi_par::for_each_hot(
            &mut w.b,
            #[inline(always)]
            |a, b| {
                let m = c.p.mass[a];
                if a >= nf && c.rest.fixed[a - nf] {
                    *b = m * vv[a];
                    return;
                }
                let nb = c.nb.of(a);
                let mut f = m * gravity + op.adhesion_position_force(a);
                if a < nf {
                    if op.implicit_visc && s.boundary_viscosity > 0.0 {
                        f += op.boundary_visc(a, Vector3::zeros(), true);
                    }
                } else {
                    let phi = c.object(a).material.porosity;
                    for k in 0..nb.n_fluid {
                        let i = nb.j[k] as usize;
                        // Buoyancy: reaction of the fluid-side skeleton pressure term (lagged).
                        f -= ((1.0 - phi) * c.vol * c.p.mass[i] * kappa_prev[i]) * nb.g(k);
                    }
                    f += elasticity::force(c, a - nf, &ef.prl) + hourglass_force(c, ef, a - nf);
                }
                *b = m * vv[a] + c.dt * f;
                if let Some(dv) = impulse {
                    *b += m * dv[a];
                }
            },
        );
    }
    // Initial guess: warm start, with constrained normal components set to their targets.
    let mut x: Vec<Vector3<f64>> = (0..n).map(|a| if s.warm_start { v[a] + dv_prev[a] } else { v[a] }).collect();
    for con in constraints {
        let xa = &mut x[con.particle as usize];
        *xa = con.project(xa);
    }
    let stats = pcg(op, &mut x, w, s.tolerance, s.max_iterations, 0.0);
    let impulses = constraint_impulses(op, &x, w);
    v.par_iter_mut().zip(dv_prev.par_iter_mut()).zip(x.par_iter()).for_each(|((vi, dvi), xi)| {
        *dvi = xi - *vi;
        *vi = *xi;
    });
    (stats, impulses)
}

/// Implicit response of the coupled system to a velocity increment `dv` (m/s), such as the
/// pressure solve's: solves `A x = m dv` with the system of [`solve`] (viscosity, drag,
/// adhesion, linearised elasticity, the same contact constraints held; `w` sized by
/// [`solve`]), and writes x into `dv`. `correction_prev` holds the previous response's
/// x - dv, the warm start (m/s), and is updated on exit (`None`: no warm start). Because
/// `A` is linear, the step's velocity v* + x equals the implicit solve with the pressure
/// force on its right-hand side. Returns the statistics and, per constraint, the impulse
/// (N s) it exerted to hold its components against the increment; what the increment
/// pushes into a body must reach that body's load. The tolerance is relative to the larger
/// of the right-hand side's norm and `rhs_floor` (N s; see [`pcg`]).
///
/// The pressure solve moves water as if it were free; through a sponge's pores the drag
/// takes most of that impulse within the same step and the skeleton's elasticity carries
/// it, so that pore water seeps at the Darcy speed the pressure gradient drives. Every pair
/// term is equal and opposite, so momentum is conserved.
pub fn pressure_response(
    op: &Op,
    dv: &mut [Vector3<f64>],
    correction_prev: Option<&mut [Vector3<f64>]>,
    w: &mut CgWork,
    rhs_floor: f64,
) -> (CgStats, Vec<Vector3<f64>>) {
    let c = op.c;
    let nf = c.p.n_fluid;
    // A fixed skeleton does not move: zero there (rhs and guess) eliminates its rows, so the
    // water sees it as an immovable obstacle and the operator stays symmetric on the rest.
    for a in nf..c.p.len() {
        if c.rest.fixed[a - nf] {
            dv[a] = Vector3::zeros();
        }
    }
    // A contact already meets its target velocity: its held components stay put (the guess is
    // filtered; the right-hand side is not, so that the constraint's impulse includes the
    // part of the increment it cancels on its own particle).
    w.b.par_iter_mut().enumerate().for_each(|(a, b)| *b = c.p.mass[a] * dv[a]);
    let hold = |x: &mut [Vector3<f64>]| {
        for a in nf..c.p.len() {
            if c.rest.fixed[a - nf] {
                x[a] = Vector3::zeros();
            }
        }
        filter(x, &op.filters);
    };
    hold(dv);
    // Warm start: the drag takes back about the same share of the pressure impulse from step
    // to step, so the last step's correction x - dv is a close guess; water away from the
    // skeleton (rows `m x = m dv`) has none.
    let dv_in: Vec<Vector3<f64>> = dv.to_vec();
    if let (true, Some(prev)) = (op.s.warm_start, correction_prev.as_deref()) {
        dv.par_iter_mut().zip(prev.par_iter()).for_each(|(x, k)| *x += k);
        hold(dv);
    }
    let stats = pcg(op, dv, w, op.s.tolerance, op.s.max_iterations, rhs_floor);
    if let Some(prev) = correction_prev {
        prev.par_iter_mut().zip(dv.par_iter().zip(dv_in.par_iter())).for_each(|(k, (x, d))| *k = x - d);
    }
    (stats, constraint_impulses(op, dv, w))
}
