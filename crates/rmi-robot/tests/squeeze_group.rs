//! Trials run from a shared prefix equal the trials run on their own, bit for bit.

use rmi_robot::config::TrialConfig;
use rmi_robot::squeeze_group::run_squeeze_group;
use rmi_robot::trial::{run_trial, TrialResult};

mod common;
use common::tiny;

/// Records and outcome, the wall time aside (it is the only field that may differ).
fn same(a: &TrialResult, b: &TrialResult) -> bool {
    let (mut oa, mut ob) = (a.outcome.clone(), b.outcome.clone());
    oa.wall_s = 0.0;
    ob.wall_s = 0.0;
    oa == ob && a.records == b.records
}

#[test]
fn each_member_equals_its_own_trial() {
    let forces = [60.0, 25.0, 60.0];
    let group = run_squeeze_group(tiny(), &forces, Some(2)).unwrap();
    assert_eq!(group.len(), forces.len());
    for (f, g) in forces.iter().zip(&group) {
        assert!(g.outcome.lift_success, "the {f} N member never squeezed: {:?}", g.outcome.failure);
        let alone = run_trial(TrialConfig { squeeze_force: *f, ..tiny() }, Some(1)).unwrap();
        assert!(same(g, &alone), "the {f} N member differs from its own trial");
    }
    // The squeeze forces do matter after the shared prefix.
    let squeezed = |r: &TrialResult| r.outcome.water_removed.iter().find(|(p, _)| p == "squeeze").unwrap().1;
    assert_ne!(squeezed(&group[0]), squeezed(&group[1]));
    assert!(same(&group[0], &group[2]));
}

#[test]
fn a_trial_that_ends_before_the_squeeze_ends_so_for_every_member() {
    // Held too weakly to lift: the gate never opens and the trial ends in the hold.
    let cfg = TrialConfig { hold_force: 0.5, ..tiny() };
    let group = run_squeeze_group(cfg.clone(), &[30.0, 80.0], Some(1)).unwrap();
    let alone = run_trial(TrialConfig { squeeze_force: 80.0, ..cfg }, Some(1)).unwrap();
    assert!(!alone.outcome.lift_success, "the weak hold lifted");
    assert!(group.iter().all(|g| same(g, &alone)));
}

#[test]
fn perturbed_and_out_of_range_groups_are_refused() {
    let mut cfg = tiny();
    cfg.controller.perturbation.enabled = true;
    let err = run_squeeze_group(cfg, &[30.0, 40.0], Some(1)).unwrap_err().to_string();
    assert!(err.contains("controller.perturbation.enabled"), "{err}");
    let err = run_squeeze_group(tiny(), &[30.0, 401.0], Some(1)).unwrap_err().to_string();
    assert!(err.contains("squeeze_forces[1]") && err.contains("401"), "{err}");
    assert!(run_squeeze_group(tiny(), &[], Some(1)).unwrap().is_empty());
}
