//! The two solves on the step's operator: the implicit non-pressure solve, and the implicit
//! response of the same system to a velocity increment (the pressure impulse, a slip).

use super::constraints::{constraint_impulses, filter};
use super::hourglass::hourglass_force;
use super::Op;
use crate::solver::elasticity;
use crate::solver::linalg::{pcg, CgStats, CgWork};
use nalgebra::Vector3;
use rayon::prelude::*;

/// Solves for v* and writes it into `v`, honouring `constraints` exactly (filtered PCG).
/// `kappa_prev` (kappa of the previous step) drives buoyancy; `gravity` (m/s^2) is part of
/// the right-hand side so that constraints see it; `dv_prev` (v* - v of the last step) and
/// `vstar_prev` (the last v\*) give the warm start (see [`warm_start`]) and are updated to
/// this step's v* - v and v* on exit. Returns the statistics and the impulse (N s) each
/// constraint exerted on its particle (along the normal; the whole vector for a sticking
/// contact). `impulse`, when
/// given, is a velocity increment (m/s) per particle whose momentum `m dv` joins the
/// right-hand side (the pressure impulse of [`crate::config::PressureConfig::single_solve`]).
#[allow(clippy::too_many_arguments)]
pub fn solve(
    op: &Op,
    kappa_prev: &[f64],
    gravity: &Vector3<f64>,
    v: &mut [Vector3<f64>],
    dv_prev: &mut [Vector3<f64>],
    vstar_prev: &mut [Vector3<f64>],
    w: &mut CgWork,
    impulse: Option<&[Vector3<f64>]>,
) -> (CgStats, Vec<Vector3<f64>>) {
    let (c, ef, s) = (op.c, op.ef, op.s);
    let n = c.p.len();
    let nf = c.p.n_fluid;
    w.resize(n, c.p.n_solid());
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
                let mut f = m * gravity + op.adhesion_force[a];
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
    let (stats, x) = if s.warm_start {
        // The guess's product is the CG's first one (`w.ap`).
        let mut x = warm_start(op, v, dv_prev, vstar_prev, w);
        let stats = pcg(op, &mut x, w, s.tolerance, s.max_iterations, 0.0, true);
        vstar_prev.copy_from_slice(&x);
        (stats, x)
    } else {
        let mut x = v.to_vec();
        project(op, &mut x);
        (pcg(op, &mut x, w, s.tolerance, s.max_iterations, 0.0, false), x)
    };
    let impulses = constraint_impulses(op, &x, w);
    v.par_iter_mut().zip(dv_prev.par_iter_mut()).zip(x.par_iter()).for_each(|((vi, dvi), xi)| {
        *dvi = xi - *vi;
        *vi = *xi;
    });
    (stats, impulses)
}

/// Sets the constrained components of `x` to their targets.
fn project(op: &Op, x: &mut [Vector3<f64>]) {
    for con in &op.constraints {
        let xa = &mut x[con.particle as usize];
        *xa = con.project(xa);
    }
}

/// The implicit solve's initial guess, and its product `A x` in `w.ap` (`w.b` holds the
/// right-hand side). Two guesses each serve part of a trial: `v + (v*_prev - v_prev)` repeats
/// the last step's change, which carries the solution's trend while a sponge is squeezed or
/// falls; the last v* itself is closer while a sponge rests or is held, where the pressure's
/// corrections move `v` but barely `v*`. The guess is the point on the line through the two
/// with the smallest error in the operator's energy norm (a line search: one product more,
/// the second guess's), so it is never worse than the first. Constrained components are set
/// to their targets in both.
fn warm_start(
    op: &Op,
    v: &[Vector3<f64>],
    dv_prev: &[Vector3<f64>],
    vstar_prev: &[Vector3<f64>],
    w: &mut CgWork,
) -> Vec<Vector3<f64>> {
    let mut x: Vec<Vector3<f64>> = v.iter().zip(dv_prev).map(|(vi, dvi)| vi + dvi).collect();
    project(op, &mut x);
    op.apply(&x, &mut w.ap, &mut w.prl);
    // The direction to the last v*, without the components the constraints hold.
    let mut d: Vec<Vector3<f64>> = vstar_prev.iter().zip(&x).map(|(b, a)| b - a).collect();
    filter(&mut d, &op.filters);
    let mut ad = vec![Vector3::zeros(); d.len()];
    op.apply(&d, &mut ad, &mut w.prl);
    // theta = d . r / d . A d minimises the energy error along d; r = b - A x, and d is
    // filtered, so the held components of r do not count.
    let (b, ax) = (&w.b, &w.ap);
    let num = rmi_par::sum(d.len(), |a| d[a].dot(&(b[a] - ax[a])));
    let den = rmi_par::sum(d.len(), |a| d[a].dot(&ad[a]));
    let theta = num / den;
    if den > 0.0 && theta.is_finite() {
        x.par_iter_mut().zip(w.ap.par_iter_mut()).enumerate().for_each(|(a, (xa, axa))| {
            *xa += theta * d[a];
            *axa += theta * ad[a];
        });
    }
    x
}

