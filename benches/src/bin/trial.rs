//! One scripted grasp-lift-squeeze trial from the command line, printing a timeline and the
//! outcome.
//!
//! `trial [--size 10] [--porosity 0.6] [--hold 40] [--squeeze 80] [--radius 0.005]
//!        [--seed 0] [--threads 2] [--every 50] [--dry] [--dry-density 100]`
//!
//! `trial --config FILE [--threads 2] --profile` runs the trial of a TrialConfig JSON file
//! (e.g. `json.dumps(rmi_sph.trial_config(...))`) and prints, per controller phase, the
//! steps, wall time per stage of the step and the mean solver iterations: where a trial's
//! time goes. The `resp` stage holds the pressure response and, in steps where a held contact
//! slides only after it, the slip release (`resp_it` and `slip_it` are their CG iterations
//! per step). `trial --config FILE --plate-load` prints instead, per phase, the mean normal
//! (squeeze-axis) load on a plate (N) and the part of it the skeleton's contacts carry; the
//! rest is water pressing on the plates through the boundary pressure.
//!
//! `trial [--config FILE] --squeeze-group 50,100,300` runs the trial once per squeeze force
//! (N) from one shared prefix (everything before the squeeze,
//! [`run_squeeze_group`](rmi_robot::run_squeeze_group)) and prints each member's outcome as a
//! JSON line, then the group's wall time.

use rmi_benches::{fail, Args};
use rmi_robot::config::{paper_sponge_size, TrialConfig};
use rmi_robot::trial::{run_trial_with, Trial};

fn main() {
    let args = Args::parse(
        &[
            "--size",
            "--porosity",
            "--hold",
            "--squeeze",
            "--radius",
            "--seed",
            "--dry-density",
            "--adhesion",
            "--poisson",
            "--threads",
            "--config",
            "--every",
            "--squeeze-group",
        ],
        &["--dry", "--profile", "--plate-load"],
    );
    let size_cm: u32 = args.value("--size", 10u32);
    let Some(size) = paper_sponge_size(f64::from(size_cm)) else {
        fail(&format!("--size: {size_cm} is not one of the paper's sizes 8, 10, 12 (cm)"))
    };
    let mut cfg = TrialConfig {
        size,
        porosity: args.value("--porosity", 0.6),
        hold_force: args.value("--hold", 40.0),
        squeeze_force: args.value("--squeeze", 80.0),
        particle_radius: args.value("--radius", 0.005),
        seed: args.value("--seed", 0),
        ..Default::default()
    };
    cfg.saturated = !args.flag("--dry");
    cfg.material.dry_density = args.value("--dry-density", cfg.material.dry_density);
    cfg.material.adhesion = args.value("--adhesion", cfg.material.adhesion);
    cfg.material.poisson_ratio = args.value("--poisson", cfg.material.poisson_ratio);
    let threads: usize = args.value("--threads", 2);
    if let Some(path) = args.text("--config") {
        let text = std::fs::read_to_string(path).unwrap_or_else(|e| fail(&format!("{path}: {e}")));
        cfg = TrialConfig::from_json(&text).unwrap_or_else(|e| fail(&format!("{path}: {e}")));
    }
    if args.flag("--profile") {
        profile(cfg, threads);
        return;
    }
    if let Some(list) = args.text("--squeeze-group") {
        squeeze_group(cfg, list, threads);
        return;
    }
    if args.flag("--plate-load") {
        plate_load(cfg, threads);
        return;
    }
    let every: usize = args.value("--every", 50);
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
        Err(e) => exit_with(e),
    }
}

/// Ends the process on a trial error: a config error as a usage error, anything else with
/// status 1.
fn exit_with(e: rmi_sph::RmiError) -> ! {
    if let rmi_sph::RmiError::InvalidConfig { .. } = e {
        fail(&e.to_string());
    }
    eprintln!("error: {e}");
    std::process::exit(1);
}

/// The members of a squeeze group, one outcome per line, and the group's wall time.
fn squeeze_group(cfg: TrialConfig, list: &str, threads: usize) {
    let forces: Vec<f64> = list
        .split(',')
        .map(|f| f.trim().parse().unwrap_or_else(|_| fail(&format!("--squeeze-group: {f:?} is not a force in N"))))
        .collect();
    let t0 = std::time::Instant::now();
    match rmi_robot::run_squeeze_group(cfg, &forces, Some(threads)) {
        Ok(results) => {
            for (f, r) in forces.iter().zip(results) {
                println!("{{\"squeeze_force\": {f}, \"outcome\": {}}}", serde_json::to_string(&r.outcome).unwrap());
            }
            println!("{{\"group_wall_s\": {:.3}}}", t0.elapsed().as_secs_f64());
        }
        Err(e) => exit_with(e),
    }
}

