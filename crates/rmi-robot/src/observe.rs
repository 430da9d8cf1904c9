//! The interaction state y_t (paper Eq. 7) and the extras recorded beside it.
//!
//! Definitions (SI units):
//! - *Retained* liquid `M_L`: the water the sponge holds. A trial's sponge starts with all
//!   the water in its pores, and what the pores lose since, `rho_f V_pore S` at the start
//!   minus now ([`rmi_sph::Simulation::pore_water`]), is expelled: pressed out onto the
//!   surface or dripping off. `M_expelled` is that loss and `M_L` the rest of the water, so
//!   that both sum to the total water mass exactly.
//! - Sponge volume: each skeleton particle occupies `d^3` at rest and `d^3 J` deformed, with
//!   `J = det F` of its corrected deformation gradient; `V_sponge` is the sum and `V_pore`
//!   subtracts the (incompressible) solid volume. `S` is the pore-volume-weighted mean of
//!   the skeleton's local saturation.
//! - Loads: `F_L`, `F_R` are the pads' normal loads (see [`crate::gripper::Gripper::loads`]);
//!   the realised load `F_meas` is their mean, the clamping force a parallel gripper's
//!   sensor reports and the quantity the controller regulates.
//! - Contact set `C_t`: skeleton particles touching a pad with a positive normal load;
//!   `A_L`, `A_R` are their counts per pad times `d^2` (each surface particle stands for a
//!   `d x d` patch); `c = 1` when both pads have contacts (valid bilateral grasp).
//! - `v_tan` is the mean tangential velocity before friction over `C_t`, `F_fric` the total
//!   friction force on the sponge, `v_res` the mean corrected tangential speed (undefined,
//!   NaN, without contact), and the friction regime is none, stick (all contacts stick), slip
//!   (all slip) or mixed.
//! - Wrist load `W`: the force the sponge and its water exert on the two pads together, the
//!   sum of the pads' body forces (pressure reactions, normal contacts, friction). It is what
//!   a force/torque sensor between the wrist and the fingers reads once tared for the
//!   fingers' own weight; carried in the air its vertical component is minus the weight of
//!   the sponge with everything it carries, expelled water that has not dripped off included.

use crate::controller::Phase;
use nalgebra::Vector3;
use rmi_sph::contact::ContactFriction;
use serde::{Deserialize, Serialize};

/// Regularises the imbalance `alpha_F` (N).
pub const EPS_F: f64 = 1e-6;

/// Names of the 23 values of y_t in the paper's order.
pub const NAMES: [&str; 23] = [
    "M_L", "S", "V_pore", "V_sponge", "w", "F_meas", "F_L", "F_R", "alpha_F", "A_L", "A_R", "c", "v_tan_x", "v_tan_y",
    "v_tan_z", "F_fric_x", "F_fric_y", "F_fric_z", "v_res", "r_none", "r_stick", "r_slip", "r_mixed",
];

/// Friction regime over the contact set.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub enum Regime {
    /// No contact.
    #[default]
    None,
    /// Every contact sticks.
    Stick,
    /// Every contact slips.
    Slip,
    /// Some stick, some slip.
    Mixed,
}

impl Regime {
    /// Index of the one-hot entry (none, stick, slip, mixed).
    pub fn index(self) -> usize {
        self as usize
    }
}

/// One observation: y_t plus the extras (SI units throughout).
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Observation {
    /// Simulated time (s).
    pub time: f64,
    /// Controller phase.
    pub phase: Option<Phase>,
    /// Retained liquid mass (kg).
    pub m_l: f64,
    /// Mean saturation (-).
    pub saturation: f64,
    /// Pore volume (m^3).
    pub v_pore: f64,
    /// Sponge volume (m^3).
    pub v_sponge: f64,
    /// Pad-to-pad width (m).
    pub width: f64,
    /// Realised load, mean of the pad loads (N).
    pub f_meas: f64,
    /// Left pad load (N).
    pub f_l: f64,
    /// Right pad load (N).
    pub f_r: f64,
    /// Contact area on the left pad (m^2).
    pub a_l: f64,
    /// Contact area on the right pad (m^2).
    pub a_r: f64,
    /// Valid bilateral contact.
    pub contact: bool,
    /// Mean tangential velocity before friction (m/s).
    pub v_tan: [f64; 3],
    /// Total friction force on the sponge from the pads (N).
    pub f_fric: [f64; 3],
    /// Residual slip (m/s); `None` without contact.
    pub v_res: Option<f64>,
    /// Friction regime.
    pub regime: Regime,
    /// Force target of the command applied in the step that led here (N).
    pub f_target: f64,
    /// Closing speed of that command (m/s).
    pub v_cmd: f64,
    /// Skeleton centre-of-mass velocity (m/s).
    pub v_com: [f64; 3],
    /// Lift gate open.
    pub gate_open: bool,
    /// Liquid outside the skeleton's support (kg).
    pub m_expelled: f64,
    /// Pad displacement along the lift axis since the lift began (m).
    pub lift_height: f64,
    /// Wrist load: total force of the sponge and its water on both pads (N, world axes).
    pub wrist_load: [f64; 3],
}

