//! The AVX2 copies of the hot loops (`cpu.rs`) give the same bits as the baseline ones.
//!
//! Its own test binary: the dispatch level is process-wide, so no other test may run while
//! it is switched.

mod common;
use common::*;
use rmi_sph::config::{Preconditioner, ViscosityMode};
use rmi_sph::{cpu, Simulation};

fn run_with(avx2: bool, cfg: &rmi_sph::config::SimConfig, steps: usize) -> Vec<u64> {
    cpu::set_avx2(avx2);
    let mut sim = Simulation::new(cfg.clone(), Some(2)).unwrap();
    run(&mut sim, steps);
    let mut b = bits(&sim);
    b.extend(sim.kappa().iter().map(|k| k.to_bits()));
    b
}

#[test]
fn dispatch_is_bit_identical() {
    // A sponge with pore water (solid and mixed pairs, implicit viscosity) and a small dam
    // break (fluid pairs, explicit viscosity) cover every dispatched loop.
    let sponge = small_sponge();
    let mut two_level = small_sponge();
    two_level.cg.preconditioner = Preconditioner::TwoLevel;
    let mut dam = rmi_sph::presets::water_column(0.01, 0.12, 0.16);
    dam.fluid.viscosity_mode = ViscosityMode::Explicit;
    for (name, cfg, steps) in
        [("sponge", &sponge, 25), ("sponge, two-level CG", &two_level, 25), ("water column", &dam, 40)]
    {
        let base = run_with(false, cfg, steps);
        let fast = run_with(true, cfg, steps);
        assert!(base == fast, "{name}: the AVX2 copy changes the results");
    }
    if !cpu::avx2_enabled() {
        eprintln!("note: this CPU has no AVX2 + FMA; both runs used the baseline copy");
    }
    cpu::set_avx2(true);
}