/// Implicit response of the coupled system to a velocity increment `dv` (m/s), such as the
/// pressure solve's: solves `A x = m dv` with the system of [`solve`] (viscosity, drag,
/// adhesion, linearised elasticity, the same contact constraints held; `w` sized by
/// [`solve`]), and writes x into `dv`. `previous` holds the last response of the same kind
/// (m/s), the initial guess, and is updated to x on exit; without it the guess is zero.
/// Because `A` is linear, the step's velocity v* + x equals the implicit solve with the
/// pressure force on its right-hand side. Returns the statistics and, per constraint, the
/// impulse (N s) it exerted to hold its components against the increment; what the
/// increment pushes into a body must reach that body's load. The tolerance is relative to
/// the larger of the right-hand side's norm and `rhs_floor` (N s; see [`pcg`]).
///
/// The pressure solve moves water as if it were free; through a sponge's pores the drag
/// takes most of that impulse within the same step and the skeleton's elasticity carries
/// it, so that pore water seeps at the Darcy speed the pressure gradient drives. Every pair
/// term is equal and opposite, so momentum is conserved.
pub fn pressure_response(
    op: &Op,
    dv: &mut [Vector3<f64>],
    previous: Option<&mut [Vector3<f64>]>,
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
    // The guess. The pressure impulse changes little from step to step, and so does the
    // velocity it leaves once drag and elasticity have answered it: the last response leaves
    // a residual of the order of the solve's tolerance. The increment itself would be a poor
    // guess: its residual `dt F_lin(dv)` is the drag's whole reaction, larger than the
    // right-hand side. Zero leaves the right-hand side itself.
    let prev = previous.as_deref().filter(|_| op.s.warm_start);
    dv.par_iter_mut().enumerate().for_each(|(a, x)| {
        let fixed = a >= nf && c.rest.fixed[a - nf];
        *x = match prev {
            Some(p) if !fixed => p[a],
            _ => Vector3::zeros(),
        };
    });
    filter(dv, &op.filters);
    let scaled = prev.is_some() && scale_guess(op, dv, w, op.s.tolerance, rhs_floor);
    let stats = pcg(op, dv, w, op.s.tolerance, op.s.max_iterations, rhs_floor, scaled);
    if let Some(prev) = previous {
        prev.par_iter_mut().zip(dv.par_iter()).for_each(|(p, x)| *p = *x);
    }
    (stats, constraint_impulses(op, dv, w))
}

/// Scales the guess `x` (filtered) to the multiple with the smallest error in the operator's
/// energy norm, `theta = x . b / x . A x` (`w.b` holds the right-hand side), and leaves its
/// product in `w.ap`: the last response's shape carries over from step to step better than
/// its size, which follows the pressure impulse. A guess whose residual already meets
/// `tolerance` (relative to the filtered right-hand side's norm or `rhs_floor`, as in
/// [`pcg`]) is kept as it is: the CG would return it unchanged, and scaling an accepted
/// answer would move it every step, so that a resting sponge's velocities would wander and
/// the next implicit solve's guess lose its footing. Returns false (nothing computed) for a
/// zero guess.
fn scale_guess(op: &Op, x: &mut [Vector3<f64>], w: &mut CgWork, tolerance: f64, rhs_floor: f64) -> bool {
    if x.iter().all(|xa| *xa == Vector3::zeros()) {
        return false;
    }
    op.apply(x, &mut w.ap, &mut w.prl);
    let (b, ax, filters) = (&w.b, &w.ap, &op.filters);
    let [xb, xax, rr, bb] = rmi_par::for_each_sum(
        &mut w.r,
        #[inline(always)]
        |a, r| {
            *r = b[a] - ax[a];
            filters[a].apply(r);
            let mut bf = b[a];
            filters[a].apply(&mut bf);
            [x[a].dot(&b[a]), x[a].dot(&ax[a]), r.dot(r), bf.dot(&bf)]
        },
    );
    let theta = xb / xax;
    let accepted = rr.sqrt() <= tolerance * bb.sqrt().max(rhs_floor).max(1e-300);
    if !accepted && xax > 0.0 && theta.is_finite() {
        x.par_iter_mut().zip(w.ap.par_iter_mut()).for_each(|(xa, axa)| {
            *xa *= theta;
            *axa *= theta;
        });
    }
    true
}

