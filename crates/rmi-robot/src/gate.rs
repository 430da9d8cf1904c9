//! The lift stability gate (paper Eq. 6, supplement S9-S10): lifting starts only after the
//! filtered pad loads, the sponge's centre-of-mass speed along the lift axis and the residual
//! slip have all been acceptable, with bilateral contact, for `k_stable` consecutive steps.

use rmi_sph::config::check_range;
use rmi_sph::Result;
use serde::{Deserialize, Serialize};

/// Gate thresholds.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct GateParams {
    /// Load filter coefficient eta_F in (0, 1] (Eq. S9).
    pub eta_f: f64,
    /// Accepted filtered load per pad, as fractions of the holding force: [F_min, F_max].
    pub force_band: [f64; 2],
    /// Largest accepted centre-of-mass speed along the lift axis (m/s).
    pub v_com_max: f64,
    /// Largest accepted residual slip (m/s).
    pub v_res_max: f64,
    /// Consecutive valid simulator steps needed to open.
    pub k_stable: u32,
}

impl Default for GateParams {
    fn default() -> Self {
        GateParams { eta_f: 0.1, force_band: [0.8, 1.25], v_com_max: 0.01, v_res_max: 0.01, k_stable: 20 }
    }
}

impl GateParams {
    /// Validates every field; `p` is the dotted path used in error messages.
    pub fn validate(&self, p: &str) -> Result<()> {
        check_range(&format!("{p}.eta_f"), self.eta_f, 1e-6, 1.0, "(dimensionless)")?;
        check_range(&format!("{p}.force_band[0]"), self.force_band[0], 0.0, 1.0, "(fraction of the holding force)")?;
        check_range(
            &format!("{p}.force_band[1]"),
            self.force_band[1],
            self.force_band[0].max(1.0),
            10.0,
            "(fraction of the holding force, at least 1 and force_band[0])",
        )?;
        check_range(&format!("{p}.v_com_max"), self.v_com_max, 0.0, 10.0, "m/s")?;
        check_range(&format!("{p}.v_res_max"), self.v_res_max, 0.0, 10.0, "m/s")?;
        if self.k_stable == 0 || self.k_stable > 100_000 {
            return Err(rmi_sph::RmiError::config(format!("{p}.k_stable"), self.k_stable, "an integer in [1, 100000]"));
        }
        Ok(())
    }
}

/// Inputs of one gate evaluation.
#[derive(Clone, Copy, Debug)]
pub struct GateInput {
    /// Left and right pad loads this step (N).
    pub loads: (f64, f64),
    /// Holding force the band refers to (N).
    pub hold_force: f64,
    /// |V_COM . a_lift| (m/s).
    pub v_com: f64,
    /// Residual slip (m/s); `None` without contact.
    pub v_res: Option<f64>,
    /// Both pads touch the sponge.
    pub bilateral: bool,
}

/// Gate state: filtered loads, the run of valid steps, and when it opened.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Gate {
    /// Filtered left and right loads (N).
    pub filtered: (f64, f64),
    /// Consecutive valid steps so far.
    pub count: u32,
    /// Simulated time at which the gate opened (s).
    pub opened_at: Option<f64>,
    primed: bool,
}

impl Gate {
    /// Updates the load filter (every step, so it is warm when the gate is consulted).
    pub fn filter(&mut self, p: &GateParams, loads: (f64, f64)) {
        if self.primed {
            self.filtered.0 += p.eta_f * (loads.0 - self.filtered.0);
            self.filtered.1 += p.eta_f * (loads.1 - self.filtered.1);
        } else {
            self.filtered = loads;
            self.primed = true;
        }
    }

    /// Whether this step satisfies every condition (the filter must be updated first).
    pub fn valid(&self, p: &GateParams, x: &GateInput) -> bool {
        let lo = p.force_band[0] * x.hold_force;
        let hi = p.force_band[1] * x.hold_force;
        let band = |f: f64| f >= lo && f <= hi;
        x.bilateral
            && band(self.filtered.0)
            && band(self.filtered.1)
            && x.v_com <= p.v_com_max
            && x.v_res.is_some_and(|v| v <= p.v_res_max)
    }

    /// Counts a valid step or resets the run; opens after `k_stable` consecutive valid steps
    /// and then stays open. Returns whether the gate is open. `time` is recorded on opening.
    pub fn update(&mut self, p: &GateParams, x: &GateInput, time: f64) -> bool {
        if self.opened_at.is_some() {
            return true;
        }
        if self.valid(p, x) {
            self.count += 1;
        } else {
            self.count = 0;
        }
        if self.count >= p.k_stable {
            self.opened_at = Some(time);
        }
        self.opened_at.is_some()
    }

    /// Forgets the run of valid steps (the gate closes again).
    pub fn reset(&mut self) {
        self.count = 0;
        self.opened_at = None;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn good() -> GateInput {
        GateInput { loads: (50.0, 50.0), hold_force: 50.0, v_com: 0.0, v_res: Some(0.0), bilateral: true }
    }

    #[test]
    fn opens_only_after_k_stable_consecutive_valid_steps() {
        let p = GateParams { k_stable: 5, ..Default::default() };
        let mut g = Gate::default();
        for k in 0..4 {
            g.filter(&p, good().loads);
            assert!(!g.update(&p, &good(), k as f64), "opened early at step {k}");
        }
        // One invalid step resets the run.
        let bad = GateInput { v_com: 1.0, ..good() };
        g.filter(&p, bad.loads);
        assert!(!g.update(&p, &bad, 4.0));
        assert_eq!(g.count, 0);
        for k in 0..4 {
            g.filter(&p, good().loads);
            assert!(!g.update(&p, &good(), 5.0 + k as f64));
        }
        g.filter(&p, good().loads);
        assert!(g.update(&p, &good(), 9.0));
        assert_eq!(g.opened_at, Some(9.0));
    }

    #[test]
    fn every_condition_is_required() {
        let p = GateParams::default();
        let cases = [
            GateInput { bilateral: false, ..good() },
            GateInput { v_res: None, ..good() },
            GateInput { v_res: Some(1.0), ..good() },
            GateInput { v_com: 0.5, ..good() },
            GateInput { loads: (10.0, 50.0), ..good() },
            GateInput { loads: (50.0, 90.0), ..good() },
        ];
        for (k, x) in cases.iter().enumerate() {
            let mut g = Gate::default();
            g.filter(&p, x.loads);
            assert!(!g.valid(&p, x), "case {k} passed");
        }
        let mut g = Gate::default();
        g.filter(&p, good().loads);
        assert!(g.valid(&p, &good()));
    }

    #[test]
    fn filter_is_exponential() {
        let p = GateParams { eta_f: 0.5, ..Default::default() };
        let mut g = Gate::default();
        g.filter(&p, (0.0, 0.0));
        g.filter(&p, (10.0, 20.0));
        assert_eq!(g.filtered, (5.0, 10.0));
    }
}
