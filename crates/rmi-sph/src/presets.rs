//! Ready-made scenes: the SPlisHSPlasH dam break, the three sponges, validation setups.
//!
//! Free water starts with its outer particle centres 1.5 d from tank walls: one-layer Akinci
//! walls double-count the region behind both walls of a concave edge, so water placed closer
//! starts over-dense there and the first pressure solve launches a jet along the edge.

use crate::config::*;

/// SPlisHSPlasH's DamBreakModel set-up in z-up coordinates: a closed 4 x 1.5 x 3 m box
/// (x, y, height) with a cubic water column of 39 particles a side (about 1 m, 39^3 =
/// 59,319 particles at r = 12.5 mm) in a corner; explicit viscosity 0.01 m^2/s, dt = 1 ms,
/// 0.05 % pressure tolerance, at least 2 iterations.
pub fn dam_break(radius: f64) -> SimConfig {
    let d = 2.0 * radius;
    let n = ((1.0 / d).round() as usize).saturating_sub(1).max(1);
    let side = n as f64 * d;
    let mut cfg = SimConfig { particle_radius: radius, dt: 1e-3, ..Default::default() };
    cfg.fluid.viscosity = 0.01;
    cfg.fluid.viscosity_mode = ViscosityMode::Explicit;
    cfg.pressure.max_error = 5e-4;
    cfg.pressure.min_iterations = 2;
    cfg.max_velocity = 30.0;
    // Water only: the 3^3-cell scan is the faster one here (`SimConfig::neighbour_reach`).
    cfg.neighbour_reach = 1;
    cfg.scene.bodies.push(BodyConfig {
        name: "tank".into(),
        shape: Shape::Container { half_extents: [2.0, 0.75, 1.5] },
        position: [2.0, 0.75, 1.5],
        rotation: [0.0; 3],
        kinematic: false,
    });
    cfg.scene.fluid_blocks.push(FluidBlock { min: [d; 3], max: [d + side; 3], velocity: [0.0; 3] });
    cfg
}

/// The three sponge sizes of the paper (x = squeeze axis, y, z = height), in m.
pub const SPONGE_SIZES: [[f64; 3]; 3] = [[0.08, 0.08, 0.18], [0.10, 0.10, 0.20], [0.12, 0.12, 0.22]];

/// Time (s) a saturated sponge's pore water settles into the pinned skeleton before a run's
/// clock starts ([`SceneConfig::soak_time`]): the default of the robot task's trials, and of
/// the validation cases that compare with them.
pub const SOAK_TIME: f64 = 0.5;

/// A saturated sponge of `size` (m) standing on a floor, centred at x = y = 0. Each side is
/// the nearest whole number of particle spacings (`scene::snapped_box`; at r = 8 mm the
/// 12 x 12 x 22 cm sponge is 12.8 x 12.8 x 22.4 cm), so that the block in the config is the
/// one sampled and the floor meets its bottom face.
pub fn sponge(size: [f64; 3], porosity: f64, radius: f64) -> SimConfig {
    let d = 2.0 * radius;
    let size: [f64; 3] = std::array::from_fn(|k| (size[k] / d).round().max(1.0) * d);
    let mut cfg = SimConfig { particle_radius: radius, dt: 1e-3, ..Default::default() };
    let material = PorousMaterial { porosity, ..Default::default() };
    let h = [size[0] / 2.0, size[1] / 2.0];
    cfg.scene.porous_blocks.push(PorousBlock {
        min: [-h[0], -h[1], 0.0],
        max: [h[0], h[1], size[2]],
        material,
        saturated: true,
        fixed: false,
    });
    // The floor's top face is the block's bottom face: the lowest skeleton particles (centres
    // at d/2) start at their contact distance and the pore water below them at its rest
    // distance from the sunk wall layer. Four spacings thick, so that the layers of its top
    // and bottom faces lie out of each other's kernel.
    cfg.scene.bodies.push(BodyConfig {
        name: "floor".into(),
        shape: Shape::Box { half_extents: [0.3, 0.3, 2.0 * d] },
        position: [0.0, 0.0, -2.0 * d],
        rotation: [0.0; 3],
        kinematic: false,
    });
    cfg
}

/// A water column of `width` x `width` x `height` (m) in a closed tank twice as tall.
pub fn water_column(radius: f64, width: f64, height: f64) -> SimConfig {
    let d = 2.0 * radius;
    let mut cfg = SimConfig { particle_radius: radius, dt: 1e-3, ..Default::default() };
    cfg.fluid.viscosity = 0.01;
    cfg.scene.bodies.push(BodyConfig {
        name: "tank".into(),
        shape: Shape::Container { half_extents: [width / 2.0 + d, width / 2.0 + d, height] },
        position: [0.0, 0.0, height - d],
        rotation: [0.0; 3],
        kinematic: false,
    });
    cfg.scene.fluid_blocks.push(FluidBlock {
        min: [-width / 2.0, -width / 2.0, 0.0],
        max: [width / 2.0, width / 2.0, height],
        velocity: [0.0; 3],
    });
    cfg
}
