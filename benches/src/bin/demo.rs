//! The main job's demo: a saturated 10 x 10 x 20 cm sponge (phi = 0.6) stands on a floor and
//! drains under gravity. Prints particle counts, solver figures and retained water over time.
//!
//! `demo [--radius 0.005] [--seconds 0.3] [--threads 2] [--preconditioner auto|two_level|
//! block_jacobi|identity] [--coarse-cell 4] [--coarse-steps 10] [--cg-tolerance 3e-3]
//! [--single-solve]`; the last
//! line is a checksum of the final state, for comparing builds and thread counts bit for bit.
//! `--cg-tolerance 1e-4` is the reference PIISPH's setting; `--single-solve` sets
//! `pressure.single_solve`.

use rmi_benches::{fail, Args};
use rmi_sph::{presets, Simulation};
use std::time::Instant;

fn main() {
    let args = Args::parse(
        &[
            "--radius",
            "--seconds",
            "--threads",
            "--preconditioner",
            "--coarse-cell",
            "--coarse-steps",
            "--cg-tolerance",
        ],
        &["--single-solve"],
    );
    let radius: f64 = args.value("--radius", 0.005);
    let seconds: f64 = args.value("--seconds", 0.3);
    let threads: usize = args.value("--threads", 2);
    let size = presets::SPONGE_SIZES[1];
    let mut cfg = presets::sponge(size, 0.6, radius);
    if let Some(p) = args.text("--preconditioner") {
        cfg.cg.preconditioner = match serde_json::from_value(serde_json::Value::String(p.to_owned())) {
            Ok(p) => p,
            Err(e) => fail(&format!("--preconditioner {p}: {e}")),
        };
    }
    cfg.cg.coarse_cell = args.value("--coarse-cell", cfg.cg.coarse_cell);
    cfg.cg.coarse_steps = args.value("--coarse-steps", cfg.cg.coarse_steps);
    cfg.cg.tolerance = args.value("--cg-tolerance", cfg.cg.tolerance);
    cfg.pressure.single_solve = args.flag("--single-solve");
    let mut sim = match Simulation::new(cfg, Some(threads)) {
        Ok(s) => s,
        Err(e) => fail(&e.to_string()),
    };
    let p = sim.particles();
    let (nf, ns) = (p.n_fluid, p.n_solid());
    let water_mass = |sim: &Simulation| -> f64 {
        // Water whose centre lies inside the skeleton's current bounding box counts as held.
        let p = sim.particles();
        let mut lo = nalgebra::Vector3::repeat(f64::INFINITY);
        let mut hi = -lo;
        for x in &p.x[p.n_fluid..] {
            lo = lo.inf(x);
            hi = hi.sup(x);
        }
        let r = sim.radius();
        (0..p.n_fluid)
            .filter(|&a| (0..3).all(|k| p.x[a][k] >= lo[k] - r && p.x[a][k] <= hi[k] + r))
            .map(|a| p.mass[a])
            .sum()
    };
    println!(
        "rmi demo: saturated {:.0}x{:.0}x{:.0} cm sponge, phi = 0.6, r = {:.1} mm, {} threads",
        size[0] * 100.0,
        size[1] * 100.0,
        size[2] * 100.0,
        radius * 1e3,
        threads
    );
    let weight = 9.81 * sim.particles().mass.iter().sum::<f64>();
    println!("particles: {nf} water, {ns} skeleton, {} boundary; total weight {weight:.2} N", sim.boundary().x.len());
    let m0 = water_mass(&sim);
    println!(
        "{:>7} {:>10} {:>10} {:>8} {:>8} {:>10}",
        "t (s)", "water (g)", "ms/step", "p-iter", "cg-iter", "floor (N)"
    );
    let steps = (seconds / sim.dt()).round() as u64;
    let report = (steps / 6).max(1);
    let t0 = Instant::now();
    let mut last = Instant::now();
    let (mut piters, mut cgiters, mut respiters) = (0u64, 0u64, 0u64);
    // The instantaneous floor load alternates from step to step (relaxed Jacobi with a half
    // warm start); the table shows its mean over each reporting interval.
    let mut floor_sum = 0.0;
    let mut phase = [0.0f64; 6];
    for i in 1..=steps {
        if let Err(e) = sim.step() {
            eprintln!("error: {e}");
            std::process::exit(1);
        }
        piters += sim.stats().pressure.iterations as u64;
        cgiters += sim.stats().cg.iterations as u64;
        respiters += sim.stats().pressure_response.iterations as u64;
        for (acc, sec) in phase.iter_mut().zip(sim.stats().seconds) {
            *acc += sec;
        }
        floor_sum -= sim.boundary().bodies[0].force.z;
        if i % report == 0 || i == steps {
            let ms = 1e3 * last.elapsed().as_secs_f64() / report as f64;
            last = Instant::now();
            let floor = floor_sum / report as f64;
            floor_sum = 0.0;
            println!(
                "{:7.3} {:10.1} {:10.1} {:8} {:8} {:10.2}",
                sim.time(),
                1e3 * water_mass(&sim),
                ms,
                sim.stats().pressure.iterations,
                sim.stats().cg.iterations,
                floor
            );
        }
    }
    let wall = t0.elapsed().as_secs_f64();
    let sat: Vec<f64> = sim.fields().saturation[nf..].to_vec();
    let mean_sat = sat.iter().sum::<f64>() / sat.len().max(1) as f64;
    println!("summary: {steps} steps in {wall:.1} s ({:.1} ms/step, {:.3} simulated s per wall s), mean iterations: pressure {:.1}, CG {:.1}, pressure-response CG {:.1}", 1e3 * wall / steps as f64, seconds / wall, piters as f64 / steps as f64, cgiters as f64 / steps as f64, respiters as f64 / steps as f64);
    let ms = |k: usize| 1e3 * phase[k] / steps as f64;
    println!(
        "phases (ms/step): neighbours {:.1}, fields {:.1}, implicit solve {:.1}, pressure {:.1}, pressure response {:.1}, other {:.1}",
        ms(0),
        ms(1),
        ms(2),
        ms(3),
        ms(4),
        ms(5)
    );
    println!(
        "water held: {:.1} g of {:.1} g; mean skeleton saturation {:.3}",
        1e3 * water_mass(&sim),
        1e3 * m0,
        mean_sat
    );
    // A fingerprint of the whole final state (SipHash with fixed keys over the snapshot's
    // fields, as JSON, whose numbers round-trip exactly): equal across thread counts and
    // across builds that keep the arithmetic. The config is left out, so that builds whose
    // configs differ only in fields the state does not depend on still compare.
    let s = sim.snapshot();
    let state = (
        s.time,
        s.step,
        &s.particles,
        &s.solid,
        &s.kappa_dt2,
        &s.dv_prev,
        &s.response_prev,
        &s.contact_load,
        &s.bodies,
    );
    let mut hasher = std::hash::DefaultHasher::new();
    std::hash::Hasher::write(&mut hasher, &serde_json::to_vec(&state).expect("state serialises"));
    println!("state checksum: {:016x}", std::hash::Hasher::finish(&hasher));
}
