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

/// Writes one validation case as JSON to `$RMI_VALIDATION_OUT/<case>.json` when that
/// variable is set (the report's validation table reads these); does nothing otherwise.
/// `pass` is the test's own acceptance condition, recorded before it is asserted so that a
/// failing case is reported as failing.
pub fn record(case: &str, setup: &str, measured: &str, analytic: &str, error: &str, pass: bool) {
    let Some(dir) = std::env::var_os("RMI_VALIDATION_OUT") else { return };
    let dir = std::path::PathBuf::from(dir);
    std::fs::create_dir_all(&dir).expect("create RMI_VALIDATION_OUT");
    let json = serde_json::json!({
        "case": case, "setup": setup, "measured": measured, "analytic": analytic,
        "error": error, "pass": pass,
    });
    let name = case.replace(|c: char| !c.is_ascii_alphanumeric(), "_");
    let tmp = dir.join(format!(".{name}.json.tmp"));
    std::fs::write(&tmp, serde_json::to_vec_pretty(&json).unwrap()).expect("write record");
    std::fs::rename(&tmp, dir.join(format!("{name}.json"))).expect("rename record");
}

/// Bit patterns of every position and velocity, for bit-identity checks.
pub fn bits(sim: &Simulation) -> Vec<u64> {
    let p = sim.particles();
    p.x.iter().chain(p.v.iter()).flat_map(|v| v.iter().map(|c| c.to_bits()).collect::<Vec<_>>()).collect()
}
