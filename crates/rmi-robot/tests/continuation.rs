//! Bit-identical continuation of a trial from a saved state at every step.
//!
//! A one-step check from every step covers everything: state that the snapshot misses shows
//! at the step that reads it, and a continuation that matches one step at a time from every
//! state matches to the end. One full continuation from the first ramp step (where the pads'
//! velocity passes through zero, the case that once lost the boundary particles' velocities)
//! checks the final state directly.

use rmi_robot::controller::Phase;
use rmi_robot::trial::Trial;

mod common;
use common::tiny;

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

#[test]
fn a_state_of_the_format_before_the_wrist_load_is_refused_by_name() {
    let a = Trial::new(tiny(), Some(1)).unwrap();
    let mut old = a.to_bytes();
    old[..8].copy_from_slice(b"RMITRL03");
    let err = Trial::from_bytes(&old, Some(1)).err().expect("an older state must be refused");
    assert!(err.to_string().contains("older format"), "{err}");
}
