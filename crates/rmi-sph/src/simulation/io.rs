//! Persistence: full-state snapshots, everything needed to continue bit-identically, and
//! the simulation's snapshot, restore, save and load.

use super::Simulation;
use crate::config::SimConfig;
use crate::error::{Result, RmiError};
use crate::solver::implicit;
pub use crate::solver::linalg::coarse::CoarseMatrix;
use crate::solver::linalg::coarse::TwoLevel;
use crate::world::boundary::BodyState;
use crate::world::particles::{Particles, SolidState};
use crate::world::scene;
use nalgebra::Vector3;
use serde::{Deserialize, Serialize};
use std::io::Write;

/// Format version written into every snapshot (3: a checksum follows the payload; 4: per-particle
/// contact loads; 5: the config's `pressure.single_solve`; 6: `response_prev` holds the last
/// pressure response itself, no longer its drag correction; 7: `vstar_prev`, the last v*; 8:
/// the two-level preconditioner's coarse matrix, which serves several steps, and the config's
/// `cg.coarse_steps`).
pub const VERSION: u32 = 8;
const MAGIC: &[u8; 8] = b"RMISNAP\0";
/// Bytes of the checksum after the payload.
const SUM_LEN: usize = 8;

/// 64-bit FNV-1a hash of `bytes`: the checksum of saved states (detects corruption, not
/// tampering).
pub fn fnv1a64(bytes: &[u8]) -> u64 {
    bytes.iter().fold(0xcbf2_9ce4_8422_2325, |h, &b| (h ^ u64::from(b)).wrapping_mul(0x0100_0000_01b3))
}

/// `bytes` with their [`fnv1a64`] checksum appended (little-endian).
pub fn seal(mut bytes: Vec<u8>) -> Vec<u8> {
    let sum = fnv1a64(&bytes);
    bytes.extend_from_slice(&sum.to_le_bytes());
    bytes
}

/// The bytes [`seal`] sealed, without their checksum, or a [`RmiError::State`] if the
/// checksum does not match (`what` names the content: "snapshot", "trial state").
pub fn unseal<'a>(bytes: &'a [u8], what: &str) -> Result<&'a [u8]> {
    let corrupt = || RmiError::State(format!("corrupt {what}: checksum mismatch"));
    let split = bytes.len().checked_sub(SUM_LEN).ok_or_else(corrupt)?;
    let (body, sum) = bytes.split_at(split);
    let sum = u64::from_le_bytes(sum.try_into().map_err(|_| corrupt())?);
    if fnv1a64(body) != sum {
        return Err(corrupt());
    }
    Ok(body)
}

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
    /// The last pressure response (m/s; the next one's initial guess).
    pub response_prev: Vec<Vector3<f64>>,
    /// The last implicit solve's v* (m/s; with `dv_prev`, the next one's guess).
    pub vstar_prev: Vec<Vector3<f64>>,
    /// Per skeleton particle, the normal force (N) of its body contact in the last step;
    /// zero where it had none or the contact did not push.
    pub contact_load: Vec<f64>,
    /// Body poses and velocities.
    pub bodies: Vec<BodyState>,
    /// Velocities of the boundary particles (m/s). They follow a body's velocity when the
    /// body moves (at the end of a step), not when it is set: a step uses the velocities of
    /// the previous update, which a velocity changed from or to zero leaves behind that of
    /// the body, so they are state of their own.
    pub boundary_velocities: Vec<Vector3<f64>>,
    /// The two-level preconditioner's coarse matrix in use, if any (it serves
    /// `cg.coarse_steps` steps).
    pub coarse: Option<CoarseMatrix>,
}

impl Snapshot {
    /// Serialises to bytes: magic header, bincode payload, checksum of both.
    pub fn to_bytes(&self) -> Vec<u8> {
        let mut out = MAGIC.to_vec();
        out.extend(bincode::serialize(self).expect("snapshot serialises"));
        seal(out)
    }

    /// Parses bytes written by [`Snapshot::to_bytes`] and checks them: header, version,
    /// checksum, then the content ([`Snapshot::check`]).
    pub fn from_bytes(b: &[u8]) -> Result<Self> {
        if b.len() < MAGIC.len() || &b[..MAGIC.len()] != MAGIC {
            return Err(RmiError::State("not an rmi snapshot (bad header)".into()));
        }
        // The version leads the payload (bincode: little-endian u32), so that a snapshot of
        // another format says so instead of failing its checksum.
        let version = b.get(MAGIC.len()..MAGIC.len() + 4).map(|v| u32::from_le_bytes(v.try_into().expect("4 bytes")));
        if let Some(v) = version.filter(|v| *v != VERSION && *v < 16) {
            return Err(RmiError::State(format!("snapshot version {v} (this build reads {VERSION})")));
        }
        let body = unseal(b, "snapshot")?;
        let s: Snapshot = bincode::deserialize(&body[MAGIC.len()..])
            .map_err(|e| RmiError::State(format!("corrupt snapshot: {e}")))?;
        s.check()?;
        Ok(s)
    }

    /// Writes to `path` atomically (temporary file in the same folder, then rename).
    pub fn save(&self, path: &std::path::Path) -> Result<()> {
        write_atomic(path, &self.to_bytes())
    }

    /// Reads and checks a snapshot file (a regular file of at most the memory a simulation
    /// may use, [`crate::config::memory_limit`]).
    pub fn load(path: &std::path::Path) -> Result<Self> {
        Self::from_bytes(&read_state(path)?)
    }
}

