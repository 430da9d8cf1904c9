//! Porosity-aware pressure solve: relaxed Jacobi IISPH in the DFSPH-factor form of
//! docs/physics.md §2.6, with per-material convergence on the mean compression.
//!
//! The unknown is kappa = p / rho (m^2/s^2, "pressure over density"); the pressure
//! acceleration of a fluid pair is `-V (kappa_a + kappa_b) grad W`. The water-water part of
//! every pair sum (most pairs of any scene) is evaluated in the position-free form of
//! [`crate::neighbourhood::pairsum`]: each pass writes one 32-byte record per particle that the next pass
//! gathers, so a pair costs one gather and a four-wide multiply-add. While no skeleton particle
//! carries pressure (a compressible skeleton's own density stays below rest), the skeleton's
//! rows of the iterations are exact zeros and are skipped, and a water particle's skeleton
//! pairs, which then involve its own values only, are one vector per particle that the
//! density pass keeps (`sum_b (1 - phi_b) V grad W_ab`); otherwise the skeleton's pairs keep
//! the direct form.

use crate::neighbourhood::pairsum::{self, Frame, Rec4};
use crate::solver::ctx::Ctx;
use crate::solver::density::DensityFields;
use nalgebra::Vector3;
use rayon::prelude::*;
use rmi_par as par;

/// Materials (water first, then the porous objects) whose mean compression the iterations'
/// update pass sums as it goes.
const FUSED_MATERIALS: usize = 4;

/// Force (N) and torque about the body centre (N m) on one body.
pub type BodyLoad = (Vector3<f64>, Vector3<f64>);

/// Solver settings resolved from the config.
#[derive(Clone, Copy, Debug)]
pub struct PressureSettings {
    /// Allowed mean compression (fraction).
    pub max_error: f64,
    /// Minimum iterations.
    pub min_iterations: u32,
    /// Maximum iterations.
    pub max_iterations: u32,
    /// Relaxation factor.
    pub omega: f64,
    /// Warm start from the previous step.
    pub warm_start: bool,
    /// Fraction of the previous pressure used as the warm start.
    pub warm_start_factor: f64,
    /// Skip the skeleton's rows of the iterations while no skeleton particle carries pressure:
    /// a compressible skeleton's own density stays below its rest value, so its kappa is zero
    /// in nearly every scene and those rows sum nothing but zeros (the same bits either way;
    /// `true` from a config).
    pub skip_idle_skeleton: bool,
}

impl From<&crate::config::PressureConfig> for PressureSettings {
    fn from(p: &crate::config::PressureConfig) -> Self {
        PressureSettings {
            max_error: p.max_error,
            min_iterations: p.min_iterations,
            max_iterations: p.max_iterations,
            omega: p.omega,
            warm_start: p.warm_start,
            warm_start_factor: p.warm_start_factor,
            skip_idle_skeleton: true,
        }
    }
}

/// What one pressure solve did.
#[derive(Clone, Debug, Default)]
pub struct PressureStats {
    /// Iterations performed.
    pub iterations: u32,
    /// Final mean compression per material (index 0 = fluid, 1 + k = object k).
    pub error: Vec<f64>,
}

/// Work arrays kept between steps to avoid reallocation.
#[derive(Clone, Debug, Default)]
pub struct PressureWork {
    source: Vec<f64>,
    ap: Vec<Vector3<f64>>,
    err: Vec<f64>,
    /// Per particle `[kappa x, kappa]` (the acceleration pass's records).
    rk: Vec<Rec4>,
    /// The lists' positions relative to their centre, for the record sums of [`pairsum`].
    frame: Frame,
    /// Per particle `[q, q . x]` of the vector field being differentiated (the predicted
    /// velocity in the source pass, the pressure acceleration in the iterations).
    rq: Vec<Rec4>,
}

/// What the water-pair sums read in [`pairsum`] form: the lists' shifted positions, the
/// neighbours' records and `sum_b V grad W_ab` over the water neighbours; and, where a pass
/// takes its water-skeleton pairs in sum form, [`DensityFields::solid_grad`].
#[derive(Clone, Copy)]
struct WaterPairs<'a> {
    x: &'a [Vector3<f64>],
    rec: &'a [Rec4],
    grad: &'a [Vector3<f64>],
    solid_grad: Option<&'a [Vector3<f64>]>,
}