#[cfg(test)]
mod tests {
    use super::super::constraints::filter;
    use super::scale_guess;
    use crate::config::{BodyConfig, Shape};
    use crate::solver::linalg::CgWork;
    use crate::{presets, Simulation};
    use nalgebra::Vector3;

    /// The response's guess is scaled to the multiple with the smallest energy-norm error: a
    /// multiple of the exact solution scales back to it (with its product), and any other
    /// guess's energy `x . A x / 2 - x . b` never grows.
    #[test]
    fn response_guess_scales_to_the_energy_optimal_multiple() {
        let mut sim = Simulation::new(presets::sponge([0.06, 0.06, 0.1], 0.6, 0.005), Some(2)).unwrap();
        sim.run(50).unwrap();
        sim.with_operator(|op| {
            let n = op.c.p.len();
            let mut w = CgWork::default();
            w.resize(n, op.c.p.n_solid());
            // A smooth, filtered velocity field as the exact solution y, and b = A y.
            let mut y: Vec<Vector3<f64>> = op.c.p.x.iter().map(|x| Vector3::new(x.z, -0.5 * x.x, 0.2 + x.y)).collect();
            filter(&mut y, &op.filters);
            let mut ay = vec![Vector3::zeros(); n];
            op.apply(&y, &mut ay, &mut w.prl);
            w.b.copy_from_slice(&ay);
            let mut x: Vec<Vector3<f64>> = y.iter().map(|v| 0.37 * v).collect();
            assert!(scale_guess(op, &mut x, &mut w, 0.0, 0.0));
            let scale = y.iter().map(|v| v.norm()).fold(0.0, f64::max);
            let ascale = ay.iter().map(|v| v.norm()).fold(0.0, f64::max);
            for a in 0..n {
                assert!((x[a] - y[a]).norm() < 1e-12 * scale, "particle {a}: {} against {}", x[a], y[a]);
                assert!((w.ap[a] - ay[a]).norm() < 1e-12 * ascale, "product of particle {a}");
            }
            // Another guess: the solution with a swirl added.
            let energy = |x: &[Vector3<f64>], ax: &[Vector3<f64>]| {
                x.iter().zip(ax).zip(&ay).map(|((xa, axa), b)| 0.5 * xa.dot(axa) - xa.dot(b)).sum::<f64>()
            };
            let mut x: Vec<Vector3<f64>> =
                y.iter().zip(&op.c.p.x).map(|(v, p)| 0.5 * v + Vector3::new(-p.y, p.x, 0.0)).collect();
            filter(&mut x, &op.filters);
            let mut ax = vec![Vector3::zeros(); n];
            op.apply(&x, &mut ax, &mut w.prl);
            let before = energy(&x, &ax);
            assert!(scale_guess(op, &mut x, &mut w, 0.0, 0.0));
            let after = energy(&x, &w.ap);
            assert!(after < before, "energy {after} after scaling, {before} before");
            // A zero guess is left alone, without a product.
            let mut zero = vec![Vector3::zeros(); n];
            assert!(!scale_guess(op, &mut zero, &mut w, 0.0, 0.0));
        });
    }

