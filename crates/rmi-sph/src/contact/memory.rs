//! Contact memory: the anchors of the skeleton particles that stick, kept from step to step,
//! and the bookkeeping of each step's friction (the held sticks' forces, Eq. 4 for the
//! others, the reactions on the bodies).

use super::{coulomb, ContactStage, FrictionForce, FrictionParams, Stick};
use crate::error::{Result, RmiError};
use crate::world::boundary::{BodyState, Boundary};
use nalgebra::{Matrix3, Vector3};
use serde::{Deserialize, Serialize};

/// A stored stick point: body index and contact point in that body's frame (m).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Anchor {
    /// Body index.
    pub body: u16,
    /// Contact point in the body frame (m).
    pub local: [f64; 3],
}

/// Per-contact result of a friction pass, for the observation.
#[derive(Clone, Copy, Debug)]
pub struct ContactFriction {
    /// Dynamic particle index.
    pub particle: u32,
    /// Body index.
    pub body: u16,
    /// Normal load N_s (N).
    pub normal_force: f64,
    /// Tangential velocity relative to the body before friction (m/s), Eq. S3.
    pub v_tan: Vector3<f64>,
    /// Applied friction force on the particle (N).
    pub force: Vector3<f64>,
    /// Tangential velocity relative to the body after friction (m/s), Eq. S7.
    pub v_tan_corr: Vector3<f64>,
    /// Stick (true) or slip.
    pub stick: bool,
}

/// Contact memory: the anchors of all skeleton particles, indexed by solid index.
#[derive(Clone, Debug, Default, Serialize, Deserialize)]
pub struct ContactMemory {
    anchors: Vec<Vec<Anchor>>,
}

impl ContactMemory {
    /// Memory for `n_solid` skeleton particles, all without anchor.
    pub fn new(n_solid: usize) -> Self {
        ContactMemory { anchors: vec![Vec::new(); n_solid] }
    }

    /// Number of skeleton particles the memory covers.
    pub fn particles(&self) -> usize {
        self.anchors.len()
    }

    /// Number of anchors currently stored.
    pub fn len(&self) -> usize {
        self.anchors.iter().map(Vec::len).sum()
    }

    /// True when no anchor is stored.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// The anchor of solid particle `s` on `body`, if it sticks there.
    pub fn anchor(&self, s: usize, body: u16) -> Option<&Anchor> {
        self.anchors.get(s)?.iter().find(|a| a.body == body)
    }

    /// Refuses a memory read from a saved state whose anchors a step could not use: a body
    /// index outside the `bodies` bodies, a second anchor on one body, or a non-finite
    /// point; `n_fluid` offsets solid indices to the particle indices the error names.
    pub fn check(&self, bodies: usize, n_fluid: usize) -> Result<()> {
        for (s, slot) in self.anchors.iter().enumerate() {
            for (k, a) in slot.iter().enumerate() {
                let at = |field: &str, value: String, expected: String| {
                    RmiError::State(format!(
                        "contact memory of particle {}: anchor `{field}` = {value} is not accepted; expected {expected}",
                        n_fluid + s
                    ))
                };
                if usize::from(a.body) >= bodies || slot[..k].iter().any(|b| b.body == a.body) {
                    let expected = format!("a body index in [0, {bodies}) that no other anchor of the particle holds");
                    return Err(at("body", a.body.to_string(), expected));
                }
                if !a.local.iter().all(|c| c.is_finite()) {
                    let value = format!("[{}, {}, {}]", a.local[0], a.local[1], a.local[2]);
                    return Err(at("local", value, "finite components (m)".into()));
                }
            }
        }
        Ok(())
    }

    /// The anchors in world coordinates of the bodies' current poses, sorted by particle and
    /// body, for [`Friction::anchors`](super::Friction::anchors); `n_fluid` offsets solid indices to particle indices.
    pub fn sticks(&self, n_fluid: usize, boundary: &Boundary) -> Vec<Stick> {
        let mut out = Vec::new();
        for (s, slot) in self.anchors.iter().enumerate() {
            let first = out.len();
            for a in slot {
                let b = &boundary.bodies[a.body as usize].state;
                let anchor = b.position + b.rotation * Vector3::from(a.local);
                out.push(Stick { particle: (n_fluid + s) as u32, body: a.body, anchor });
            }
            out[first..].sort_by_key(|x| x.body);
        }
        out
    }

