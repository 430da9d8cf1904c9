//! The AVX2 copies of the hot loops (`crates/rmi-par/src/cpu.rs`) give the same bits as the baseline ones.
//!
//! Its own test binary: the dispatch level is process-wide, so no other test may run while
//! it is switched; the tests here take turns through [`SWITCH`].

mod common;
use common::*;
use nalgebra::Vector3;
use rmi_par::cpu;
use rmi_sph::config::{Preconditioner, ViscosityMode};
use rmi_sph::neighbourhood::{bounds, CubicKernel, Grid, NeighbourLists};
use rmi_sph::Simulation;

/// Held by each test while it switches the dispatch level.
static SWITCH: std::sync::Mutex<()> = std::sync::Mutex::new(());

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
    let _turn = SWITCH.lock().unwrap_or_else(|e| e.into_inner());
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

/// Every list entry (index, W, grad W, fluid/solid split) of one build, as bits.
fn list_bits(nb: &NeighbourLists) -> Vec<u64> {
    let mut out = Vec::new();
    for a in 0..nb.len() {
        let l = nb.of(a);
        out.push(l.j.len() as u64);
        out.push(l.n_fluid as u64);
        out.extend(l.j.iter().map(|&j| j as u64));
        out.extend(l.w.iter().map(|w| w.to_bits()));
        out.extend((0..l.j.len()).flat_map(|k| l.g(k).iter().map(|c| c.to_bits()).collect::<Vec<_>>()));
    }
    out
}

#[test]
fn neighbour_lists_are_bit_identical_with_and_without_avx2() {
    let _turn = SWITCH.lock().unwrap_or_else(|e| e.into_inner());
    // Random points with clusters, coincident pairs, points at exactly half and whole support
    // on a lattice, a NaN query; half the targets count as solid, so the split is exercised.
    let h = 0.05;
    let mut s = 987654321u64;
    let mut r = || {
        s = s.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
        (s >> 11) as f64 / (1u64 << 53) as f64
    };
    let mut pts: Vec<Vector3<f64>> = (0..3000).map(|_| Vector3::new(r(), 0.6 * r(), 0.3 * r())).collect();
    pts.extend((0..400).map(|i| Vector3::new(0.5 + 0.001 * r(), 0.3, 0.1 + (i % 3) as f64 * 1e-12)));
    let copies = pts[..200].to_vec();
    pts.extend(copies);
    pts.extend((0..512).map(|i| Vector3::new((i % 8) as f64, ((i / 8) % 8) as f64, (i / 64) as f64) * (h / 2.0)));
    let mut queries = pts.clone();
    queries.push(Vector3::new(f64::NAN, 0.1, 0.1));
    let kernel = CubicKernel::new(h);
    let (lo, hi) = bounds(&pts, h);
    let mut grid = Grid::default();
    grid.build_with(&pts, lo, hi, h, 2);
    for (exclude_self, n_fluid) in [(true, pts.len() / 2), (false, pts.len()), (false, 0)] {
        let mut built = Vec::new();
        for avx2 in [false, true] {
            cpu::set_avx2(avx2);
            let mut nb = NeighbourLists::default();
            let q = if exclude_self { &pts } else { &queries };
            nb.build(q, &grid, &kernel, n_fluid, exclude_self);
            assert!(nb.pairs() > 10 * q.len(), "the point set should be dense, {} pairs", nb.pairs());
            built.push(list_bits(&nb));
        }
        assert!(built[0] == built[1], "exclude_self {exclude_self}, {n_fluid} fluid targets: lists differ");
    }
    cpu::set_avx2(true);
}