/// Writes `bytes` to `path` through a temporary file in the same folder, synced and then
/// renamed, so that a crash leaves either the old file or the new one, never half of one.
///
/// The temporary file's name is unique (the target's name, the process id, a process-wide
/// counter and the clock) and created exclusively, so that concurrent saves, to the same path
/// or to different ones, never share one. Only a regular file at `path` is replaced: a
/// symlink (it is not followed), a directory, a FIFO or a device there is an error naming the
/// path.
pub fn write_atomic(path: &std::path::Path, bytes: &[u8]) -> Result<()> {
    use std::sync::atomic::{AtomicU64, Ordering};
    static COUNTER: AtomicU64 = AtomicU64::new(0);
    refuse_special(path)?;
    let name = path.file_name().ok_or_else(|| invalid_path(path, "has no file name"))?;
    let folder = path.parent().filter(|p| !p.as_os_str().is_empty()).unwrap_or(std::path::Path::new("."));
    let mut attempt = 0;
    let (tmp, mut file) = loop {
        let nanos = std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).map_or(0, |d| d.as_nanos());
        let mut tmp_name = std::ffi::OsString::from(".");
        tmp_name.push(name);
        tmp_name.push(format!(".{}.{}.{nanos:x}.tmp", std::process::id(), COUNTER.fetch_add(1, Ordering::Relaxed)));
        let tmp = folder.join(tmp_name);
        match std::fs::OpenOptions::new().write(true).create_new(true).open(&tmp) {
            Ok(f) => break (tmp, f),
            Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists && attempt < 16 => attempt += 1,
            Err(e) => return Err(e.into()),
        }
    };
    let res = (|| {
        file.write_all(bytes)?;
        file.sync_all()?;
        drop(file);
        // Checked again just before the rename: something may have appeared meanwhile.
        refuse_special(path)?;
        std::fs::rename(&tmp, path)?;
        Ok(())
    })();
    if res.is_err() {
        let _ = std::fs::remove_file(&tmp);
    }
    res
}

/// Reads a state file: a regular file no longer than the memory a simulation may use.
pub fn read_state(path: &std::path::Path) -> Result<Vec<u8>> {
    read_limited(path, crate::config::memory_limit() as u64, "state file")
}

/// An I/O error of kind `InvalidInput` whose text names `path`.
fn invalid_path(path: &std::path::Path, what: &str) -> RmiError {
    RmiError::Io(std::io::Error::new(std::io::ErrorKind::InvalidInput, format!("{}: {what}", path.display())))
}

/// Refuses to replace anything but a regular file (or nothing) at `path`.
fn refuse_special(path: &std::path::Path) -> Result<()> {
    match std::fs::symlink_metadata(path) {
        Ok(m) if m.file_type().is_symlink() => {
            Err(invalid_path(path, "is a symbolic link; states are written only to regular files"))
        }
        // A directory keeps the system's error (EISDIR), as writing to it would give.
        #[cfg(unix)]
        Ok(m) if m.is_dir() => Err(std::io::Error::from_raw_os_error(21).into()),
        Ok(m) if !m.is_file() => Err(invalid_path(path, "exists and is not a regular file")),
        Ok(_) => Ok(()),
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => Ok(()),
        Err(e) => Err(e.into()),
    }
}

/// Reads the regular file `path` (symlinks to one are followed), refusing anything else (a
/// FIFO, a device such as `/dev/zero`, a directory) and files longer than `limit` bytes;
/// `what` names the content in the error ("config file", "state file").
pub fn read_limited(path: &std::path::Path, limit: u64, what: &str) -> Result<Vec<u8>> {
    use std::io::Read;
    // Checked before opening: opening a FIFO would block.
    let meta = std::fs::metadata(path)?;
    if !meta.is_file() {
        return Err(invalid_path(path, &format!("is not a regular file; a {what} must be one")));
    }
    let too_long = |len: u64| {
        RmiError::Io(std::io::Error::new(
            std::io::ErrorKind::InvalidData,
            format!("{}: {len} bytes or more exceed the limit of {limit} bytes for a {what}", path.display()),
        ))
    };
    if meta.len() > limit {
        return Err(too_long(meta.len()));
    }
    let mut out = Vec::new();
    std::fs::File::open(path)?.take(limit + 1).read_to_end(&mut out)?;
    if out.len() as u64 > limit {
        return Err(too_long(out.len() as u64));
    }
    Ok(out)
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
            vstar_prev: self.vstar_prev.clone(),
            contact_load: self.contact_load.clone(),
            bodies: self.bnd.bodies.iter().map(|b| b.state.clone()).collect(),
            boundary_velocities: self.bnd.v.clone(),
            coarse: self.op_buffers.coarse.as_ref().map(|tl| tl.matrix()),
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
        let (built, p) = (&fresh.p, &s.particles);
        if built.len() != p.len() || built.n_fluid != p.n_fluid || built.material != p.material {
            return Err(RmiError::State(format!(
                "snapshot has {} fluid and {} porous particles, its config's scene {} and {} (or other materials)",
                p.n_fluid,
                p.n_solid(),
                built.n_fluid,
                built.n_solid()
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
        fresh.vstar_prev = s.vstar_prev;
        fresh.contact_load = s.contact_load;
        fresh.op_buffers.coarse = s.coarse.map(|m| std::sync::Arc::new(pool.install(|| TwoLevel::from_matrix(m))));
        fresh.kappa = vec![0.0; n];
        fresh.acc = vec![Vector3::zeros(); n];
        for (b, st) in fresh.bnd.bodies.iter_mut().zip(s.bodies) {
            b.state = st;
        }
        fresh.bnd.invalidate();
        if s.boundary_velocities.len() != fresh.bnd.v.len() {
            return Err(RmiError::State(format!(
                "snapshot has {} boundary particles, its config {}",
                s.boundary_velocities.len(),
                fresh.bnd.v.len()
            )));
        }
        fresh.bnd.v = s.boundary_velocities;
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
