//! Ready-made scenes: the SPlisHSPlasH dam break, the three sponges, validation setups.

use crate::config::*;

/// SPlisHSPlasH's DamBreakModel set-up in z-up coordinates: a closed 4 x 1.5 x 3 m box
/// (x, y, height) with a water column of side 39 d (about 1 m, 39^3 = 59,319 particles at
/// r = 12.5 mm) in a corner; explicit viscosity 0.01 m^2/s, dt = 1 ms, 0.05 % tolerance.
pub fn dam_break(radius: f64) -> SimConfig {
    let d = 2.0 * radius;
    let side = (1.0 / d).floor().max(1.0) * d - if (1.0 / d).fract() < 1e-9 { d } else { 0.0 };
    let mut cfg = SimConfig {
        particle_radius: radius,
        dt: 1e-3,
        ..Default::default()
    };
    cfg.fluid.viscosity = 0.01;
    cfg.fluid.viscosity_mode = ViscosityMode::Explicit;
    cfg.pressure.max_error = 5e-4;
    cfg.pressure.min_iterations = 2;
    cfg.max_velocity = 30.0;
    cfg.scene.bodies.push(BodyConfig {
        name: "tank".into(),
        shape: Shape::Container {
            half_extents: [2.0, 0.75, 1.5],
        },
        position: [2.0, 0.75, 1.5],
        rotation: [0.0; 3],
        kinematic: false,
    });
    // Leave half a spacing to the walls, as a particle sits d/2 inside its sampling cell.
    cfg.scene.fluid_blocks.push(FluidBlock {
        min: [d / 2.0; 3],
        max: [d / 2.0 + side; 3],
        velocity: [0.0; 3],
    });
    cfg
}

/// The three sponge sizes of the paper (x = squeeze axis, y, z = height), in m.
pub const SPONGE_SIZES: [[f64; 3]; 3] =
    [[0.08, 0.08, 0.18], [0.10, 0.10, 0.20], [0.12, 0.12, 0.22]];

/// A saturated sponge of `size` (m) standing on a floor, centred at x = y = 0.
pub fn sponge(size: [f64; 3], porosity: f64, radius: f64) -> SimConfig {
    let mut cfg = SimConfig {
        particle_radius: radius,
        dt: 1e-3,
        ..Default::default()
    };
    let material = PorousMaterial {
        porosity,
        ..Default::default()
    };
    let h = [size[0] / 2.0, size[1] / 2.0];
    cfg.scene.porous_blocks.push(PorousBlock {
        min: [-h[0], -h[1], 0.0],
        max: [h[0], h[1], size[2]],
        material,
        saturated: true,
        fixed: false,
    });
    let d = 2.0 * radius;
    cfg.scene.bodies.push(BodyConfig {
        name: "floor".into(),
        shape: Shape::Box {
            half_extents: [0.3, 0.3, d],
        },
        position: [0.0, 0.0, -d - 0.5 * d],
        rotation: [0.0; 3],
        kinematic: false,
    });
    cfg
}

/// A water column of height `height` (m) in a closed square tank of side `width` (m).
pub fn water_column(radius: f64, width: f64, height: f64) -> SimConfig {
    let d = 2.0 * radius;
    let mut cfg = SimConfig {
        particle_radius: radius,
        dt: 1e-3,
        ..Default::default()
    };
    cfg.fluid.viscosity = 0.01;
    cfg.scene.bodies.push(BodyConfig {
        name: "tank".into(),
        shape: Shape::Container {
            half_extents: [width / 2.0 + d / 2.0, width / 2.0 + d / 2.0, height],
        },
        position: [0.0, 0.0, height - d / 2.0],
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