/// The volume factors of docs/physics.md §1 that the pressure passes need, per particle, so
/// that the pair loops read one number instead of walking particle -> object -> material
/// (the values are those of [`Ctx::volume_factor`], bit for bit).
struct Factors {
    /// For a skeleton particle b: `f(water <- b) = 1 - phi_b`.
    from_solid: Vec<f64>,
    /// For a skeleton particle a: `f(a <- b)` for b of a's own material.
    same: Vec<f64>,
}

impl Factors {
    fn new(c: &Ctx) -> Self {
        let n = c.p.len();
        let nf = c.p.n_fluid;
        let mut from_solid = vec![0.0; n];
        let mut same = vec![0.0; n];
        for a in nf..n {
            // The expressions of `Ctx::volume_factor`'s water <- skeleton and same-material arms.
            from_solid[a] = 1.0 - c.object(a).material.porosity;
            same[a] = c.volume_factor(a, a);
        }
        Factors { from_solid, same }
    }

    /// `f(a <- b)` for skeleton particles a and b.
    #[inline(always)]
    fn solid_pair(&self, c: &Ctx, a: usize, b: usize) -> f64 {
        if c.p.material[a] == c.p.material[b] {
            self.same[a]
        } else {
            1.0
        }
    }
}

/// Pressure acceleration of particle `a` for the current kappa; `w.rec` holds the records
/// `[kappa x, kappa]` of the same kappa. `solid_live` is false when every skeleton kappa is
/// zero: a skeleton row is then exactly zero and is not summed.
#[inline(always)]
#[allow(clippy::too_many_arguments)]
fn accel(
    c: &Ctx,
    fs: &Factors,
    a: usize,
    kappa: &[f64],
    rho0: &[f64],
    gb: &[Vector3<f64>],
    w: WaterPairs,
    solid_live: bool,
) -> Vector3<f64> {
    let nb = c.nb.of(a);
    let ka = kappa[a];
    let v = c.vol;
    let mut acc = Vector3::zeros();
    if c.p.is_fluid(a) {
        // -sum_b V (kappa_a + kappa_b) grad W_ab over the water pairs (see `pairsum`).
        let t = pairsum::weighted(&nb.j[..nb.n_fluid], &nb.gf()[..nb.n_fluid], w.rec);
        acc = -(ka * w.grad[a] + v * (w.x[a] * t.0[3] - t.xyz()));
        // The skeleton pairs carry kappa_a alone: -kappa_a sum_b (1 - phi_b) V grad W_ab.
        match w.solid_grad {
            Some(sg) => acc -= ka * sg[a],
            None => {
                for k in nb.n_fluid..nb.j.len() {
                    let b = nb.j[k] as usize;
                    acc -= (fs.from_solid[b] * v * ka) * nb.g(k);
                }
            }
        }
    } else if solid_live {
        let r0a = rho0[a];
        for k in nb.n_fluid..nb.j.len() {
            let b = nb.j[k] as usize;
            // One symmetric factor: the reference's extra f(b <- a) on kappa_b makes the pair
            // forces of a compressible skeleton unequal (net force V^2 f (1 - f) grad W
            // (rho0 kappa_b - rho0 kappa_a)), which pushed resting sponges into the floor.
            let f_ab = fs.solid_pair(c, a, b);
            // x / x is exactly 1: skip the division within one material.
            let ratio = if rho0[b] == r0a { 1.0 } else { rho0[b] / r0a };
            acc -= (f_ab * v * (ka + ratio * kappa[b])) * nb.g(k);
        }
    } else {
        // Every term is a signed zero and `acc` starts at +0: the sum would be +0, and
        // `gb[a]` is zero for the skeleton.
        return Vector3::zeros();
    }
    acc - ka * gb[a]
}