    /// Applies friction to every skeleton contact with a body in `bodies` (and a positive
    /// normal load), updates the anchors, adds the reactions to the body loads and returns
    /// one record per contact, in particle order. Contacts that ended drop their anchors.
    ///
    /// A contact whose friction the step's solves held ([`crate::contact::Contact::held`],
    /// coupled friction) is bookkept only: its force is applied and in the body's load, and
    /// its anchor is kept (or set) when it stuck and dropped when it slid. Every other
    /// contact gets Eq. 4 on its particle's velocity.
    pub fn apply(&mut self, stage: &mut ContactStage<'_>, bodies: &[bool], p: &FrictionParams) -> Vec<ContactFriction> {
        let nf = stage.particles.n_fluid;
        let dt = stage.dt;
        let mut touched = vec![false; self.anchors.len()];
        let mut out = Vec::new();
        for c in stage.contacts {
            let a = c.particle as usize;
            let bi = c.body as usize;
            if a < nf || c.normal_force <= 0.0 || !bodies.get(bi).copied().unwrap_or(false) {
                continue;
            }
            let s = a - nf;
            if stage.rest_fixed[s] {
                continue;
            }
            touched[s] = true;
            let body = stage.body(bi).clone();
            let n = c.normal;
            let proj = Matrix3::identity() - n * n.transpose();
            let vb = point_velocity(&body, &c.point);
            let m = stage.particles.mass[a];
            let slot = &mut self.anchors[s];
            let existing = slot.iter().position(|x| x.body == c.body);
            let (f, v_tan) = match c.held {
                Some(held) => {
                    let f = FrictionForce { force: held.force, stick: held.stuck };
                    // The tendency before friction: the velocity without the force.
                    (f, proj * (stage.v[a] - vb) - dt / m * held.force)
                }
                None => {
                    let v_tan = proj * (stage.v[a] - vb);
                    let e = match existing {
                        Some(k) => proj * (body.position + body.rotation * Vector3::from(slot[k].local) - c.point),
                        None => Vector3::zeros(),
                    };
                    let f = coulomb(m, dt, c.normal_force, &e, &v_tan, p);
                    stage.v[a] += dt / m * f.force;
                    let (force, torque) = &mut stage.body_forces[bi];
                    *force -= f.force;
                    *torque -= (c.point - body.position).cross(&f.force);
                    (f, v_tan)
                }
            };
            match (f.stick, existing) {
                (true, None) => {
                    let q = body.rotation.inverse() * (c.point - body.position);
                    slot.push(Anchor { body: c.body, local: q.into() });
                }
                (false, Some(k)) => {
                    slot.remove(k);
                }
                _ => {}
            }
            out.push(ContactFriction {
                particle: c.particle,
                body: c.body,
                normal_force: c.normal_force,
                v_tan,
                force: f.force,
                v_tan_corr: proj * (stage.v[a] - vb),
                stick: f.stick,
            });
        }
        // A contact that ended forgets its anchor; so does one whose body lost the contact.
        for (s, slot) in self.anchors.iter_mut().enumerate() {
            if !touched[s] {
                slot.clear();
            } else {
                slot.retain(|x| out.iter().any(|r| r.particle as usize == s + nf && r.body == x.body));
            }
        }
        out
    }
}

/// Eq. S2: velocity of the body at a world point.
fn point_velocity(b: &BodyState, x: &Vector3<f64>) -> Vector3<f64> {
    b.velocity + b.angular_velocity.cross(&(x - b.position))
}

#[cfg(test)]
mod tests {
    use super::*;

    const M: f64 = 1e-3;
    const DT: f64 = 1e-3;

    /// One skeleton particle pressed against a static plate below it (normal +z).
    fn scene(v: Vector3<f64>) -> (crate::world::particles::Particles, crate::world::boundary::Boundary) {
        use crate::config::{BodyConfig, Shape};
        let k = crate::neighbourhood::kernel::CubicKernel::new(0.04);
        let cfg = BodyConfig {
            name: "plate".into(),
            shape: Shape::Box { half_extents: [0.2, 0.2, 0.01] },
            position: [0.0, 0.0, -0.02],
            rotation: [0.0; 3],
            kinematic: true,
        };
        let b = crate::world::boundary::Boundary::new(&[cfg], 0.01, &k, crate::config::WallLayer::Sunk);
        let p = crate::world::particles::Particles {
            n_fluid: 0,
            x: vec![Vector3::new(0.0, 0.0, -0.005)],
            v: vec![v],
            mass: vec![M],
            material: vec![1],
            id: vec![0],
        };
        (p, b)
    }

