//! Rigid boundary bodies: static walls and kinematic boxes (the gripper plates).
//!
//! Each body is sampled with one layer of Akinci et al. 2012 boundary particles (fluid and
//! solid see it in densities and the pressure solve) and also keeps its analytic shape, used
//! for the velocity-level non-penetration of skeleton particles (docs/physics.md §3.7).

use crate::config::{BodyConfig, Shape, WallLayer};
use crate::neighbourhood::grid::{bounds, Grid};
use crate::neighbourhood::kernel::CubicKernel;
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

/// Samples the surface of a box of half extents `he` (m) with spacing close to `d`. An axis
/// with a zero half extent is one plane: the box is then a single sheet of particles.
fn sample_box_surface(he: &Vector3<f64>, d: f64) -> Vec<Vector3<f64>> {
    let coords: Vec<Vec<f64>> = (0..3)
        .map(|k| {
            if he[k] == 0.0 {
                return vec![0.0];
            }
            let n = ((2.0 * he[k] / d).round() as usize).max(1);
            (0..=n).map(|i| -he[k] + 2.0 * he[k] * i as f64 / n as f64).collect()
        })
        .collect();
    let flat = coords.iter().any(|c| c.len() == 1);
    let mut pts = Vec::new();
    for (i, &x) in coords[0].iter().enumerate() {
        for (j, &y) in coords[1].iter().enumerate() {
            for (l, &z) in coords[2].iter().enumerate() {
                let edge = |k: usize, q: usize| q == 0 || q + 1 == coords[k].len();
                if flat || edge(0, i) || edge(1, j) || edge(2, l) {
                    pts.push(Vector3::new(x, y, z));
                }
            }
        }
    }
    pts
}

