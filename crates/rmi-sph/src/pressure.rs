//! Porosity-aware pressure solve: relaxed Jacobi IISPH in the DFSPH-factor form of
//! physics.md sec. 2 step 10, with per-material convergence on the mean compression.
//!
//! The unknown is kappa = p / rho (m^2/s^2, "pressure over density"); the pressure
//! acceleration of a fluid pair is `-V (kappa_a + kappa_b) grad W`.

use crate::ctx::Ctx;
use crate::density::DensityFields;
use crate::par;
use nalgebra::Vector3;
use rayon::prelude::*;

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
    /// Per particle `sum_k V_k grad W_ak` over boundary neighbours (constant within a step).
    gb: Vec<Vector3<f64>>,
    ap: Vec<Vector3<f64>>,
    err: Vec<f64>,
}

/// The volume factors of physics.md sec. 1 that the pressure passes need, per particle, so
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

/// Pressure acceleration of particle `a` for the current kappa.
#[inline(always)]
fn accel(c: &Ctx, fs: &Factors, a: usize, kappa: &[f64], rho0: &[f64], gb: &[Vector3<f64>]) -> Vector3<f64> {
    let nb = c.nb.of(a);
    let ka = kappa[a];
    let v = c.vol;
    let mut acc = Vector3::zeros();
    if c.p.is_fluid(a) {
        for k in 0..nb.n_fluid {
            acc -= (v * (ka + kappa[nb.j[k] as usize])) * nb.g(k);
        }
        for k in nb.n_fluid..nb.j.len() {
            let b = nb.j[k] as usize;
            acc -= (fs.from_solid[b] * v * ka) * nb.g(k);
        }
    } else {
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
    }
    acc - ka * gb[a]
}

/// Divergence-like sum `sum_b f V (q_a - q_b) . grad W_ab` over dynamic neighbours.
#[inline(always)]
fn div(c: &Ctx, fs: &Factors, a: usize, q: &[Vector3<f64>]) -> f64 {
    let nb = c.nb.of(a);
    let v = c.vol;
    let qa = q[a];
    let mut s = 0.0;
    if c.p.is_fluid(a) {
        for k in 0..nb.n_fluid {
            s += v * (qa - q[nb.j[k] as usize]).dot(&nb.g(k));
        }
        for k in nb.n_fluid..nb.j.len() {
            let b = nb.j[k] as usize;
            s += fs.from_solid[b] * v * (qa - q[b]).dot(&nb.g(k));
        }
    } else {
        for k in nb.n_fluid..nb.j.len() {
            let b = nb.j[k] as usize;
            s += fs.solid_pair(c, a, b) * v * (qa - q[b]).dot(&nb.g(k));
        }
    }
    s
}

/// The boundary sums of particle `a`, one walk over its wall neighbours: `sum_k V_k grad W_ak`
/// (1/m, constant within a step) and the boundary part of the velocity divergence,
/// `sum_k V_k (v_a - v_k) . grad W_ak` (1/s). Both zero for the skeleton: only water feels
/// boundary pressure, the skeleton meets bodies through contacts.
#[inline(always)]
fn boundary_sums(c: &Ctx, a: usize, va: &Vector3<f64>) -> (Vector3<f64>, f64) {
    let mut gb = Vector3::zeros();
    let mut s = 0.0;
    if !c.p.is_fluid(a) {
        return (gb, s);
    }
    let nbb = c.nbb.of(a);
    for k in 0..nbb.j.len() {
        let kk = nbb.j[k] as usize;
        let g = nbb.g(k);
        gb += c.bnd.volume[kk] * g;
        s += c.bnd.volume[kk] * (va - c.bnd.v[kk]).dot(&g);
    }
    (gb, s)
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
    work.gb.resize(n, Vector3::zeros());
    work.ap.resize(n, Vector3::zeros());
    work.err.resize(n, 0.0);
    let fs = &Factors::new(c);
    kappa.resize(n, 0.0);
    {
        let vv: &[Vector3<f64>] = v;
        let source = &mut work.source;
        let kdt2: &[f64] = kappa_dt2;
        par::for_each_hot3(
            source,
            kappa,
            &mut work.gb,
            #[inline(always)]
            |a, s, ka, gb| {
                let (g, bdiv) = boundary_sums(c, a, &vv[a]);
                *gb = g;
                let rho_adv = dens.rho_ratio[a] + dt * (div(c, fs, a, vv) + bdiv);
                *s = 1.0 - rho_adv;
                *ka = if settings.warm_start && rho_adv > 1.0 {
                    settings.warm_start_factor * kdt2[a].min(2.5e-4) / dt2
                } else {
                    0.0
                };
            },
        );
    }
    let counts: Vec<f64> =
        (0..n_materials).map(|m| c.p.material.iter().filter(|&&x| x as usize == m).count().max(1) as f64).collect();
    let mut stats = PressureStats { iterations: 0, error: vec![0.0; n_materials] };
    let eta = settings.max_error;
    loop {
        {
            let kap: &[f64] = kappa;
            let gb = &work.gb;
            par::for_each_hot(
                &mut work.ap,
                #[inline(always)]
                |a, ap| *ap = accel(c, fs, a, kap, rho0, gb),
            );
        }
        {
            let ap: &[Vector3<f64>] = &work.ap;
            let source = &work.source;
            let gb = &work.gb;
            par::for_each_hot2(
                kappa,
                &mut work.err,
                #[inline(always)]
                |a, ka, e| {
                    let akappa = dt2 * (div(c, fs, a, ap) + ap[a].dot(&gb[a]));
                    let residual = source[a] - akappa;
                    *e = (-residual).max(0.0);
                    let alpha = dens.alpha[a];
                    *ka = if alpha > 0.0 { (*ka - settings.omega * residual * alpha / dt2).max(0.0) } else { 0.0 };
                },
            );
        }
        stats.iterations += 1;
        let mut converged = true;
        for (m, em) in stats.error.iter_mut().enumerate() {
            let mat = &c.p.material;
            let errs = &work.err;
            *em = par::sum(n, |a| if mat[a] as usize == m { errs[a] } else { 0.0 }) / counts[m];
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
        let gb = &work.gb;
        par::for_each_hot2(
            v,
            kappa_dt2,
            #[inline(always)]
            |a, va, kt| {
                *va += dt * accel(c, fs, a, kap, rho0, gb);
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
            crate::cpu::hot(
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
