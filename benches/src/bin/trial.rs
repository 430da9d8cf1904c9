//! One scripted grasp-lift-squeeze trial from the command line, printing a timeline and the
//! outcome.
//!
//! `trial [--size 10] [--porosity 0.6] [--hold 40] [--squeeze 80] [--radius 0.005]
//!        [--seed 0] [--threads 2] [--every 50] [--dry] [--dry-density 100]`

use rmi_benches::arg;
use rmi_sph::presets::SPONGE_SIZES;
use rmi_sph::trial::{run_trial_with, TrialConfig};

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let size_cm: u32 = arg(&args, "--size", 10);
    let size = match size_cm {
        8 => SPONGE_SIZES[0],
        12 => SPONGE_SIZES[2],
        _ => SPONGE_SIZES[1],
    };
    let mut cfg = TrialConfig {
        size,
        porosity: arg(&args, "--porosity", 0.6),
        hold_force: arg(&args, "--hold", 40.0),
        squeeze_force: arg(&args, "--squeeze", 80.0),
        particle_radius: arg(&args, "--radius", 0.005),
        seed: arg(&args, "--seed", 0),
        ..Default::default()
    };
    cfg.saturated = !args.iter().any(|a| a == "--dry");
    cfg.material.dry_density = arg(&args, "--dry-density", cfg.material.dry_density);
    cfg.material.adhesion = arg(&args, "--adhesion", cfg.material.adhesion);
    cfg.material.poisson_ratio = arg(&args, "--poisson", cfg.material.poisson_ratio);
    let threads: usize = arg(&args, "--threads", 2);
    let every: usize = arg(&args, "--every", 50);
    let mut k = 0usize;
    println!(
        "{:>6} {:>8} {:>7} {:>7} {:>7} {:>7} {:>7} {:>8} {:>6} {:>8} {:>5}",
        "t", "phase", "F_tgt", "F_meas", "F_L", "F_R", "w_mm", "M_L_g", "nC", "v_res", "gate"
    );
    let res = run_trial_with(cfg.clone(), Some(threads), |o| {
        k += 1;
        if k.is_multiple_of((every / cfg.record_every as usize).max(1)) {
            let n = ((o.a_l + o.a_r) / (4.0 * cfg.particle_radius * cfg.particle_radius)).round();
            println!(
                "{:6.3} {:>8} {:7.2} {:7.2} {:7.2} {:7.2} {:7.2} {:8.2} {:6} {:8.4} {:>5}",
                o.time,
                o.phase.map_or("-", |p| p.name()),
                o.f_target,
                o.f_meas,
                o.f_l,
                o.f_r,
                o.width * 1e3,
                o.m_l * 1e3,
                n,
                o.v_res.unwrap_or(f64::NAN),
                o.gate_open
            );
        }
        true
    });
    match res {
        Ok(r) => println!("{}", serde_json::to_string_pretty(&r.outcome).unwrap()),
        Err(e) => {
            eprintln!("error: {e}");
            std::process::exit(1);
        }
    }
}
