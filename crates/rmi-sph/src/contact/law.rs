//! The friction law between skeleton particles and bodies: its parameters, Coulomb's cone
//! solved inside the implicit system ([`Friction`]), and Eq. 4 applied to a particle after
//! the solves ([`coulomb`]).

use crate::config::check_range;
use nalgebra::Vector3;
use serde::{Deserialize, Serialize};

/// A contact that stuck in the previous step, with its anchor in world coordinates.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Stick {
    /// Dynamic particle index.
    pub particle: u32,
    /// Body index.
    pub body: u16,
    /// Anchor (stick point) in world coordinates at the start of the step (m).
    pub anchor: Vector3<f64>,
}

/// Coulomb friction between skeleton particles and bodies, solved inside the implicit
/// system (paper Eq. 4 as constraints): every skeleton contact with
/// a body in `bodies` first holds its tangential velocity, the body's plus `gain e / dt`
/// toward its anchor if it has one; a contact whose holding force leaves the static cone
/// `mu_static N` slides with the kinetic force `mu_kinetic N` along it instead.
#[derive(Clone, Copy, Debug)]
pub struct Friction<'a> {
    /// Per body: whether its contacts have friction.
    pub bodies: &'a [bool],
    /// Static coefficient mu_st.
    pub mu_static: f64,
    /// Kinetic coefficient mu_kin (at most mu_st).
    pub mu_kinetic: f64,
    /// Positional recovery gain beta in (0, 1].
    pub gain: f64,
    /// The anchors of the previous step, sorted by particle and body.
    pub anchors: &'a [Stick],
}

impl Friction<'_> {
    /// Whether contacts with body `bi` have friction.
    pub fn on(&self, bi: usize) -> bool {
        self.bodies.get(bi).copied().unwrap_or(false)
    }

    /// The anchor of `particle` on `body`, if it stuck there in the previous step.
    pub fn anchor(&self, particle: u32, body: u16) -> Option<&Stick> {
        self.anchors.binary_search_by_key(&(particle, body), |s| (s.particle, s.body)).ok().map(|k| &self.anchors[k])
    }
}

/// Friction parameters. Dimensionless except `eps_v` (m/s).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct FrictionParams {
    /// Static coefficient mu_st.
    pub mu_static: f64,
    /// Kinetic coefficient mu_kin (at most mu_st).
    pub mu_kinetic: f64,
    /// Positional recovery gain beta in (0, 1].
    pub beta: f64,
    /// Regulariser of the slip direction (m/s), > 0.
    pub eps_v: f64,
    /// Solve friction inside the coupled implicit system (contacts as constraints of the
    /// solves, Coulomb's cone enforced on their reactions); `false` adds each Eq. 4 force to
    /// its skeleton particle's velocity after the solves, as the paper reads.
    pub coupled: bool,
}

impl Default for FrictionParams {
    fn default() -> Self {
        FrictionParams { mu_static: 0.6, mu_kinetic: 0.5, beta: 0.2, eps_v: 1e-6, coupled: true }
    }
}

impl FrictionParams {
    /// This law on `bodies` with these anchors, for
    /// [`crate::Simulation::step_with_friction`].
    pub fn law<'a>(&self, anchors: &'a [Stick], bodies: &'a [bool]) -> Friction<'a> {
        Friction { bodies, mu_static: self.mu_static, mu_kinetic: self.mu_kinetic, gain: self.beta, anchors }
    }

    /// Validates every field; `p` is the dotted path used in error messages.
    pub fn validate(&self, p: &str) -> crate::Result<()> {
        let range = check_range;
        range(&format!("{p}.mu_static"), self.mu_static, 0.0, 10.0, "(dimensionless)")?;
        range(&format!("{p}.mu_kinetic"), self.mu_kinetic, 0.0, self.mu_static, "(dimensionless, at most mu_static)")?;
        range(&format!("{p}.beta"), self.beta, 1e-6, 1.0, "(dimensionless)")?;
        range(&format!("{p}.eps_v"), self.eps_v, 1e-12, 1.0, "m/s")
    }
}

