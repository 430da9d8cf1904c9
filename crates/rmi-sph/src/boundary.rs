//! Rigid boundary bodies: static walls and kinematic boxes (the gripper plates).
//!
//! Each body is sampled with one layer of Akinci et al. 2012 boundary particles (fluid and
//! solid see it in densities and the pressure solve) and also keeps its analytic shape, used
//! for the velocity-level non-penetration of skeleton particles (physics.md sec. 3.7).

use crate::config::{BodyConfig, Shape};
use crate::grid::{bounds, Grid};
use crate::kernel::CubicKernel;
use nalgebra::{UnitQuaternion, Vector3};
use serde::{Deserialize, Serialize};

/// Pose and motion of one body; this is the state that snapshots carry.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct BodyState {
    /// Centre position in m.
    pub position: Vector3<f64>,
    /// Orientation.
    pub rotation: UnitQuaternion<f64>,
    /// Linear velocity in m/s.
    pub velocity: Vector3<f64>,
    /// Angular velocity in rad/s (world frame).
    pub angular_velocity: Vector3<f64>,
}

/// A rigid body with its sampled boundary particles.
#[derive(Clone, Debug)]
pub struct Body {
    /// Name from the config.
    pub name: String,
    /// Shape in the body frame.
    pub shape: Shape,
    /// Moves under caller control.
    pub kinematic: bool,
    /// Pose and velocities.
    pub state: BodyState,
    /// Range of this body's particles in [`Boundary`] arrays.
    pub range: std::ops::Range<usize>,
    /// Force exerted on the body by fluid and solid during the last step, N (pressure plus
    /// contact impulses divided by dt).
    pub force: Vector3<f64>,
    /// Torque about the body centre during the last step, N m.
    pub torque: Vector3<f64>,
}

/// All boundary particles, with body-frame positions and Akinci volumes.
#[derive(Clone, Debug, Default)]
pub struct Boundary {
    /// Bodies in config order.
    pub bodies: Vec<Body>,
    /// Body-frame positions in m.
    pub local: Vec<Vector3<f64>>,
    /// World positions in m (updated from the body poses).
    pub x: Vec<Vector3<f64>>,
    /// World velocities in m/s.
    pub v: Vec<Vector3<f64>>,
    /// Akinci volumes in m^3.
    pub volume: Vec<f64>,
    /// Owning body of each particle.
    pub body: Vec<u16>,
    /// Grid over the boundary particles (rebuilt only when a body moved).
    pub grid: Grid,
    grid_valid: bool,
}

/// Samples the surface of a box of half extents `he` with spacing close to `d`.
fn sample_box_surface(he: &Vector3<f64>, d: f64) -> Vec<Vector3<f64>> {
    let n: Vec<usize> = (0..3).map(|k| ((2.0 * he[k] / d).round() as usize).max(1)).collect();
    let mut pts = Vec::new();
    for i in 0..=n[0] {
        for j in 0..=n[1] {
            for l in 0..=n[2] {
                let on = i == 0 || i == n[0] || j == 0 || j == n[1] || l == 0 || l == n[2];
                if on {
                    pts.push(Vector3::new(
                        -he[0] + 2.0 * he[0] * i as f64 / n[0] as f64,
                        -he[1] + 2.0 * he[1] * j as f64 / n[1] as f64,
                        -he[2] + 2.0 * he[2] * l as f64 / n[2] as f64,
                    ));
                }
            }
        }
    }
    pts
}

/// Signed distance (m) from a body-frame point to the shape's surface, positive on the side
/// where particles belong, and the unit normal pointing to that side.
pub fn signed_distance(shape: &Shape, p: &Vector3<f64>) -> (f64, Vector3<f64>) {
    match shape {
        Shape::Box { half_extents } => {
            let he = Vector3::from(*half_extents);
            let q = p.abs() - he;
            if q.max() > 0.0 {
                let outside = q.map(|c| c.max(0.0));
                let dist = outside.norm();
                let n = Vector3::from_fn(|k, _| outside[k] * p[k].signum()) / dist.max(1e-300);
                (dist, n)
            } else {
                // Inside: the nearest face decides.
                let k = q.imax();
                let mut n = Vector3::zeros();
                n[k] = if p[k] >= 0.0 { 1.0 } else { -1.0 };
                (q[k], n)
            }
        }
        Shape::Container { half_extents } => {
            let he = Vector3::from(*half_extents);
            let q = he - p.abs();
            let k = q.imin();
            let mut n = Vector3::zeros();
            n[k] = if p[k] >= 0.0 { -1.0 } else { 1.0 };
            (q[k], n)
        }
    }
}