/// Divergence-like sum `sum_b f V (q_a - q_b) . grad W_ab` over dynamic neighbours; `w.rec`
/// holds the records `[q, q . x]` of the same `q`. `solid_live` false says that `q` is zero
/// on every skeleton particle (the pressure accelerations of a skeleton without pressure):
/// a skeleton row, which sums over skeleton neighbours only, is then +0 and is not summed,
/// and with `w.solid_grad` a water row's skeleton pairs reduce to `q_a . solid_grad_a`.
#[inline(always)]
fn div(c: &Ctx, fs: &Factors, a: usize, q: &[Vector3<f64>], w: WaterPairs, solid_live: bool) -> f64 {
    let nb = c.nb.of(a);
    let v = c.vol;
    let qa = q[a];
    let mut s = 0.0;
    if c.p.is_fluid(a) {
        let t = pairsum::weighted(&nb.j[..nb.n_fluid], &nb.gf()[..nb.n_fluid], w.rec);
        s = qa.dot(&w.grad[a]) - v * (w.x[a].dot(&t.xyz()) - t.0[3]);
        match w.solid_grad {
            // q_a . sum f V grad W minus the skeleton's q_b part (a sum of zeros while no
            // skeleton particle carries pressure, which the skip leaves out).
            Some(sg) => {
                s += qa.dot(&sg[a]);
                if solid_live {
                    let mut sq = 0.0;
                    for k in nb.n_fluid..nb.j.len() {
                        let b = nb.j[k] as usize;
                        sq += fs.from_solid[b] * v * q[b].dot(&nb.g(k));
                    }
                    s -= sq;
                }
            }
            // The difference form, for the source pass: neighbouring velocities share a
            // common part, which the sum form would cancel only after rounding it.
            None => {
                for k in nb.n_fluid..nb.j.len() {
                    let b = nb.j[k] as usize;
                    s += fs.from_solid[b] * v * (qa - q[b]).dot(&nb.g(k));
                }
            }
        }
    } else if solid_live {
        for k in nb.n_fluid..nb.j.len() {
            let b = nb.j[k] as usize;
            s += fs.solid_pair(c, a, b) * v * (qa - q[b]).dot(&nb.g(k));
        }
    }
    s
}

