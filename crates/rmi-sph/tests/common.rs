//! Shared helpers of the integration tests.
#![allow(dead_code)]

use rmi_sph::config::*;
use rmi_sph::Simulation;

/// Mean of a slice.
pub fn mean(v: &[f64]) -> f64 {
    v.iter().sum::<f64>() / v.len().max(1) as f64
}

/// Least-squares slope of y over x.
pub fn slope(x: &[f64], y: &[f64]) -> f64 {
    let mx = mean(x);
    let my = mean(y);
    let sxy: f64 = x.iter().zip(y).map(|(a, b)| (a - mx) * (b - my)).sum();
    let sxx: f64 = x.iter().map(|a| (a - mx).powi(2)).sum();
    sxy / sxx
}

/// A small saturated sponge on a floor (for determinism and snapshot tests).
pub fn small_sponge() -> SimConfig {
    let mut cfg = rmi_sph::presets::sponge([0.06, 0.06, 0.08], 0.6, 0.005);
    cfg.dt = 1e-3;
    cfg
}

/// Runs `n` steps, panicking with the error text on failure.
pub fn run(sim: &mut Simulation, n: usize) {
    for _ in 0..n {
        sim.step().unwrap_or_else(|e| panic!("{e}"));
    }
}
