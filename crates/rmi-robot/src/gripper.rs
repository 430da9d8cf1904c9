//! Two parallel gripper pads: kinematic boxes that close along the squeeze axis (x) and move
//! together along the lift axis (z).
//!
//! The left pad sits at -x, the right at +x; a positive closing speed moves both toward the
//! sponge. Loads are read from the bodies' force read-back (pressure reactions of the water,
//! contact reactions of the skeleton and friction reactions), which is what a wrist
//! force sensor behind each pad would measure.

use nalgebra::Vector3;
use rmi_sph::config::{check_range, BodyConfig, Shape, SimConfig};
use rmi_sph::world::Boundary;
use rmi_sph::Result;
use serde::{Deserialize, Serialize};

/// Squeeze axis (world x): the left pad's inward normal.
pub const SQUEEZE_AXIS: Vector3<f64> = Vector3::new(1.0, 0.0, 0.0);
/// Lift axis (world z, against gravity).
pub const LIFT_AXIS: Vector3<f64> = Vector3::new(0.0, 0.0, 1.0);

/// Hard force limit of the gripper (N): targets are clipped to it, loads above it open.
pub const FORCE_LIMIT: f64 = 400.0;

/// Pad geometry, in fractions of the sponge face and metres.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct GripperConfig {
    /// Pad width along y as a fraction of the sponge's y size; below 1 so that the contact
    /// area can grow as the sponge bulges.
    pub pad_width_fraction: f64,
    /// Pad height along z as a fraction of the sponge's height.
    pub pad_height_fraction: f64,
    /// Height of the pad centre as a fraction of the sponge's height.
    pub pad_center_fraction: f64,
    /// Pad thickness along x (m). The default 5 cm keeps the boundary layer of a pad's back
    /// face out of the kernel of water at its front face up to r = 1 cm (the layers are sunk
    /// `boundary::wall_depth` below each face); a pad thinner than `2 wall_depth + d` is
    /// sampled as one sheet through its middle.
    pub thickness: f64,
    /// Initial clearance between each pad face and the sponge face (m).
    pub gap: f64,
}

impl Default for GripperConfig {
    fn default() -> Self {
        GripperConfig {
            pad_width_fraction: 0.8,
            pad_height_fraction: 0.5,
            pad_center_fraction: 0.5,
            thickness: 0.05,
            gap: 0.005,
        }
    }
}

impl GripperConfig {
    /// Validates every field; `p` is the dotted path used in error messages.
    pub fn validate(&self, p: &str) -> Result<()> {
        check_range(&format!("{p}.pad_width_fraction"), self.pad_width_fraction, 0.05, 2.0, "(fraction)")?;
        check_range(&format!("{p}.pad_height_fraction"), self.pad_height_fraction, 0.05, 2.0, "(fraction)")?;
        check_range(&format!("{p}.pad_center_fraction"), self.pad_center_fraction, 0.0, 1.0, "(fraction)")?;
        check_range(&format!("{p}.thickness"), self.thickness, 1e-3, 0.2, "m")?;
        check_range(&format!("{p}.gap"), self.gap, 0.0, 0.1, "m")
    }
}

/// Body names of the pads in the scene.
pub const LEFT: &str = "pad_left";
/// Body names of the pads in the scene.
pub const RIGHT: &str = "pad_right";

/// Adds the two pads around a sponge spanning `min..max` (m) to `cfg`.
pub fn add_pads(cfg: &mut SimConfig, min: [f64; 3], max: [f64; 3], g: &GripperConfig) {
    let size = [max[0] - min[0], max[1] - min[1], max[2] - min[2]];
    let half = [g.thickness / 2.0, g.pad_width_fraction * size[1] / 2.0, g.pad_height_fraction * size[2] / 2.0];
    let y = 0.5 * (min[1] + max[1]);
    let z = min[2] + g.pad_center_fraction * size[2];
    for (name, x) in [(LEFT, min[0] - g.gap - half[0]), (RIGHT, max[0] + g.gap + half[0])] {
        cfg.scene.bodies.push(BodyConfig {
            name: name.into(),
            shape: Shape::Box { half_extents: half },
            position: [x, y, z],
            rotation: [0.0; 3],
            kinematic: true,
        });
    }
}

/// The pads of a built scene.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Gripper {
    /// Body index of the left pad.
    pub left: usize,
    /// Body index of the right pad.
    pub right: usize,
    /// Pad thickness (m).
    pub thickness: f64,
}

impl Gripper {
    /// Finds the pads added by [`add_pads`].
    pub fn find(b: &Boundary, thickness: f64) -> Option<Self> {
        Some(Gripper { left: b.find(LEFT)?, right: b.find(RIGHT)?, thickness })
    }

    /// Distance between the two pad faces along the squeeze axis (m).
    pub fn width(&self, b: &Boundary) -> f64 {
        let l = b.bodies[self.left].state.position.dot(&SQUEEZE_AXIS);
        let r = b.bodies[self.right].state.position.dot(&SQUEEZE_AXIS);
        r - l - self.thickness
    }

    /// Height of the pads' centre along the lift axis (m).
    pub fn height(&self, b: &Boundary) -> f64 {
        0.5 * (b.bodies[self.left].state.position + b.bodies[self.right].state.position).dot(&LIFT_AXIS)
    }

    /// Normal loads (N) on the left and right pads from their body forces: the push of the
    /// sponge and its water outward along the squeeze axis, zero when it pulls.
    pub fn loads(&self, b: &Boundary) -> (f64, f64) {
        let fl = -b.bodies[self.left].force.dot(&SQUEEZE_AXIS);
        let fr = b.bodies[self.right].force.dot(&SQUEEZE_AXIS);
        (fl.max(0.0), fr.max(0.0))
    }

    /// Total force on both pads (N): the wrist load a tared force/torque sensor reads.
    pub fn wrist_load(&self, b: &Boundary) -> Vector3<f64> {
        b.bodies[self.left].force + b.bodies[self.right].force
    }

    /// Body velocities for a closing speed per pad (m/s, positive closes) and a common lift
    /// speed (m/s).
    pub fn velocities(&self, closing: f64, lift: f64) -> [(usize, Vector3<f64>); 2] {
        let up = lift * LIFT_AXIS;
        [(self.left, up + closing * SQUEEZE_AXIS), (self.right, up - closing * SQUEEZE_AXIS)]
    }
}