/// Per-phase totals of one trial.
#[derive(Default)]
struct PhaseCost {
    steps: usize,
    wall: f64,
    stages: [f64; 6],
    pressure_iterations: u64,
    cg_iterations: u64,
    response_iterations: u64,
    slip_iterations: u64,
}

fn profile(cfg: TrialConfig, threads: usize) {
    let mut trial = Trial::new(cfg, Some(threads)).unwrap_or_else(|e| fail(&e.to_string()));
    // Phases in the order the trial reaches them.
    let mut phases: Vec<(String, PhaseCost)> = Vec::new();
    let t_all = std::time::Instant::now();
    let mut step = 0usize;
    while !trial.finished() {
        let name = trial.phase().name().to_string();
        let t0 = std::time::Instant::now();
        if let Err(e) = trial.step() {
            eprintln!("error: {e}");
            std::process::exit(1);
        }
        let wall = t0.elapsed().as_secs_f64();
        let st = trial.simulation().stats();
        let i = phases.iter().position(|(n, _)| *n == name).unwrap_or_else(|| {
            phases.push((name, PhaseCost::default()));
            phases.len() - 1
        });
        let pc = &mut phases[i].1;
        pc.steps += 1;
        pc.wall += wall;
        for (acc, s) in pc.stages.iter_mut().zip(st.seconds) {
            *acc += s;
        }
        pc.pressure_iterations += u64::from(st.pressure.iterations);
        pc.cg_iterations += u64::from(st.cg.iterations);
        pc.response_iterations += u64::from(st.pressure_response.iterations);
        pc.slip_iterations += u64::from(st.slip_response.iterations);
        step += 1;
    }
    let total = t_all.elapsed().as_secs_f64();
    let n = trial.simulation().particles().len();
    println!("{n} particles, {threads} threads, {step} steps, {total:.1} s wall");
    println!(
        "{:>8} {:>6} {:>7} {:>8} | {:>6} {:>6} {:>6} {:>6} {:>6} {:>6} | {:>6} {:>6} {:>7} {:>7}",
        "phase",
        "steps",
        "wall_s",
        "ms/step",
        "nb",
        "fields",
        "cg",
        "press",
        "resp",
        "rest",
        "p_it",
        "cg_it",
        "resp_it",
        "slip_it"
    );
    for (name, pc) in &phases {
        let k = pc.steps.max(1) as f64;
        let st: Vec<String> = pc.stages.iter().map(|s| format!("{:6.1}", 1e3 * s / k)).collect();
        println!(
            "{:>8} {:>6} {:>7.1} {:>8.1} | {} | {:>6.1} {:>6.1} {:>7.1} {:>7.1}",
            name,
            pc.steps,
            pc.wall,
            1e3 * pc.wall / k,
            st.join(" "),
            pc.pressure_iterations as f64 / k,
            pc.cg_iterations as f64 / k,
            pc.response_iterations as f64 / k,
            pc.slip_iterations as f64 / k
        );
    }
}

/// Per phase: mean normal load (N) on a plate and the part the skeleton's contacts carry.
fn plate_load(cfg: TrialConfig, threads: usize) {
    let mut trial = Trial::new(cfg, Some(threads)).unwrap_or_else(|e| fail(&e.to_string()));
    // (phase, steps, total load, skeleton contact load), phases in the order reached.
    let mut phases: Vec<(&str, usize, f64, f64)> = Vec::new();
    while !trial.finished() {
        let name = trial.phase().name();
        if let Err(e) = trial.step() {
            eprintln!("error: {e}");
            std::process::exit(1);
        }
        let (sim, g) = (trial.simulation(), trial.gripper());
        let (mut total, mut skeleton) = (0.0, 0.0);
        for b in [g.left, g.right] {
            // The squeeze axis is x: the normal load, without friction and weight.
            total += sim.boundary().bodies[b].force.x.abs();
            skeleton += sim.skeleton_contact_force(b).x.abs();
        }
        if phases.last().is_none_or(|p| p.0 != name) {
            phases.push((name, 0, 0.0, 0.0));
        }
        let p = phases.last_mut().unwrap();
        p.1 += 1;
        p.2 += total / 2.0;
        p.3 += skeleton / 2.0;
    }
    println!("{:>8} {:>6} {:>10} {:>12} {:>10}", "phase", "steps", "plate_N", "skeleton_N", "water_N");
    for (name, n, total, skeleton) in phases {
        let n = n as f64;
        println!("{name:>8} {:>6} {:>10.1} {:>12.1} {:>10.1}", n, total / n, skeleton / n, (total - skeleton) / n);
    }
}