impl Boundary {
    /// Samples every body with spacing `d` and computes Akinci volumes `V_k = 1 / sum_l W_kl`.
    pub fn new(configs: &[BodyConfig], d: f64, kernel: &CubicKernel) -> Self {
        let mut b = Boundary::default();
        for (bi, c) in configs.iter().enumerate() {
            let he = match &c.shape {
                Shape::Box { half_extents } | Shape::Container { half_extents } => Vector3::from(*half_extents),
            };
            let pts = sample_box_surface(&he, d);
            let start = b.local.len();
            // Volumes from the body's own particles: the sum is pose independent.
            let (lo, hi) = bounds(&pts, 0.0);
            let mut g = Grid::default();
            g.build(&pts, lo, hi, kernel.support());
            for p in &pts {
                let mut s = kernel.w0();
                g.for_each_candidate(p, |slot| {
                    let r = (g.point(slot) - p).norm();
                    if r > 1e-12 {
                        s += kernel.w(r);
                    }
                });
                b.volume.push(1.0 / s);
            }
            b.local.extend_from_slice(&pts);
            b.body.extend(std::iter::repeat_n(bi as u16, pts.len()));
            let rot = UnitQuaternion::from_scaled_axis(Vector3::from(c.rotation));
            b.bodies.push(Body {
                name: c.name.clone(),
                shape: c.shape.clone(),
                kinematic: c.kinematic,
                state: BodyState {
                    position: Vector3::from(c.position),
                    rotation: rot,
                    velocity: Vector3::zeros(),
                    angular_velocity: Vector3::zeros(),
                },
                range: start..b.local.len(),
                force: Vector3::zeros(),
                torque: Vector3::zeros(),
            });
        }
        b.x = vec![Vector3::zeros(); b.local.len()];
        b.v = vec![Vector3::zeros(); b.local.len()];
        b.update_particles();
        b
    }

    /// Recomputes world positions and velocities of boundary particles from the body states.
    pub fn update_particles(&mut self) {
        for body in &self.bodies {
            let s = &body.state;
            for k in body.range.clone() {
                let r = s.rotation * self.local[k];
                self.x[k] = s.position + r;
                self.v[k] = s.velocity + s.angular_velocity.cross(&r);
            }
        }
        self.grid_valid = false;
    }

    /// Rebuilds the boundary grid if any body moved since the last build.
    pub fn ensure_grid(&mut self, h: f64) {
        if !self.grid_valid {
            let (lo, hi) = bounds(&self.x, h);
            self.grid.build(&self.x, lo, hi, h);
            self.grid.mark_near();
            self.grid_valid = true;
        }
    }

    /// Advances kinematic bodies by `dt` with their current velocities.
    pub fn advance(&mut self, dt: f64) {
        let mut moved = false;
        for body in &mut self.bodies {
            if !body.kinematic {
                continue;
            }
            let s = &mut body.state;
            if s.velocity != Vector3::zeros() || s.angular_velocity != Vector3::zeros() {
                s.position += dt * s.velocity;
                s.rotation = UnitQuaternion::from_scaled_axis(dt * s.angular_velocity) * s.rotation;
                moved = true;
            }
        }
        if moved {
            self.update_particles();
        }
    }

    /// Index of the body called `name`.
    pub fn find(&self, name: &str) -> Option<usize> {
        self.bodies.iter().position(|b| b.name == name)
    }

    /// Signed distance and world normal of a world point to body `bi`.
    pub fn distance(&self, bi: usize, p: &Vector3<f64>) -> (f64, Vector3<f64>) {
        let s = &self.bodies[bi].state;
        let local = s.rotation.inverse() * (p - s.position);
        let (d, n) = signed_distance(&self.bodies[bi].shape, &local);
        (d, s.rotation * n)
    }

    /// Velocity of body `bi` at world point `p` (m/s).
    pub fn point_velocity(&self, bi: usize, p: &Vector3<f64>) -> Vector3<f64> {
        let s = &self.bodies[bi].state;
        s.velocity + s.angular_velocity.cross(&(p - s.position))
    }

    /// Marks the grid stale (after a pose was set from outside).
    pub fn invalidate(&mut self) {
        self.update_particles();
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn box_distance_signs() {
        let s = Shape::Box { half_extents: [1.0, 1.0, 1.0] };
        let (d, n) = signed_distance(&s, &Vector3::new(0.0, 0.0, 1.5));
        assert!((d - 0.5).abs() < 1e-12 && (n - Vector3::z()).norm() < 1e-12);
        let (d, n) = signed_distance(&s, &Vector3::new(0.9, 0.0, 0.0));
        assert!((d + 0.1).abs() < 1e-12 && (n - Vector3::x()).norm() < 1e-12);
        let c = Shape::Container { half_extents: [1.0, 2.0, 3.0] };
        let (d, n) = signed_distance(&c, &Vector3::new(0.0, 0.0, -2.5));
        assert!((d - 0.5).abs() < 1e-12 && (n - Vector3::z()).norm() < 1e-12);
    }

    #[test]
    fn akinci_volume_of_flat_wall_is_plausible() {
        let k = CubicKernel::new(0.04);
        let cfg = BodyConfig {
            name: "floor".into(),
            shape: Shape::Box { half_extents: [0.5, 0.5, 0.01] },
            position: [0.0; 3],
            rotation: [0.0; 3],
            kinematic: false,
        };
        let b = Boundary::new(&[cfg], 0.02, &k);
        // A particle in the middle of the top face: volume is a few d^3 (one layer stands in
        // for the missing half space).
        let mid = b.local.iter().position(|p| p.x.abs() < 1e-9 && p.y.abs() < 1e-9 && p.z > 0.0).unwrap();
        let v = b.volume[mid] / 0.02f64.powi(3);
        assert!(v > 1.0 && v < 3.0, "V/d^3 = {v}");
    }
}
