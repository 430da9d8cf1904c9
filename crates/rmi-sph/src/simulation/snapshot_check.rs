//! What a snapshot must satisfy before a simulation continues from it: its format version,
//! array lengths that agree, a valid config, and every value the step trusts in its range
//! (finite positions and velocities, masses a configured density gives, unique particle ids,
//! unit rotations). A checksum only proves that the bytes are the ones written, so a state
//! made or edited by hand and sealed again is refused here, not by the step.

use super::io::{Snapshot, VERSION};
use crate::config::DENSITY_RANGE;
use crate::error::{Result, RmiError};
use nalgebra::{UnitQuaternion, Vector3};

/// Largest accepted distance of a rotation's quaternion norm from 1. The solver's rotations
/// are products of unit quaternions, whose norm drifts only by rounding.
pub const UNIT_TOLERANCE: f64 = 1e-6;

/// The refusal of `value` of `field` at `at` ("particle 3", "body 0"; empty for the whole
/// snapshot), one line naming what was expected.
fn refused(at: &str, field: &str, value: impl std::fmt::Display, expected: impl std::fmt::Display) -> RmiError {
    let at = if at.is_empty() { String::new() } else { format!(" {at}") };
    RmiError::State(format!("snapshot{at}: `{field}` = {value} is not accepted; expected {expected}"))
}

/// A vector on one line.
fn show(v: &Vector3<f64>) -> String {
    format!("[{}, {}, {}]", v.x, v.y, v.z)
}

/// Refuses the first entry of `values` with a non-finite component (entry `i` is at `at(i)`).
fn finite_vectors(values: &[Vector3<f64>], field: &str, unit: &str, at: impl Fn(usize) -> String) -> Result<()> {
    match values.iter().position(|v| !v.iter().all(|c| c.is_finite())) {
        Some(i) => Err(refused(&at(i), field, show(&values[i]), format!("finite components ({unit})"))),
        None => Ok(()),
    }
}

/// Refuses `q` unless its norm is 1 within [`UNIT_TOLERANCE`] (a non-finite one never is).
fn unit_rotation(q: &UnitQuaternion<f64>, at: &str) -> Result<()> {
    let c = q.quaternion().coords;
    if (c.norm() - 1.0).abs() <= UNIT_TOLERANCE {
        return Ok(());
    }
    let value = format!("[{}, {}, {}, {}] (i, j, k, w; norm {})", c[0], c[1], c[2], c[3], c.norm());
    Err(refused(at, "rotation", value, format!("a unit quaternion (norm within {UNIT_TOLERANCE} of 1)")))
}

impl Snapshot {
    /// Consistency checks: the version, lengths that agree, a valid config, then every value
    /// the step trusts in its range; a refusal names the field, the particle and the range.
    pub fn check(&self) -> Result<()> {
        if self.version != VERSION {
            return Err(RmiError::State(format!("snapshot version {} (this build reads {VERSION})", self.version)));
        }
        self.check_lengths()?;
        if let Some(m) = &self.coarse {
            m.check(self.particles.len())
                .map_err(|e| RmiError::State(format!("the snapshot's coarse matrix is not valid: {e}")))?;
        }
        self.config.validate().map_err(|e| RmiError::State(format!("the snapshot's config is not valid: {e}")))?;
        self.check_values()
    }