/// Runs the pressure solve on the predicted velocities `v` (updated in place).
///
/// `kappa_dt2` holds kappa * dt^2 of the previous step on entry (warm start) and of this
/// step on exit. Returns the body reaction forces and torques (N, N m) per body.
#[allow(clippy::too_many_arguments)]
pub fn solve(
    c: &Ctx,
    dens: &DensityFields,
    settings: &PressureSettings,
    rho0: &[f64],
    v: &mut [Vector3<f64>],
    kappa: &mut Vec<f64>,
    kappa_dt2: &mut [f64],
    work: &mut PressureWork,
    n_materials: usize,
) -> (PressureStats, Vec<BodyLoad>) {
    let n = c.p.len();
    let dt = c.dt;
    let dt2 = dt * dt;
    work.source.resize(n, 0.0);
    work.ap.resize(n, Vector3::zeros());
    work.err.resize(n, 0.0);
    let fs = &Factors::new(c);
    kappa.resize(n, 0.0);
    // Per particle `sum_k V_k grad W_ak` over boundary neighbours (1/m; zero for the skeleton:
    // only water feels boundary pressure, the skeleton meets bodies through contacts).
    let gb = &dens.boundary_grad;
    let xl = c.nb.target_positions();
    assert_eq!(xl.len(), n, "the pressure passes need lists over the dynamic particles");
    work.frame.rebuild(xl);
    let x = &work.frame.x;
    work.rk.resize(n, Rec4::default());
    work.rq.resize(n, Rec4::default());
    // Without a skeleton there are no such pairs, and the pure-water solve keeps its bits.
    let sg = (c.p.n_solid() > 0).then_some(dens.solid_grad.as_slice());
    let vv: &[Vector3<f64>] = v;
    par::for_each_hot(
        &mut work.rq,
        #[inline(always)]
        |a, r| *r = Rec4::vector_moment(&vv[a], &x[a]),
    );
    {
        let w = WaterPairs { x, rec: &work.rq, grad: &dens.fluid_grad, solid_grad: None };
        let kdt2: &[f64] = kappa_dt2;
        par::for_each_hot3(
            &mut work.source,
            kappa,
            &mut work.rk,
            #[inline(always)]
            |a, s, ka, r| {
                // The walls' part of the velocity divergence, sum V_k (v_a - v_k) . grad W_ak.
                let bdiv = vv[a].dot(&gb[a]) - dens.boundary_flux[a];
                let rho_adv = dens.rho_ratio[a] + dt * (div(c, fs, a, vv, w, true) + bdiv);
                *s = 1.0 - rho_adv;
                *ka = if settings.warm_start && rho_adv > 1.0 {
                    settings.warm_start_factor * kdt2[a].min(2.5e-4) / dt2
                } else {
                    0.0
                };
                *r = Rec4::scaled_position(*ka, &x[a]);
            },
        );
    }
    let counts: Vec<f64> =
        (0..n_materials).map(|m| c.p.material.iter().filter(|&&x| x as usize == m).count().max(1) as f64).collect();
    let mut stats = PressureStats { iterations: 0, error: vec![0.0; n_materials] };
    let eta = settings.max_error;
    // Whether any skeleton particle carries pressure: while none does, the skeleton's rows of
    // the iterations are exact zeros and are skipped (a sponge that is not compressed).
    let nf = c.p.n_fluid;
    let live = |kappa: &[f64]| !settings.skip_idle_skeleton || kappa[nf..].iter().any(|&k| k != 0.0);
    let mut solid_live = live(kappa);
    loop {
        {
            let kap: &[f64] = kappa;
            let w = WaterPairs { x, rec: &work.rk, grad: &dens.fluid_grad, solid_grad: sg };
            par::for_each_hot2(
                &mut work.ap,
                &mut work.rq,
                #[inline(always)]
                |a, ap, r| {
                    *ap = accel(c, fs, a, kap, rho0, gb, w, solid_live);
                    *r = Rec4::vector_moment(ap, &x[a]);
                },
            );
        }
        let mat = &c.p.material;
        // The first FUSED_MATERIALS materials' compression sums come out of the update pass
        // (each with the bits of its own `par::sum`); any further material's get a pass each.
        let fused = {
            let ap: &[Vector3<f64>] = &work.ap;
            let source = &work.source;
            let w = WaterPairs { x, rec: &work.rq, grad: &dens.fluid_grad, solid_grad: sg };
            par::for_each3_sum(
                kappa,
                &mut work.err,
                &mut work.rk,
                #[inline(always)]
                |a, ka, e, r| {
                    let akappa = dt2 * (div(c, fs, a, ap, w, solid_live) + ap[a].dot(&gb[a]));
                    let residual = source[a] - akappa;
                    *e = (-residual).max(0.0);
                    let alpha = dens.alpha[a];
                    *ka = if alpha > 0.0 { (*ka - settings.omega * residual * alpha / dt2).max(0.0) } else { 0.0 };
                    *r = Rec4::scaled_position(*ka, &x[a]);
                    let mut sums = [0.0; FUSED_MATERIALS];
                    if let Some(s) = sums.get_mut(mat[a] as usize) {
                        *s = *e;
                    }
                    sums
                },
            )
        };
        stats.iterations += 1;
        solid_live = live(kappa);
        let mut converged = true;
        for (m, em) in stats.error.iter_mut().enumerate() {
            let errs = &work.err;
            let total = match fused.get(m) {
                Some(s) => *s,
                None => par::sum(n, |a| if mat[a] as usize == m { errs[a] } else { 0.0 }),
            };
            *em = total / counts[m];
            if *em > eta {
                converged = false;
            }
        }
        if (converged && stats.iterations >= settings.min_iterations) || stats.iterations >= settings.max_iterations {
            break;
        }
    }
    // Apply the pressure of the final kappa.
    {
        let kap: &[f64] = kappa;
        let w = WaterPairs { x, rec: &work.rk, grad: &dens.fluid_grad, solid_grad: sg };
        par::for_each_hot2(
            v,
            kappa_dt2,
            #[inline(always)]
            |a, va, kt| {
                *va += dt * accel(c, fs, a, kap, rho0, gb, w, solid_live);
                *kt = kap[a] * dt2;
            },
        );
    }
    let reactions = body_reactions(c, kappa);
    (stats, reactions)
}

/// Force and torque of the dynamic particles' pressure on each body: `m_a kappa_a V_k grad W_ak`.
fn body_reactions(c: &Ctx, kappa: &[f64]) -> Vec<(Vector3<f64>, Vector3<f64>)> {
    let nbody = c.bnd.bodies.len();
    let n = c.p.len();
    let chunk = par::REDUCE_CHUNK;
    let partial: Vec<Vec<(Vector3<f64>, Vector3<f64>)>> = (0..n.div_ceil(chunk))
        .into_par_iter()
        .map(|ci| {
            let mut acc = vec![(Vector3::zeros(), Vector3::zeros()); nbody];
            rmi_par::cpu::hot(
                #[inline(always)]
                || body_reactions_of(c, kappa, ci * chunk..((ci + 1) * chunk).min(n), &mut acc),
            );
            acc
        })
        .collect();
    let mut out = vec![(Vector3::zeros(), Vector3::zeros()); nbody];
    for p in partial {
        for (o, q) in out.iter_mut().zip(p) {
            o.0 += q.0;
            o.1 += q.1;
        }
    }
    out
}

