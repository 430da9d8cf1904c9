//! Criterion benches of solver throughput (`cargo bench` at the workspace root):
//! neighbour search, one step of the SPlisHSPlasH dam break, one step of the medium sponge.
//!
//! Scenes are advanced past their start-up transient before timing. `RMI_BENCH_RADIUS_DAM`
//! and `RMI_BENCH_RADIUS_SPONGE` override the particle radii (defaults: the comparison's
//! 12.5 mm dam break and the 5 mm fast sponge preset).

use criterion::{criterion_group, criterion_main, Criterion, Throughput};
use rmi_sph::neighbourhood::{bounds, CubicKernel, Grid, NeighbourLists};
use rmi_sph::{presets, Simulation};

fn radius(var: &str, default: f64) -> f64 {
    std::env::var(var).ok().and_then(|v| v.parse().ok()).unwrap_or(default)
}

fn warm(cfg: rmi_sph::SimConfig, steps: u64) -> Simulation {
    let mut sim = Simulation::new(cfg, Some(2)).expect("scene builds");
    sim.run(steps).expect("warm-up steps");
    sim
}

fn neighbour_search(c: &mut Criterion) {
    let sim = warm(presets::dam_break(radius("RMI_BENCH_RADIUS_DAM", 0.0125)), 20);
    let x = sim.particles().x.clone();
    let kernel = CubicKernel::new(4.0 * sim.radius());
    let reach = sim.config().neighbour_reach as usize;
    let pool = rayon::ThreadPoolBuilder::new().num_threads(2).build().unwrap();
    let mut grid = Grid::default();
    let mut nb = NeighbourLists::default();
    let mut g = c.benchmark_group("neighbours");
    g.throughput(Throughput::Elements(x.len() as u64));
    g.sample_size(20);
    g.bench_function("dam_break_grid_and_lists_2_threads", |b| {
        b.iter(|| {
            pool.install(|| {
                let (lo, hi) = bounds(&x, kernel.support());
                grid.build_with(&x, lo, hi, kernel.support(), reach);
                nb.build(&x, &grid, &kernel, x.len(), true);
            })
        })
    });
    g.finish();
}

fn dam_break_step(c: &mut Criterion) {
    let mut sim = warm(presets::dam_break(radius("RMI_BENCH_RADIUS_DAM", 0.0125)), 50);
    let mut g = c.benchmark_group("dam_break");
    g.throughput(Throughput::Elements(sim.particles().n_fluid as u64));
    g.sample_size(20);
    g.bench_function("step_2_threads", |b| {
        b.iter(|| {
            sim.step().expect("step");
        })
    });
    g.finish();
}

fn sponge_step(c: &mut Criterion) {
    let mut sim = warm(presets::sponge(presets::SPONGE_SIZES[1], 0.6, radius("RMI_BENCH_RADIUS_SPONGE", 0.005)), 30);
    let mut g = c.benchmark_group("sponge_medium");
    g.throughput(Throughput::Elements(sim.particles().len() as u64));
    g.sample_size(20);
    g.bench_function("step_2_threads", |b| {
        b.iter(|| {
            sim.step().expect("step");
        })
    });
    g.finish();
}

criterion_group!(benches, neighbour_search, dam_break_step, sponge_step);
criterion_main!(benches);
