//! Persistence: full-state snapshots, everything needed to continue bit-identically, and
//! the simulation's snapshot, restore, save and load.

use super::Simulation;
use crate::config::SimConfig;
use crate::error::{Result, RmiError};
use crate::solver::implicit;
use crate::world::boundary::BodyState;
use crate::world::particles::{Particles, SolidState};
use crate::world::scene;
use nalgebra::Vector3;
use serde::{Deserialize, Serialize};
use std::io::Write;

/// Format version written into every snapshot.
pub const VERSION: u32 = 2;
const MAGIC: &[u8; 8] = b"RMISNAP\0";

/// Serializable simulation state. Derived data (neighbours, rest matrices) is recomputed.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct Snapshot {
    /// Format version.
    pub version: u32,
    /// Configuration that built the scene.
    pub config: SimConfig,
    /// Simulated time (s).
    pub time: f64,
    /// Completed steps.
    pub step: u64,
    /// Dynamic particles.
    pub particles: Particles,
    /// Skeleton rest positions (m).
    pub rest_positions: Vec<Vector3<f64>>,
    /// Pinned skeleton particles.
    pub fixed: Vec<bool>,
    /// Skeleton rotations.
    pub solid: SolidState,
    /// Pressure of the last step times dt^2 (warm start and buoyancy).
    pub kappa_dt2: Vec<f64>,
    /// Velocity change of the last implicit solve (warm start).
    pub dv_prev: Vec<Vector3<f64>>,
    /// Drag correction of the last pressure response (warm start).
    pub response_prev: Vec<Vector3<f64>>,
    /// Skeleton contacts that pushed in the last step.
    pub contact_active: Vec<bool>,
    /// Body poses and velocities.
    pub bodies: Vec<BodyState>,
}

impl Snapshot {
    /// Consistency checks: lengths agree and every value is finite.
    pub fn check(&self) -> Result<()> {
        if self.version != VERSION {
            return Err(RmiError::State(format!("snapshot version {} (this build reads {VERSION})", self.version)));
        }
        let p = &self.particles;
        let n = p.x.len();
        let ns =
            n.checked_sub(p.n_fluid).ok_or_else(|| RmiError::State("n_fluid exceeds the particle count".into()))?;
        for (name, len) in [
            ("v", p.v.len()),
            ("mass", p.mass.len()),
            ("material", p.material.len()),
            ("id", p.id.len()),
            ("kappa_dt2", self.kappa_dt2.len()),
            ("dv_prev", self.dv_prev.len()),
            ("response_prev", self.response_prev.len()),
        ] {
            if len != n {
                return Err(RmiError::State(format!("array `{name}` has {len} entries, expected {n}")));
            }
        }
        for (name, len) in [
            ("rest_positions", self.rest_positions.len()),
            ("fixed", self.fixed.len()),
            ("contact_active", self.contact_active.len()),
            ("rotation", self.solid.rotation.len()),
        ] {
            if len != ns {
                return Err(RmiError::State(format!(
                    "array `{name}` has {len} entries, expected {ns} (solid particles)"
                )));
            }
        }
        let finite = |v: &Vector3<f64>| v.iter().all(|c| c.is_finite());
        if !p
            .x
            .iter()
            .chain(&p.v)
            .chain(&self.dv_prev)
            .chain(&self.response_prev)
            .chain(&self.rest_positions)
            .all(finite)
            || !self.kappa_dt2.iter().all(|k| k.is_finite())
            || !self.time.is_finite()
        {
            return Err(RmiError::State("snapshot contains non-finite values".into()));
        }
        self.config.validate()
    }

    /// Serialises to bytes (magic header + bincode).
    pub fn to_bytes(&self) -> Vec<u8> {
        let mut out = MAGIC.to_vec();
        out.extend(bincode::serialize(self).expect("snapshot serialises"));
        out
    }

    /// Parses bytes written by [`Snapshot::to_bytes`] and checks them.
    pub fn from_bytes(b: &[u8]) -> Result<Self> {
        if b.len() < MAGIC.len() || &b[..MAGIC.len()] != MAGIC {
            return Err(RmiError::State("not an rmi snapshot (bad header)".into()));
        }
        let s: Snapshot =
            bincode::deserialize(&b[MAGIC.len()..]).map_err(|e| RmiError::State(format!("corrupt snapshot: {e}")))?;
        s.check()?;
        Ok(s)
    }