/// Depth (m) below a flat wall's surface at which its one layer of Akinci particles (volumes
/// `1 / sum W` over the layer) gives water whose first lattice plane lies `d / 2` from the
/// surface the density of the bulk lattice: 0.598 d for the cubic spline with H = 2 d.
///
/// One layer stands in for the whole half space behind it; on the surface it puts that
/// water at 1.55 times the rest density, and water rests 1.1 d off the wall instead, while
/// skeleton contacts hold a sponge's particles at d / 2. Found by bisection on the kernel's
/// lattice sums (water lattice aligned with the layer).
pub fn wall_depth(d: f64, kernel: &CubicKernel) -> f64 {
    let reach = (kernel.support() / d).ceil() as i32 + 1;
    // Sum of W over the square lattice of spacing d in a plane at height z above a point.
    let plane = |z: f64| -> f64 {
        let mut s = 0.0;
        for i in -reach..=reach {
            for j in -reach..=reach {
                let (x, y) = (i as f64 * d, j as f64 * d);
                s += kernel.w((x * x + y * y + z * z).sqrt());
            }
        }
        s
    };
    let v = d * d * d;
    let bulk: f64 = (-reach..=reach).map(|k| plane(k as f64 * d)).sum::<f64>() * v;
    let half: f64 = (0..=reach).map(|k| plane(k as f64 * d)).sum::<f64>() * v;
    let layer_volume = 1.0 / plane(0.0);
    let density = |depth: f64| half + layer_volume * plane(0.5 * d + depth);
    let (mut lo, mut hi) = (0.0, d);
    for _ in 0..60 {
        let mid = 0.5 * (lo + hi);
        if density(mid) > bulk {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    0.5 * (lo + hi)
}

/// Half extents (m) of the box on which a body's boundary particles are sampled: the shape
/// shrunk (solid box) or grown (container) by `depth`. An axis along which a solid box is
/// thinner than `2 depth + d` collapses to one plane through its centre, so that the two
/// faces' layers do not lie within a spacing of each other and count twice.
fn layer_half_extents(shape: &Shape, depth: f64, d: f64) -> Vector3<f64> {
    match shape {
        Shape::Box { half_extents } => {
            Vector3::from(*half_extents).map(|h| if h - depth < 0.5 * d { 0.0 } else { h - depth })
        }
        Shape::Container { half_extents } => Vector3::from(*half_extents).add_scalar(depth),
    }
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
    /// Samples every body with spacing `d`, its layer placed as `layer` says, and computes
    /// Akinci volumes `V_k = 1 / sum_l W_kl`.
    pub fn new(configs: &[BodyConfig], d: f64, kernel: &CubicKernel, layer: WallLayer) -> Self {
        let mut b = Boundary::default();
        let depth = match layer {
            WallLayer::Sunk => wall_depth(d, kernel),
            WallLayer::Surface => 0.0,
        };
        for (bi, c) in configs.iter().enumerate() {
            let pts = sample_box_surface(&layer_half_extents(&c.shape, depth, d), d);
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
        let b = Boundary::new(&[cfg], 0.02, &k, WallLayer::Surface);
        // A particle in the middle of the top face: volume is a few d^3 (one layer stands in
        // for the missing half space).
        let mid = b.local.iter().position(|p| p.x.abs() < 1e-9 && p.y.abs() < 1e-9 && p.z > 0.0).unwrap();
        let v = b.volume[mid] / 0.02f64.powi(3);
        assert!(v > 1.0 && v < 3.0, "V/d^3 = {v}");
    }

    /// Density ratio at `x` of a water lattice of spacing `d` (given as its points) plus the
    /// boundary particles of `b`.
    fn density(x: &Vector3<f64>, water: &[Vector3<f64>], b: &Boundary, k: &CubicKernel, d: f64) -> f64 {
        let fluid: f64 = water.iter().map(|y| k.w((x - y).norm())).sum::<f64>() * d * d * d;
        let wall: f64 = b.x.iter().zip(&b.volume).map(|(y, v)| v * k.w((x - y).norm())).sum();
        fluid + wall
    }

    #[test]
    fn water_half_a_spacing_off_a_sunk_wall_has_the_bulk_density() {
        let d = 0.02;
        let k = CubicKernel::new(2.0 * d);
        let depth = wall_depth(d, &k);
        assert!((depth / d - 0.598).abs() < 1e-3, "depth {} d", depth / d);
        // A floor whose sunk top layer is a lattice of spacing d aligned with the water's, its
        // bottom layer out of the kernel's reach; the top surface at z = 0.
        let he = [12.0 * d + depth, 12.0 * d + depth, 2.0 * d + depth];
        let floor = |layer| {
            let cfg = BodyConfig {
                name: "floor".into(),
                shape: Shape::Box { half_extents: he },
                position: [0.0, 0.0, -he[2]],
                rotation: [0.0; 3],
                kinematic: false,
            };
            Boundary::new(&[cfg], d, &k, layer)
        };
        let mut water = Vec::new();
        for i in -4..=4 {
            for j in -4..=4 {
                for l in 0..4 {
                    water.push(Vector3::new(i as f64 * d, j as f64 * d, (0.5 + l as f64) * d));
                }
            }
        }
        let mut bulk = 0.0;
        for i in -3..=3 {
            for j in -3..=3 {
                for l in -3..=3 {
                    bulk += k.w(d * ((i * i + j * j + l * l) as f64).sqrt());
                }
            }
        }
        bulk *= d * d * d;
        let x = Vector3::new(0.0, 0.0, 0.5 * d);
        let sunk = density(&x, &water, &floor(WallLayer::Sunk), &k, d);
        assert!((sunk - bulk).abs() < 1e-9, "sunk layer: {sunk} against the bulk {bulk}");
        // The same water against a layer on the surface is compressed by more than a third.
        let surface = density(&x, &water, &floor(WallLayer::Surface), &k, d);
        assert!(surface > 1.33 * bulk, "surface layer: {surface}");
    }

    #[test]
    fn thin_boxes_collapse_to_one_sheet() {
        let d = 0.016;
        let k = CubicKernel::new(2.0 * d);
        let pad = BodyConfig {
            name: "pad".into(),
            shape: Shape::Box { half_extents: [0.01, 0.05, 0.05] },
            position: [0.0; 3],
            rotation: [0.0; 3],
            kinematic: true,
        };
        let b = Boundary::new(&[pad], d, &k, WallLayer::Sunk);
        assert!(b.local.iter().all(|p| p.x == 0.0), "a 20 mm pad at d = 16 mm is one sheet");
        let n = b.local.len();
        let mut unique = b.local.clone();
        unique.sort_by(|a, c| {
            a.iter().zip(c.iter()).map(|(x, y)| x.total_cmp(y)).find(|o| o.is_ne()).unwrap_or(std::cmp::Ordering::Equal)
        });
        unique.dedup();
        assert_eq!(unique.len(), n, "no particle is sampled twice");
    }
}