impl Observation {
    /// Load imbalance alpha_F = |F_L - F_R| / (F_L + F_R + eps).
    pub fn alpha_f(&self) -> f64 {
        (self.f_l - self.f_r).abs() / (self.f_l + self.f_r + EPS_F)
    }

    /// The 23 values of y_t in the order of [`NAMES`]; `v_res` is NaN without contact.
    pub fn values(&self) -> [f64; 23] {
        let mut r = [0.0; 4];
        r[self.regime.index()] = 1.0;
        [
            self.m_l,
            self.saturation,
            self.v_pore,
            self.v_sponge,
            self.width,
            self.f_meas,
            self.f_l,
            self.f_r,
            self.alpha_f(),
            self.a_l,
            self.a_r,
            if self.contact { 1.0 } else { 0.0 },
            self.v_tan[0],
            self.v_tan[1],
            self.v_tan[2],
            self.f_fric[0],
            self.f_fric[1],
            self.f_fric[2],
            self.v_res.unwrap_or(f64::NAN),
            r[0],
            r[1],
            r[2],
            r[3],
        ]
    }
}

/// Contact aggregates over the pads' contact set.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct ContactSummary {
    /// Contacting particles on the left and right pads.
    pub count: (usize, usize),
    /// Mean tangential velocity before friction (m/s).
    pub v_tan: Vector3<f64>,
    /// Total friction force on the sponge (N).
    pub f_fric: Vector3<f64>,
    /// Mean corrected tangential speed (m/s), `None` without contact.
    pub v_res: Option<f64>,
    /// Regime.
    pub regime: Regime,
}

/// Aggregates friction records of the pads `left` and `right` (other bodies are ignored).
pub fn summarise(records: &[ContactFriction], left: usize, right: usize) -> ContactSummary {
    let mut s = ContactSummary::default();
    let (mut stick, mut slip, mut res) = (0usize, 0usize, 0.0);
    for r in records {
        let b = r.body as usize;
        if b == left {
            s.count.0 += 1;
        } else if b == right {
            s.count.1 += 1;
        } else {
            continue;
        }
        s.v_tan += r.v_tan;
        s.f_fric += r.force;
        res += r.v_tan_corr.norm();
        if r.stick {
            stick += 1;
        } else {
            slip += 1;
        }
    }
    let n = s.count.0 + s.count.1;
    if n > 0 {
        s.v_tan /= n as f64;
        s.v_res = Some(res / n as f64);
    }
    s.regime = match (stick, slip) {
        (0, 0) => Regime::None,
        (_, 0) => Regime::Stick,
        (0, _) => Regime::Slip,
        _ => Regime::Mixed,
    };
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    fn rec(body: u16, stick: bool, vt: f64, corr: f64) -> ContactFriction {
        ContactFriction {
            particle: 0,
            body,
            normal_force: 1.0,
            v_tan: Vector3::new(vt, 0.0, 0.0),
            force: Vector3::new(0.0, 0.0, 1.0),
            v_tan_corr: Vector3::new(0.0, corr, 0.0),
            stick,
        }
    }

    #[test]
    fn summary_regimes_and_magnitude_average() {
        assert_eq!(summarise(&[], 1, 2).regime, Regime::None);
        assert_eq!(summarise(&[], 1, 2).v_res, None);
        // Floor contacts (body 0) are not part of the pads' contact set.
        assert_eq!(summarise(&[rec(0, true, 1.0, 1.0)], 1, 2).regime, Regime::None);
        let s = summarise(&[rec(1, true, 1.0, 0.1), rec(2, false, -1.0, -0.3)], 1, 2);
        assert_eq!(s.regime, Regime::Mixed);
        assert_eq!(s.count, (1, 1));
        // Opposite slips do not cancel in v_res, they do in the signed mean v_tan.
        assert!((s.v_res.unwrap() - 0.2).abs() < 1e-12);
        assert!(s.v_tan.norm() < 1e-12);
        assert_eq!(summarise(&[rec(1, false, 1.0, 0.0)], 1, 2).regime, Regime::Slip);
        assert_eq!(summarise(&[rec(2, true, 1.0, 0.0)], 1, 2).regime, Regime::Stick);
    }

    #[test]
    fn values_follow_the_paper_order() {
        let o = Observation { m_l: 1.0, f_l: 30.0, f_r: 10.0, regime: Regime::Slip, ..Default::default() };
        let v = o.values();
        assert_eq!(v[0], 1.0);
        assert!((v[8] - 0.5).abs() < 1e-6);
        assert!(v[18].is_nan());
        assert_eq!(&v[19..], &[0.0, 0.0, 1.0, 0.0]);
        assert_eq!(NAMES[18], "v_res");
    }
}
