//! Trials that differ only in their squeeze force, run from one shared prefix.
//!
//! Before the squeeze nothing in a scripted trial depends on the squeeze force (the
//! controller reads it from the squeeze on), so the runs of a grid that share everything else
//! share their settling, grip, hold and lift step for step. [`run_squeeze_group`] simulates
//! that prefix once, saves the whole state ([`Trial::to_bytes`]) where the squeeze begins and
//! continues each member from it: every member's result has the bits of its own
//! [`run_trial`](crate::trial::run_trial), at the cost of one prefix for the group.

use crate::config::TrialConfig;
use crate::controller::Phase;
use crate::gripper::FORCE_LIMIT;
use crate::observe::Observation;
use crate::trial::{Trial, TrialResult};
use rmi_sph::config::check_range;
use rmi_sph::{Result, RmiError};
use std::time::Instant;

/// Runs the trial of `cfg` once per force in `squeeze_forces` (N), sharing everything before
/// the squeeze; results in the order of the forces, each equal to
/// [`run_trial`](crate::trial::run_trial) of `cfg` with that squeeze force (records and
/// outcome), but for its wall time: the prefix's split evenly over the group plus the
/// member's own squeeze. A trial that ends before the squeeze (the sponge slipped, a guard
/// tripped) ends the same way for every member. `cfg.squeeze_force` itself is not run.
///
/// Perturbed force targets (`controller.perturbation.enabled`) depend on the squeeze force
/// from the lift on (it seeds their schedule): such a group is refused with a config error.
pub fn run_squeeze_group(cfg: TrialConfig, squeeze_forces: &[f64], threads: Option<usize>) -> Result<Vec<TrialResult>> {
    run_squeeze_group_with(cfg, squeeze_forces, threads, |_| true)
}

/// [`run_squeeze_group`] with a callback after every recorded row, of the prefix and then of
/// each member in turn; returning `false` stops the group with [`RmiError::State`] (used to
/// honour interrupts from Python).
pub fn run_squeeze_group_with<F: FnMut(&Observation) -> bool>(
    cfg: TrialConfig,
    squeeze_forces: &[f64],
    threads: Option<usize>,
    mut keep_going: F,
) -> Result<Vec<TrialResult>> {
    let Some(&first) = squeeze_forces.first() else {
        return Ok(Vec::new());
    };
    if cfg.controller.perturbation.enabled {
        return Err(RmiError::config(
            "controller.perturbation.enabled",
            true,
            "false: perturbed targets depend on the squeeze force from the lift on; run each trial on its own",
        ));
    }
    // Every force is checked before the scene is built and soaked.
    for (i, &f) in squeeze_forces.iter().enumerate() {
        check_range(&format!("squeeze_forces[{i}]"), f, 0.0, FORCE_LIMIT, "N")?;
    }
    let n = squeeze_forces.len() as f64;
    let start = Instant::now();
    let mut t = Trial::new(TrialConfig { squeeze_force: first, ..cfg }, threads)?;
    let mut records = vec![t.take_record()];
    while !t.finished() && t.phase() != Phase::Squeeze {
        t.step_recording(&mut records, &mut keep_going)?;
    }
    let prefix_s = start.elapsed().as_secs_f64() / n;
    if t.finished() {
        let r = TrialResult { outcome: t.outcome(prefix_s), records };
        return Ok(vec![r; squeeze_forces.len()]);
    }
    let state = t.to_bytes();
    drop(t);
    let mut results = Vec::with_capacity(squeeze_forces.len());
    for &f in squeeze_forces {
        let start = Instant::now();
        let mut t = Trial::from_bytes(&state, threads)?;
        t.set_squeeze_force(f)?;
        let mut records = records.clone();
        while !t.finished() {
            t.step_recording(&mut records, &mut keep_going)?;
        }
        results.push(TrialResult { outcome: t.outcome(prefix_s + start.elapsed().as_secs_f64()), records });
    }
    Ok(results)
}
