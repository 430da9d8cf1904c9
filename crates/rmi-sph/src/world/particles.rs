//! Particle storage: dynamic particles (fluid first, then porous solid) as structure of arrays.
//!
//! Fluid particles occupy indices `0..n_fluid`, solid particles `n_fluid..n`. Keeping the two
//! phases in contiguous ranges lets every neighbour list split into a fluid and a solid part
//! and lets per-solid data be indexed by `a - n_fluid`.

use nalgebra::{Matrix3, UnitQuaternion, Vector3};
use serde::{Deserialize, Serialize};

/// Material id of water.
pub const FLUID: u16 = 0;

/// Dynamic particles (fluid and porous solid). Positions in m, velocities in m/s, masses in kg.
#[derive(Clone, Debug, Default, Serialize, Deserialize)]
pub struct Particles {
    /// Number of fluid particles (they come first).
    pub n_fluid: usize,
    /// Positions.
    pub x: Vec<Vector3<f64>>,
    /// Velocities.
    pub v: Vec<Vector3<f64>>,
    /// Masses.
    pub mass: Vec<f64>,
    /// Material: [`FLUID`] or `1 + k` for porous object `k`.
    pub material: Vec<u16>,
    /// Stable identity, unchanged by re-sorting.
    pub id: Vec<u32>,
}

impl Particles {
    /// Total number of dynamic particles.
    pub fn len(&self) -> usize {
        self.x.len()
    }

    /// True when there are no dynamic particles.
    pub fn is_empty(&self) -> bool {
        self.x.is_empty()
    }

    /// Number of solid particles.
    pub fn n_solid(&self) -> usize {
        self.x.len() - self.n_fluid
    }

    /// True for a fluid index.
    #[inline]
    pub fn is_fluid(&self, a: usize) -> bool {
        a < self.n_fluid
    }
}

/// Per-solid-particle data (indexed by `s = a - n_fluid`), constant or slowly varying.
#[derive(Clone, Debug, Default)]
pub struct SolidRest {
    /// Rest positions in m.
    pub x0: Vec<Vector3<f64>>,
    /// Rest volumes V0 in m^3 (the sampling volume d^3).
    pub v0: Vec<f64>,
    /// Rest Shepard sum `sum_r V W(x_s0 - x_r0)` including self (kernel coverage at rest).
    pub shepard0: Vec<f64>,
    /// Kernel-gradient correction matrices L.
    pub l: Vec<Matrix3<f64>>,
    /// CSR offsets into the rest-neighbour arrays (length n_solid + 1).
    pub start: Vec<u32>,
    /// Rest neighbour (global dynamic index).
    pub nbr: Vec<u32>,
    /// `grad W(x_s0 - x_r0)` per rest pair.
    pub grad0: Vec<Vector3<f64>>,
    /// Per solid `sum_r V_r0 grad W(x_s0 - x_r0)` (1/m): the elastic force sum factors through it.
    pub grad0_sum: Vec<Vector3<f64>>,
    /// Pinned particles (never integrated).
    pub fixed: Vec<bool>,
    /// Hourglass spring constant (N/m) per rest pair, constant over a run.
    pub hg_k: Vec<f64>,
}

/// Per-solid state that evolves and must be saved for bit-identical continuation.
#[derive(Clone, Debug, Default, Serialize, Deserialize)]
pub struct SolidState {
    /// Rotation extracted from the deformation (warm start of the next extraction).
    pub rotation: Vec<UnitQuaternion<f64>>,
}

/// A porous object with its material and derived SPH coefficients.
#[derive(Clone, Debug)]
pub struct PorousObject {
    /// Dynamic index range of its particles.
    pub range: std::ops::Range<usize>,
    /// Material parameters.
    pub material: crate::config::PorousMaterial,
    /// SPH drag coefficient beta (Pa s), from the permeability and resolution.
    pub drag_beta: f64,
    /// Adhesion alpha (N/m) at the simulation's spacing.
    pub adhesion: f64,
    /// Shear modulus mu (Pa).
    pub mu: f64,
    /// Coefficient of the trace term (lambda in Pa, or 1 with the reference-code flag).
    pub lambda_trace: f64,
    /// Lambda (Pa) used by the bloating term.
    pub lambda: f64,
    /// Lower corner of the object's rest volume (its block) in m.
    pub rest_min: nalgebra::Vector3<f64>,
    /// Upper corner of the object's rest volume in m.
    pub rest_max: nalgebra::Vector3<f64>,
}

/// Drag lattice constant c of docs/physics.md §3.1: `sum_s V (u.x)/(|x|^2+eps) grad W ~ -c u/H^2`.
pub const DRAG_LATTICE_C: f64 = 3.70;
/// Dimension factor D = 2 (dim + 2) of the Laplacian viscosity/drag forms in 3D.
pub const LAPLACE_D: f64 = 10.0;

/// Converts an intrinsic permeability (m^2) to the SPH drag coefficient beta (Pa s):
/// `beta = mu_f phi^2 H^2 / (D c kappa)`.
pub fn drag_beta(permeability: f64, porosity: f64, darcy_viscosity: f64, h: f64) -> f64 {
    if permeability <= 0.0 {
        0.0
    } else {
        darcy_viscosity * porosity * porosity * h * h / (LAPLACE_D * DRAG_LATTICE_C * permeability)
    }
}