    /// Writes to `path` atomically (temporary file in the same folder, then rename).
    pub fn save(&self, path: &std::path::Path) -> Result<()> {
        write_atomic(path, &self.to_bytes())
    }

    /// Reads and checks a snapshot file.
    pub fn load(path: &std::path::Path) -> Result<Self> {
        Self::from_bytes(&std::fs::read(path)?)
    }
}

/// Writes `bytes` to `path` through a temporary file in the same folder, synced and then
/// renamed, so that a crash leaves either the old file or the new one, never half of one.
pub fn write_atomic(path: &std::path::Path, bytes: &[u8]) -> Result<()> {
    let tmp = path.with_extension(format!("tmp{}", std::process::id()));
    let res = (|| {
        let mut f = std::fs::File::create(&tmp)?;
        f.write_all(bytes)?;
        f.sync_all()?;
        std::fs::rename(&tmp, path)
    })();
    if res.is_err() {
        let _ = std::fs::remove_file(&tmp);
    }
    res.map_err(RmiError::from)
}

/// Persistence.
impl Simulation {
    /// Captures the full state needed for a bit-identical continuation.
    pub fn snapshot(&self) -> Snapshot {
        Snapshot {
            version: VERSION,
            config: self.cfg.clone(),
            time: self.time,
            step: self.step,
            particles: self.p.clone(),
            rest_positions: self.rest.x0.clone(),
            fixed: self.rest.fixed.clone(),
            solid: self.solid.clone(),
            kappa_dt2: self.kappa_dt2.clone(),
            dv_prev: self.dv_prev.clone(),
            response_prev: self.response_prev.clone(),
            contact_active: self.contact_active.clone(),
            bodies: self.bnd.bodies.iter().map(|b| b.state.clone()).collect(),
        }
    }

    /// Restores a snapshot taken from a simulation of the same configuration.
    pub fn restore(&mut self, s: Snapshot) -> Result<()> {
        s.check()?;
        let threads = self.threads;
        let mut fresh = Simulation::build(s.config.clone(), Some(threads))?;
        if fresh.bnd.bodies.len() != s.bodies.len() {
            return Err(RmiError::State(format!(
                "snapshot has {} bodies, its config {}",
                s.bodies.len(),
                fresh.bnd.bodies.len()
            )));
        }
        let n = s.particles.len();
        let mut rest_p = s.particles.clone();
        rest_p.x[s.particles.n_fluid..].copy_from_slice(&s.rest_positions);
        let pool = fresh.pool.clone();
        pool.install(|| {
            fresh.rest = scene::rest_data(&rest_p, &s.fixed, &fresh.kernel);
            fresh.rest.hg_k = implicit::hourglass_constants(&fresh.rest, &rest_p, &fresh.objects, &fresh.kernel);
        });
        fresh.p = s.particles;
        fresh.solid = s.solid;
        fresh.kappa_dt2 = s.kappa_dt2;
        fresh.dv_prev = s.dv_prev;
        fresh.response_prev = s.response_prev;
        fresh.contact_active = s.contact_active;
        fresh.kappa = vec![0.0; n];
        fresh.acc = vec![Vector3::zeros(); n];
        for (b, st) in fresh.bnd.bodies.iter_mut().zip(s.bodies) {
            b.state = st;
        }
        fresh.bnd.invalidate();
        fresh.time = s.time;
        fresh.step = s.step;
        fresh.refresh_rho0();
        *self = fresh;
        Ok(())
    }

    /// Writes a snapshot file (atomically: temporary name, then rename).
    pub fn save(&self, path: &std::path::Path) -> Result<()> {
        self.snapshot().save(path)
    }

    /// Loads a snapshot file into a new simulation with `threads` workers.
    pub fn load(path: &std::path::Path, threads: Option<usize>) -> Result<Self> {
        Self::from_snapshot(Snapshot::load(path)?, threads)
    }

    /// A new simulation with `threads` workers continuing from `snapshot` (its own config).
    pub fn from_snapshot(snapshot: Snapshot, threads: Option<usize>) -> Result<Self> {
        let mut sim = Simulation::build(snapshot.config.clone(), threads)?;
        sim.restore(snapshot)?;
        Ok(sim)
    }
}
