//! Seeded perturbations of the scripted force targets, for data in which the effect of a
//! command can be told apart from the state it was issued in.
//!
//! A scripted trial issues one force target per phase (hold, then the squeeze force), so
//! every command in its data follows from the run's parameters and a world model never sees
//! two different commands from similar states. With a perturbation enabled, the target
//! from the lift on is a seeded sequence of segments instead: each segment lasts a random
//! time, ends at a random level in the safe range, and either steps to that level or ramps
//! to it linearly from the previous one. The schedule is a pure function of the seed, the
//! trial's forces and the simulated time, so a restored trial continues it bit-identically
//! and nothing about it is kept in the trial's state.
//!
//! The hold on the floor stays scripted: the lift gate accepts a grasp only while the load
//! stays within its band around the holding force, so a perturbed hold would change which
//! trials are lifted rather than what the water does.

use crate::gripper::FORCE_LIMIT;
use rmi_sph::config::{check_range, check_seed};
use rmi_sph::{Result, RmiError};
use serde::{Deserialize, Serialize};

/// Options of the perturbed force targets (SI: s, N).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct SetpointPerturbation {
    /// Replace the scripted targets from the lift on by the seeded schedule.
    pub enabled: bool,
    /// Seed of the schedule; it is mixed with the holding and squeeze forces, so runs of
    /// one seed that differ in either force follow different schedules. In [0, `SEED_MAX`].
    pub seed: u64,
    /// Shortest and longest segment (s).
    pub segment_time: [f64; 2],
    /// Lowest target as a fraction of the holding force (-): the lower edge of the lift
    /// gate's load band by default, the smallest grip the trial counts as a stable hold.
    pub min_fraction_of_hold: f64,
    /// Highest target (N).
    pub max_force: f64,
    /// Probability that a segment ramps from the previous level instead of stepping (-).
    pub ramp_probability: f64,
}

impl Default for SetpointPerturbation {
    fn default() -> Self {
        SetpointPerturbation {
            enabled: false,
            seed: 0,
            segment_time: [0.06, 0.3],
            min_fraction_of_hold: 0.8,
            max_force: FORCE_LIMIT,
            ramp_probability: 0.5,
        }
    }
}

