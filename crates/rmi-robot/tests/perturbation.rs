//! Trials with perturbed force targets: the commands recorded are the seeded schedule from
//! the lift on, the hold stays scripted, and a restored trial continues the schedule.

use rmi_robot::config::TrialConfig;
use rmi_robot::controller::Phase;
use rmi_robot::perturbation::SetpointPerturbation;
use rmi_robot::trial::Trial;

mod common;
use common::tiny;

/// The shared tiny trial with a long squeeze, so that the schedule passes several segments
/// in the air.
fn perturbed(enabled: bool) -> TrialConfig {
    let mut c = tiny();
    c.controller.squeeze_hold_time = 0.6;
    c.controller.perturbation = SetpointPerturbation { enabled, seed: 11, max_force: 60.0, ..Default::default() };
    c
}

/// (phase, recorded F_target, time) of every step, and the state at the first squeeze step.
fn run(cfg: TrialConfig) -> (Vec<(Phase, f64, f64)>, Vec<u8>, Trial) {
    let mut t = Trial::new(cfg, Some(1)).unwrap();
    let mut log = Vec::new();
    let mut saved = Vec::new();
    while !t.finished() {
        t.step().unwrap();
        if t.phase() == Phase::Squeeze && saved.is_empty() {
            saved = t.to_bytes();
        }
        log.push((t.phase(), t.controller().last.force_target, t.simulation().time()));
        assert!(log.len() < 6000, "the trial did not finish");
    }
    (log, saved, t)
}

#[test]
fn perturbed_targets_follow_the_schedule_from_the_lift_on() {
    let cfg = perturbed(true);
    let schedule = cfg.controller.perturbation.clone();
    let (log, saved, end) = run(cfg.clone());
    assert!(end.failure().is_none(), "failure {:?}", end.failure());
    let (scripted, _, _) = run(perturbed(false));
    // Identical up to the lift: the hold is scripted in both.
    let lift = log.iter().position(|(p, _, _)| *p == Phase::Lift).expect("the sponge was lifted");
    for (a, b) in log[..lift].iter().zip(&scripted) {
        assert_eq!(a.1.to_bits(), b.1.to_bits(), "targets differ before the lift at t = {}", a.2);
    }
    // In the air the command of each step is the schedule at that step's start (the phase
    // and time the step began with are those the previous step ended with).
    let mut distinct = Vec::<f64>::new();
    for w in log[lift..].windows(2) {
        let ((phase, _, t0), (_, f, _)) = (w[0], w[1]);
        if matches!(phase, Phase::Lift | Phase::Waiting | Phase::Squeeze) {
            assert_eq!(f.to_bits(), schedule.target(20.0, 40.0, t0).to_bits(), "t = {t0}");
            assert!((16.0..=60.0).contains(&f), "target {f} N outside [0.8 F_hold, max_force]");
            if distinct.iter().all(|d| (d - f).abs() > 1.0) {
                distinct.push(f);
            }
        }
    }
    assert!(distinct.len() >= 5, "only {} distinct targets in the air", distinct.len());
    // A restored trial continues the schedule bit-identically.
    let mut b = Trial::from_bytes(&saved, Some(2)).unwrap();
    while !b.finished() {
        b.step().unwrap();
    }
    assert!(b.to_bytes() == end.to_bytes(), "the restored trial ended elsewhere");
}