    fn run(
        mem: &mut ContactMemory,
        p: &crate::world::particles::Particles,
        b: &crate::world::boundary::Boundary,
        normal: f64,
    ) -> (Vector3<f64>, Vec<ContactFriction>) {
        let contacts = [crate::contact::Contact {
            particle: 0,
            body: 0,
            normal: Vector3::z(),
            point: Vector3::new(p.x[0].x, p.x[0].y, -0.01),
            normal_force: normal,
            held: None,
        }];
        let mut v = p.v.clone();
        let mut forces = vec![(Vector3::zeros(), Vector3::zeros())];
        let mut stage = ContactStage {
            particles: p,
            v: &mut v,
            contacts: &contacts,
            boundary: b,
            body_forces: &mut forces,
            dt: DT,
            rest_fixed: &[false],
        };
        let out = mem.apply(&mut stage, &[true], &FrictionParams::default());
        // Reaction on the plate balances the force on the particle.
        assert!((forces[0].0 + out[0].force).norm() < 1e-15);
        (v[0], out)
    }

    #[test]
    fn saved_anchors_a_step_could_not_use_are_refused() {
        let anchor = |body: u16, local: [f64; 3]| Anchor { body, local };
        let memory = |slot: Vec<Anchor>| ContactMemory { anchors: vec![Vec::new(), slot] };
        memory(vec![anchor(0, [0.0, 0.0, 0.01]), anchor(1, [0.0; 3])]).check(2, 10).unwrap();
        for (slot, start) in [
            (vec![anchor(2, [0.0; 3])], "contact memory of particle 11: anchor `body` = 2 "),
            (vec![anchor(1, [0.0; 3]), anchor(1, [0.0; 3])], "contact memory of particle 11: anchor `body` = 1 "),
            (
                vec![anchor(0, [0.0, f64::INFINITY, 0.0])],
                "contact memory of particle 11: anchor `local` = [0, inf, 0] ",
            ),
        ] {
            match memory(slot).check(2, 10) {
                Err(RmiError::State(m)) => {
                    assert!(m.starts_with(start) && m.contains("is not accepted; expected"), "{m}")
                }
                r => panic!("{start}: expected a state error, got {r:?}"),
            }
        }
    }

    #[test]
    fn memory_keeps_the_anchor_while_sticking_and_drops_it_on_slip() {
        let (mut p, b) = scene(Vector3::new(1e-3, 0.0, 0.0));
        let mut mem = ContactMemory::new(1);
        let (v, out) = run(&mut mem, &p, &b, 10.0);
        assert!(out[0].stick && v.x.abs() < 1e-15);
        let first = *mem.anchor(0, 0).expect("anchor stored on stick");
        // The particle creeps 0.1 mm: the anchor stays where it was, and the demand pulls back.
        p.x[0].x += 1e-4;
        p.v[0] = Vector3::zeros();
        let (v, out) = run(&mut mem, &p, &b, 10.0);
        assert!(out[0].stick);
        assert_eq!(*mem.anchor(0, 0).unwrap(), first);
        assert!((v.x + FrictionParams::default().beta * 1e-4 / DT).abs() < 1e-12, "restoring velocity {v:?}");
        // A demand beyond mu_st N releases the anchor and applies the kinetic force.
        p.v[0] = Vector3::new(1.0, 0.0, 0.0);
        let (v, out) = run(&mut mem, &p, &b, 0.1);
        assert!(!out[0].stick && mem.anchor(0, 0).is_none());
        assert!((out[0].force.x + 0.5 * 0.1).abs() < 1e-12);
        assert!(v.x > 0.0 && v.x < 1.0);
        // A new anchor is created when sticking is established again.
        p.v[0] = Vector3::zeros();
        let (_, out) = run(&mut mem, &p, &b, 10.0);
        assert!(out[0].stick);
        assert_eq!(mem.anchor(0, 0).unwrap().local, [p.x[0].x, 0.0, 0.01]);
        // A contact that ends forgets its anchor.
        let mut stage_v = p.v.clone();
        let mut forces = vec![(Vector3::zeros(), Vector3::zeros())];
        let mut stage = ContactStage {
            particles: &p,
            v: &mut stage_v,
            contacts: &[],
            boundary: &b,
            body_forces: &mut forces,
            dt: DT,
            rest_fixed: &[false],
        };
        mem.apply(&mut stage, &[true], &FrictionParams::default());
        assert!(mem.is_empty());
    }
}