    /// A sponge with pore water on the floor, pressed by a plate from above at 2 cm/s (its
    /// contacts constraints of the implicit system): a step's pressure response is close to
    /// the last one's, so starting from it saves most of the CG's iterations, and the step ends
    /// where a response solved from zero ends. The guess this one replaced (the increment plus
    /// the last drag correction) does not meet the bound (docs/benchmark-history.md, "The
    /// pressure response starts from the last one").
    #[test]
    fn pressure_response_starts_from_the_last_one() {
        let mut cfg = presets::sponge([0.06, 0.06, 0.1], 0.6, 0.005);
        cfg.scene.bodies.push(BodyConfig {
            name: "plate".into(),
            shape: Shape::Box { half_extents: [0.05, 0.05, 0.01] },
            position: [0.0, 0.0, 0.1 + 0.01],
            rotation: [0.0; 3],
            kinematic: true,
        });
        let mut warm = Simulation::new(cfg.clone(), Some(2)).unwrap();
        warm.set_body_velocity(1, Vector3::new(0.0, 0.0, -0.02), Vector3::zeros()).unwrap();
        warm.run(100).unwrap();
        assert!(warm.contacts().len() > 40, "{} contacts: the plate must press", warm.contacts().len());
        let mut cold = Simulation::new(cfg, Some(2)).unwrap();
        let (mut iw, mut ic) = (0, 0);
        let norm = |v: &mut dyn Iterator<Item = f64>| v.sum::<f64>().sqrt();
        for _ in 0..150 {
            cold.restore(warm.snapshot()).unwrap();
            assert!(warm.response_prev.iter().any(|x| x.norm() > 0.0), "the sponge's water must respond");
            cold.response_prev.iter_mut().for_each(|x| *x = Vector3::zeros());
            warm.step().unwrap();
            cold.step().unwrap();
            iw += warm.stats().pressure_response.iterations;
            ic += cold.stats().pressure_response.iterations;
            let (vw, vc) = (&warm.particles().v, &cold.particles().v);
            let diff = norm(&mut vw.iter().zip(vc).map(|(a, b)| (a - b).norm_squared()));
            let size = norm(&mut vc.iter().map(|a| a.norm_squared()));
            // Both stop at a relative residual of 3e-3; the constraints' stiffness magnifies
            // that in the velocities.
            assert!(diff < 0.1 * size, "velocities differ by {diff} of {size} m/s (L2 norms)");
        }
        assert!(7 * iw <= 2 * ic, "150 steps: from the last response {iw} iterations, from zero {ic}");
    }

    /// A saturated sponge settled on the floor: the pressure's corrections move v but barely
    /// v*, so the line search lands near the last v* and needs fewer implicit iterations than
    /// the repeated last change alone (the guess when the search direction is zero), ending
    /// where that one ends.
    #[test]
    fn implicit_guess_line_search_beats_the_repeated_change_at_rest() {
        let cfg = presets::sponge([0.06, 0.06, 0.1], 0.6, 0.005);
        let mut search = Simulation::new(cfg.clone(), Some(2)).unwrap();
        search.run(500).unwrap();
        let mut first = Simulation::new(cfg, Some(2)).unwrap();
        let (mut is, mut i1) = (0, 0);
        for _ in 0..100 {
            first.restore(search.snapshot()).unwrap();
            // The last v* on the first guess: a zero search direction.
            let p = &first.p;
            for (a, vs) in first.vstar_prev.iter_mut().enumerate() {
                *vs = p.v[a] + first.dv_prev[a];
            }
            search.step().unwrap();
            first.step().unwrap();
            is += search.stats().cg.iterations;
            i1 += first.stats().cg.iterations;
            let (vs, v1) = (&search.particles().v, &first.particles().v);
            let diff = vs.iter().zip(v1).map(|(a, b)| (a - b).norm_squared()).sum::<f64>().sqrt();
            // At rest the velocities are the solve's error; its scale is what gravity adds in a
            // step (the right-hand side's), and both stop at a relative residual of 3e-3.
            let scale = 9.81 * search.config().dt * (v1.len() as f64).sqrt();
            assert!(diff < 0.03 * scale, "velocities differ by {diff} m/s (L2 norm; gravity's step {scale} m/s)");
        }
        assert!(i1 > 0, "the repeated change must need iterations");
        assert!(3 * is <= 2 * i1, "100 steps: with the line search {is} implicit iterations, the first guess {i1}");
    }
}
