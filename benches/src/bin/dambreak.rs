//! Runs the SPlisHSPlasH DamBreakModel scene in rmi-sph and prints one JSON line of figures.
//!
//! `dambreak --steps 500 --threads 2 --radius 0.0125 [--reach N] [--json]`. Setup is excluded from
//! timing; `--reach` overrides the preset's `SimConfig::neighbour_reach`.

use rmi_benches::{fail, peak_rss_bytes, Args};
use rmi_sph::{presets, Simulation};
use std::time::Instant;

fn main() {
    let args = Args::parse(&["--steps", "--threads", "--radius", "--reach"], &["--json"]);
    let steps: u64 = args.value("--steps", 500);
    let threads: usize = args.value("--threads", 2);
    let radius: f64 = args.value("--radius", 0.0125);
    let json = args.flag("--json");
    let mut cfg = presets::dam_break(radius);
    cfg.neighbour_reach = args.value("--reach", cfg.neighbour_reach);
    let mut sim = match Simulation::new(cfg, Some(threads)) {
        Ok(s) => s,
        Err(e) => fail(&e.to_string()),
    };
    let nf = sim.particles().n_fluid;
    let mut iters = 0u64;
    let mut phase = [0.0f64; 6];
    let mut err_sum = 0.0;
    let mut pairs = 0u64;
    let t0 = Instant::now();
    for i in 0..steps {
        if let Err(e) = sim.step() {
            eprintln!("error: {e}");
            std::process::exit(1);
        }
        let st = sim.stats();
        iters += st.pressure.iterations as u64;
        err_sum += st.pressure.error[0];
        pairs += st.neighbour_pairs as u64;
        for (acc, sec) in phase.iter_mut().zip(st.seconds) {
            *acc += sec;
        }
        if !json && (i + 1) % 100 == 0 {
            eprintln!(
                "step {} t={:.3}s iters={} err={:.2e}",
                i + 1,
                sim.time(),
                st.pressure.iterations,
                st.pressure.error[0]
            );
        }
    }
    let wall = t0.elapsed().as_secs_f64();
    let ms_step = 1e3 * wall / steps as f64;
    let mean_it = iters as f64 / steps as f64;
    let out = serde_json::json!({
        "engine": "rmi",
        "fluid_particles": nf,
        "boundary_particles": sim.boundary().x.len(),
        "steps": steps,
        "threads": threads,
        "ms_per_step": ms_step,
        "mean_pressure_iterations": mean_it,
        "ms_per_pressure_iteration": 1e3 * phase[3] / iters.max(1) as f64,
        "particle_steps_per_s": nf as f64 * steps as f64 / wall,
        "mean_density_error": err_sum / steps as f64,
        "mean_neighbours_per_particle": pairs as f64 / (steps.max(1) * nf.max(1) as u64) as f64,
        "phase_ms_per_step": {
            "neighbours": 1e3 * phase[0] / steps as f64,
            "fields": 1e3 * phase[1] / steps as f64,
            "nonpressure": 1e3 * phase[2] / steps as f64,
            "pressure": 1e3 * phase[3] / steps as f64,
            "pressure_response": 1e3 * phase[4] / steps as f64,
            "other": 1e3 * phase[5] / steps as f64,
        },
        "engine_bytes_per_particle": sim.memory_bytes() as f64 / (nf + sim.boundary().x.len()) as f64,
        "peak_rss_bytes": peak_rss_bytes(),
    });
    println!("{out}");
}
