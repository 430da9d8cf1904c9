//! Bit-identical continuation of a trial from a saved state at every step.
//!
//! A one-step check from every step covers everything: state that the snapshot misses shows
//! at the step that reads it, and a continuation that matches one step at a time from every
//! state matches to the end. One full continuation from the first ramp step (where the pads'
//! velocity passes through zero, the case that once lost the boundary particles' velocities)
//! checks the final state directly.

use rmi_robot::controller::Phase;
use rmi_robot::trial::{Trial, TrialConfig};

/// The 8 cm sponge at r = 10 mm (228 particles) with brief phases: every phase in about
/// 1,300 steps.
fn tiny() -> TrialConfig {
    let mut c = TrialConfig {
        size: rmi_sph::presets::SPONGE_SIZES[0],
        porosity: 0.6,
        hold_force: 20.0,
        squeeze_force: 40.0,
        particle_radius: 0.01,
        seed: 3,
        ..Default::default()
    };
    let k = &mut c.controller;
    [k.settle_time, k.ramp_time, k.hold_time, k.wait_time, k.squeeze_ramp_time, k.squeeze_hold_time] =
        [0.05, 0.3, 0.2, 0.2, 0.1, 0.05];
    c
}

#[test]
fn continuation_from_every_step_is_bit_identical() {
    let mut a = Trial::new(tiny(), Some(1)).unwrap();
    let mut states = vec![a.to_bytes()];
    let mut phases = vec![a.phase()];
    while !a.finished() {
        a.step().unwrap();
        states.push(a.to_bytes());
        phases.push(a.phase());
        assert!(states.len() < 5000, "the trial did not finish");
    }
    assert!(a.failure().is_none(), "failure {:?}", a.failure());
    for ph in Phase::ALL {
        assert!(phases.contains(&ph), "phase {ph:?} not covered");
    }
    for k in 0..states.len() - 1 {
        let mut b = Trial::from_bytes(&states[k], Some(2)).unwrap();
        b.step().unwrap();
        assert!(b.to_bytes() == states[k + 1], "continuation from step {k} ({:?}) differs", phases[k]);
    }
    // To the end from the first completed ramp step.
    let k = phases.iter().position(|p| *p == Phase::Ramp).unwrap() + 1;
    let mut b = Trial::from_bytes(&states[k], Some(1)).unwrap();
    while !b.finished() {
        b.step().unwrap();
    }
    assert!(b.to_bytes() == *states.last().unwrap(), "continuation from step {k} to the end differs");
}