/// The outcome of Eq. 4 for one contact.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FrictionForce {
    /// Force applied to the particle (N), tangential.
    pub force: Vector3<f64>,
    /// True when the demand stayed inside the static cone (the anchor is kept).
    pub stick: bool,
}

/// Eq. 4a-4d: the friction force on a particle of mass `m` (kg) with normal load `normal`
/// (N), tangential anchor error `e` (m) and tangential velocity before friction `v_tan`
/// (m/s), over a step `dt` (s).
pub fn coulomb(
    m: f64,
    dt: f64,
    normal: f64,
    e: &Vector3<f64>,
    v_tan: &Vector3<f64>,
    p: &FrictionParams,
) -> FrictionForce {
    let demand = (m / dt) * (p.beta / dt * e - v_tan);
    if demand.norm() <= p.mu_static * normal {
        return FrictionForce { force: demand, stick: true };
    }
    let speed = v_tan.norm();
    // Eq. 4b: never more than what stops the slip in this step.
    let kappa = (p.mu_kinetic * normal).min(m * speed / dt);
    FrictionForce { force: -kappa * v_tan / speed.max(p.eps_v), stick: false }
}

#[cfg(test)]
mod tests {
    use super::*;

    const M: f64 = 1e-3;
    const DT: f64 = 1e-3;

    #[test]
    fn stick_inside_the_static_cone() {
        let p = FrictionParams::default();
        let v = Vector3::new(0.001, 0.0, 0.0);
        let f = coulomb(M, DT, 10.0, &Vector3::zeros(), &v, &p);
        assert!(f.stick);
        // The demand cancels the tangential velocity exactly.
        assert!((f.force + M / DT * v).norm() < 1e-15);
    }

    #[test]
    fn anchor_error_pulls_back_with_gain_beta() {
        let p = FrictionParams::default();
        let e = Vector3::new(0.0, 1e-4, 0.0);
        let f = coulomb(M, DT, 10.0, &e, &Vector3::zeros(), &p);
        assert!(f.stick);
        assert!((f.force - M / (DT * DT) * p.beta * e).norm() < 1e-12);
    }

    #[test]
    fn exceeding_the_static_bound_slips_with_the_kinetic_force() {
        let p = FrictionParams::default();
        let v = Vector3::new(0.0, 0.0, -1.0);
        let normal = 0.5; // demand m v / dt = 1 N > 0.6 * 0.5
        let f = coulomb(M, DT, normal, &Vector3::zeros(), &v, &p);
        assert!(!f.stick);
        assert!((f.force - Vector3::new(0.0, 0.0, p.mu_kinetic * normal)).norm() < 1e-12);
    }

    #[test]
    fn kinetic_correction_never_reverses_the_slip() {
        let p = FrictionParams::default();
        // A large anchor error forces slip although the particle barely moves: the kinetic
        // force must stop at zero tangential velocity, not push it backwards.
        let v = Vector3::new(1e-4, 0.0, 0.0);
        let e = Vector3::new(-1.0, 0.0, 0.0);
        let f = coulomb(M, DT, 1.0, &e, &v, &p);
        assert!(!f.stick);
        let v_after = v + DT / M * f.force;
        assert!(v_after.dot(&v) >= -1e-15, "slip reversed: {v_after:?}");
        assert!(v_after.norm() < 1e-15);
    }

    #[test]
    fn zero_velocity_slip_stays_finite() {
        let p = FrictionParams::default();
        let f = coulomb(M, DT, 0.1, &Vector3::new(1.0, 0.0, 0.0), &Vector3::zeros(), &p);
        assert!(!f.stick && f.force.iter().all(|x| x.is_finite()) && f.force.norm() == 0.0);
    }
}
