//! Criterion bench of world-model scoring: the native free rollout of an
//! AC-GRU-WM of the paper's size (random weights) over 8 command chunks of 32 steps against
//! one 16-step history, on 1 and 2 threads. The Python figure, with the call overhead, comes
//! from `benches/bench_wm_latency.py`.

use criterion::{criterion_group, criterion_main, Criterion};
use rmi_wm::synthetic::{random_state, Dims};
use rmi_wm::{GruWorldModel, Inputs, Spec};

fn scoring(c: &mut Criterion) {
    let d = Dims::PAPER;
    let spec =
        Spec { keep: vec![1.0; d.n_obs], assemble: (0..d.n_obs).collect(), continuous: (0..d.n_obs - 5).collect() };
    let model = GruWorldModel::from_state(&random_state(d, 0.1, 1), spec).expect("model");
    let (l, n, h) = (16, 8, 32);
    let hist: Vec<f32> = (0..l * d.n_obs).map(|i| ((i * 7 % 13) as f32 - 6.0) / 6.0).collect();
    let mask = vec![1.0; l * d.n_obs];
    let actions: Vec<f32> = (0..n * h * d.n_u).map(|i| ((i * 5 % 11) as f32 - 5.0) / 5.0).collect();
    let x = Inputs { hist: &hist, mask: &mask, actions: &actions, b: 1, l, n, h, n_u: d.n_u };
    let mut g = c.benchmark_group("world_model");
    g.sample_size(50);
    for threads in [1, 2] {
        let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().expect("pool");
        let p = (threads > 1).then_some(&pool);
        g.bench_function(format!("ac_gru_8x32_{threads}_threads"), |b| {
            b.iter(|| model.forecast(x, p).expect("forecast"))
        });
    }
    g.finish();
}

criterion_group!(benches, scoring);
criterion_main!(benches);
