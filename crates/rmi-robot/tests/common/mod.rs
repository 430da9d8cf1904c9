//! Configurations shared by the trial tests.

use rmi_robot::config::TrialConfig;

/// The 8 cm sponge at r = 10 mm (228 particles) with brief phases: every phase in about
/// 1,300 steps.
pub fn tiny() -> TrialConfig {
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