/// splitmix64: a well-mixed 64-bit value from any 64-bit input.
fn mix(mut z: u64) -> u64 {
    z = z.wrapping_add(0x9E37_79B9_7F4A_7C15);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

/// A uniform number in [0, 1) for draw `channel` of segment `k`.
fn uniform(key: u64, k: u64, channel: u64) -> f64 {
    let bits = mix(key ^ mix(k.wrapping_mul(4).wrapping_add(channel)));
    (bits >> 11) as f64 / (1u64 << 53) as f64
}

impl SetpointPerturbation {
    /// Validates every field; `p` is the dotted path used in error messages.
    pub fn validate(&self, p: &str) -> Result<()> {
        check_seed(&format!("{p}.seed"), self.seed)?;
        let [lo, hi] = self.segment_time;
        check_range(&format!("{p}.segment_time[0]"), lo, 1e-3, 10.0, "s")?;
        check_range(&format!("{p}.segment_time[1]"), hi, 1e-3, 10.0, "s")?;
        if hi < lo {
            return Err(RmiError::config(
                format!("{p}.segment_time[1]"),
                hi,
                format!("at least segment_time[0] = {lo} s"),
            ));
        }
        check_range(
            &format!("{p}.min_fraction_of_hold"),
            self.min_fraction_of_hold,
            0.0,
            10.0,
            "(fraction of the holding force)",
        )?;
        check_range(&format!("{p}.max_force"), self.max_force, 0.0, FORCE_LIMIT, "N")?;
        check_range(&format!("{p}.ramp_probability"), self.ramp_probability, 0.0, 1.0, "(probability)")?;
        Ok(())
    }

    /// The target (N) at simulated time `time` (s) of a trial with the given holding and
    /// squeeze forces (N). Segments start at time 0; before the first one the level is the
    /// holding force. Levels are uniform in [min_fraction_of_hold x hold, max_force],
    /// clipped to [0, FORCE_LIMIT].
    pub fn target(&self, hold_force: f64, squeeze_force: f64, time: f64) -> f64 {
        let key = mix(self.seed ^ mix(hold_force.to_bits() ^ mix(squeeze_force.to_bits())));
        let lo = (self.min_fraction_of_hold * hold_force).clamp(0.0, FORCE_LIMIT);
        let hi = self.max_force.clamp(lo, FORCE_LIMIT);
        let [t_min, t_max] = self.segment_time;
        let (mut start, mut previous) = (0.0, hold_force.clamp(lo, hi));
        let mut k = 0u64;
        loop {
            let duration = t_min + (t_max - t_min) * uniform(key, k, 0);
            let level = lo + (hi - lo) * uniform(key, k, 1);
            let ramps = uniform(key, k, 2) < self.ramp_probability;
            if time < start + duration {
                return if ramps {
                    previous + (level - previous) * ((time - start) / duration).max(0.0)
                } else {
                    level
                };
            }
            start += duration;
            previous = level;
            k += 1;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn on() -> SetpointPerturbation {
        SetpointPerturbation { enabled: true, seed: 7, ..Default::default() }
    }

    #[test]
    fn targets_stay_in_the_safe_range_and_vary() {
        let p = on();
        let xs: Vec<f64> = (0..5000).map(|i| p.target(100.0, 300.0, i as f64 * 1e-3)).collect();
        assert!(xs.iter().all(|x| (80.0..=FORCE_LIMIT).contains(x)), "a target left [80, 400] N");
        let (min, max) = xs.iter().fold((f64::MAX, f64::MIN), |(a, b), x| (a.min(*x), b.max(*x)));
        assert!(max - min > 100.0, "five seconds of targets span only {min}..{max} N");
    }

    #[test]
    fn schedule_has_steps_and_ramps() {
        let p = on();
        let xs: Vec<f64> = (0..5000).map(|i| p.target(100.0, 300.0, i as f64 * 1e-3)).collect();
        let jumps = xs.windows(2).filter(|w| (w[1] - w[0]).abs() > 5.0).count();
        let sloped = xs.windows(2).filter(|w| (w[1] - w[0]).abs() > 1e-6 && (w[1] - w[0]).abs() < 5.0).count();
        assert!(jumps >= 3, "only {jumps} steps in five seconds");
        assert!(sloped >= 100, "only {sloped} ramping steps in five seconds");
    }

    #[test]
    fn schedule_depends_on_seed_and_forces_only() {
        let p = on();
        let a = p.target(100.0, 300.0, 1.234);
        assert_eq!(a.to_bits(), on().target(100.0, 300.0, 1.234).to_bits());
        let other_seed = SetpointPerturbation { seed: 8, ..on() };
        let differs =
            |f: &dyn Fn(f64) -> f64| (0..50).any(|i| f(i as f64 * 0.1) != p.target(100.0, 300.0, i as f64 * 0.1));
        assert!(differs(&|t| other_seed.target(100.0, 300.0, t)));
        assert!(differs(&|t| p.target(100.0, 200.0, t)));
        assert!(differs(&|t| p.target(110.0, 300.0, t)));
    }

    #[test]
    fn bad_options_name_the_field() {
        let p = SetpointPerturbation { segment_time: [0.3, 0.1], ..on() };
        let msg = p.validate("controller.perturbation").unwrap_err().to_string();
        assert!(msg.contains("controller.perturbation.segment_time[1]"), "{msg}");
        let p = SetpointPerturbation { ramp_probability: 1.5, ..on() };
        let msg = p.validate("controller.perturbation").unwrap_err().to_string();
        assert!(msg.contains("ramp_probability"), "{msg}");
    }
}