    /// Per-particle arrays of the particle count, per-skeleton ones of the skeleton's.
    fn check_lengths(&self) -> Result<()> {
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
            ("vstar_prev", self.vstar_prev.len()),
        ] {
            if len != n {
                return Err(RmiError::State(format!("array `{name}` has {len} entries, expected {n}")));
            }
        }
        for (name, len) in [
            ("rest_positions", self.rest_positions.len()),
            ("fixed", self.fixed.len()),
            ("contact_load", self.contact_load.len()),
            ("rotation", self.solid.rotation.len()),
        ] {
            if len != ns {
                return Err(RmiError::State(format!(
                    "array `{name}` has {len} entries, expected {ns} (solid particles)"
                )));
            }
        }
        Ok(())
    }

    /// Every value the step trusts in its range, the first one outside named with its
    /// particle (or boundary particle, or body) and the accepted range. Needs the lengths
    /// checked and a valid config.
    fn check_values(&self) -> Result<()> {
        if !self.time.is_finite() {
            return Err(refused("", "time", self.time, "a finite value (s)"));
        }
        self.check_motion()?;
        self.check_masses()?;
        self.check_ids()?;
        self.check_skeleton()?;
        self.check_bodies()
    }

    /// Positions, velocities and the solver's memory of them finite.
    fn check_motion(&self) -> Result<()> {
        let p = &self.particles;
        let particle = |i: usize| format!("particle {i}");
        for (field, values, unit) in [
            ("x", &p.x, "m"),
            ("v", &p.v, "m/s"),
            ("dv_prev", &self.dv_prev, "m/s"),
            ("response_prev", &self.response_prev, "m/s"),
            ("vstar_prev", &self.vstar_prev, "m/s"),
        ] {
            finite_vectors(values, field, unit, particle)?;
        }
        finite_vectors(&self.rest_positions, "rest_positions", "m", |s| particle(p.n_fluid + s))?;
        finite_vectors(&self.boundary_velocities, "boundary_velocities", "m/s", |i| format!("boundary particle {i}"))?;
        match self.kappa_dt2.iter().position(|k| !k.is_finite()) {
            Some(i) => Err(refused(&particle(i), "kappa_dt2", self.kappa_dt2[i], "a finite value (m^2)")),
            None => Ok(()),
        }
    }

    /// Every mass within what the accepted densities give at the config's spacing (the
    /// scene's particles weigh their density times the spacing cubed).
    fn check_masses(&self) -> Result<()> {
        let d = self.config.spacing();
        let vol = d * d * d;
        let (lo, hi) = (DENSITY_RANGE[0] * vol, DENSITY_RANGE[1] * vol);
        match self.particles.mass.iter().position(|m| !(m.is_finite() && *m >= lo && *m <= hi)) {
            Some(a) => Err(refused(
                &format!("particle {a}"),
                "mass",
                format!("{} kg", self.particles.mass[a]),
                format!(
                    "a finite value in [{lo}, {hi}] kg (a density in [{}, {}] kg/m^3 times the spacing {d} m cubed)",
                    DENSITY_RANGE[0], DENSITY_RANGE[1]
                ),
            )),
            None => Ok(()),
        }
    }

    /// Ids unique and below the particle count (the scene numbers its particles `0..n`; a
    /// step only reorders them).
    fn check_ids(&self) -> Result<()> {
        let ids = &self.particles.id;
        let n = ids.len();
        let mut seen = vec![false; n];
        for (a, &id) in ids.iter().enumerate() {
            let slot = seen.get_mut(id as usize);
            match slot {
                Some(s) if !*s => *s = true,
                Some(_) => {
                    let holder = ids.iter().position(|&j| j == id).expect("an id seen before has a holder");
                    let expected =
                        format!("an id in [0, {n}) that no other particle holds (particle {holder} holds it)");
                    return Err(refused(&format!("particle {a}"), "id", id, expected));
                }
                None => return Err(refused(&format!("particle {a}"), "id", id, format!("an id in [0, {n})"))),
            }
        }
        Ok(())
    }

    /// The skeleton's rotations unit quaternions, its contact loads finite and not negative
    /// (a contact that did not push adds none).
    fn check_skeleton(&self) -> Result<()> {
        let nf = self.particles.n_fluid;
        for (s, q) in self.solid.rotation.iter().enumerate() {
            unit_rotation(q, &format!("particle {}", nf + s))?;
        }
        match self.contact_load.iter().position(|f| !(f.is_finite() && *f >= 0.0)) {
            Some(s) => Err(refused(
                &format!("particle {}", nf + s),
                "contact_load",
                format!("{} N", self.contact_load[s]),
                "a finite value of at least 0 N",
            )),
            None => Ok(()),
        }
    }

    /// Body poses and velocities finite, orientations unit quaternions.
    fn check_bodies(&self) -> Result<()> {
        for (k, b) in self.bodies.iter().enumerate() {
            let at = format!("body {k}");
            for (field, v, unit) in [
                ("position", &b.position, "m"),
                ("velocity", &b.velocity, "m/s"),
                ("angular_velocity", &b.angular_velocity, "rad/s"),
            ] {
                finite_vectors(std::slice::from_ref(v), field, unit, |_| at.clone())?;
            }
            unit_rotation(&b.rotation, &at)?;
        }
        Ok(())
    }
}