/// Adds the loads of the particles in `range` to `acc` (per body), in particle and list order.
#[inline(always)]
fn body_reactions_of(c: &Ctx, kappa: &[f64], range: std::ops::Range<usize>, acc: &mut [BodyLoad]) {
    for a in range {
        if kappa[a] == 0.0 || !c.p.is_fluid(a) {
            continue;
        }
        let nbb = c.nbb.of(a);
        for k in 0..nbb.j.len() {
            let kk = nbb.j[k] as usize;
            let bi = c.bnd.body[kk] as usize;
            let f = (c.p.mass[a] * kappa[a] * c.bnd.volume[kk]) * nbb.g(k);
            acc[bi].0 += f;
            acc[bi].1 += (c.bnd.x[kk] - c.bnd.bodies[bi].state.position).cross(&f);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::{presets, Simulation};

    /// Solves the next step's pressure problem of `sim` with and without the skip of an idle
    /// skeleton and asserts the same bits; returns whether the skeleton carried pressure.
    /// `cold`: without the warm start, so that every kappa starts at zero (an idle skeleton
    /// that turns live within the solve).
    fn skip_is_exact(sim: &mut Simulation, cold: bool) -> bool {
        let cfg = sim.config().clone();
        let ps = PressureSettings::from(&cfg.pressure);
        sim.with_pressure_problem(|c, dens, rho0, v, kdt2| {
            let run = |skip: bool| {
                let (mut v, mut kdt2) = (v.to_vec(), kdt2.to_vec());
                if cold {
                    kdt2.iter_mut().for_each(|k| *k = 0.0);
                }
                let mut kappa = Vec::new();
                let ps = PressureSettings { skip_idle_skeleton: skip, ..ps };
                let (st, loads) = solve(
                    c,
                    dens,
                    &ps,
                    rho0,
                    &mut v,
                    &mut kappa,
                    &mut kdt2,
                    &mut PressureWork::default(),
                    1 + c.objects.len(),
                );
                (st.iterations, st.error, loads, v, kappa, kdt2)
            };
            let (skipped, full) = (run(true), run(false));
            assert!(skipped.0 > 2, "the solve should iterate: {} iterations", skipped.0);
            let bits = |x: &[f64]| x.iter().map(|v| v.to_bits()).collect::<Vec<_>>();
            let vbits = |x: &[Vector3<f64>]| x.iter().flat_map(|v| v.iter().map(|e| e.to_bits())).collect::<Vec<_>>();
            assert_eq!(skipped.0, full.0);
            assert_eq!(bits(&skipped.1), bits(&full.1));
            assert_eq!(skipped.2, full.2);
            assert_eq!(vbits(&skipped.3), vbits(&full.3), "velocities");
            assert_eq!(bits(&skipped.4), bits(&full.4), "kappa");
            assert_eq!(bits(&skipped.5), bits(&full.5), "kappa dt^2");
            full.4[c.p.n_fluid..].iter().any(|&k| k != 0.0)
        })
    }

    #[test]
    fn skipping_an_idle_skeleton_changes_no_bit() {
        // A compressible skeleton: its own density stays below rest, its rows are skipped.
        let mut sim = Simulation::new(presets::sponge([0.04, 0.04, 0.06], 0.6, 0.004), Some(2)).unwrap();
        sim.run(20).unwrap();
        assert!(!skip_is_exact(&mut sim, false), "a compressible skeleton should carry no pressure");
    }

    #[test]
    fn a_skeleton_under_pressure_is_solved_in_full() {
        // An incompressible skeleton on a floor, pressed by its own weight: its kappa turns
        // positive, and the solve must equal the unskipped one while it does.
        let mut cfg = presets::sponge([0.04, 0.04, 0.06], 0.6, 0.004);
        cfg.scene.porous_blocks[0].material.compressible = false;
        let mut sim = Simulation::new(cfg, Some(2)).unwrap();
        let (mut live, mut turned_live) = (0, 0);
        for _ in 0..10 {
            sim.run(2).unwrap();
            live += skip_is_exact(&mut sim, false) as u32;
            turned_live += skip_is_exact(&mut sim, true) as u32;
        }
        assert!(live > 0, "the skeleton never carried pressure");
        assert!(turned_live > 0, "the skeleton never turned live from a cold start");
    }
}
