//! The one error type of the engine. The Python binding maps each variant to an exception.

use thiserror::Error;

/// Every failure the engine reports. No engine call panics on bad input; it returns one of these.
#[derive(Debug, Error)]
pub enum RmiError {
    /// A configuration value is outside its accepted range (or malformed).
    #[error("invalid config: `{field}` = {value} is not accepted; expected {expected}")]
    InvalidConfig {
        /// Dotted path of the field, e.g. `scene.porous_blocks[0].material.porosity`.
        field: String,
        /// The offending value, as text.
        value: String,
        /// The accepted range or form, with units.
        expected: String,
    },
    /// The simulation diverged; the state is left at the last good step.
    #[error("simulation unstable at step {step} (t = {time:.6} s): {reason}")]
    Unstable {
        /// Index of the step that failed (0-based count of completed steps).
        step: u64,
        /// Simulated time at the start of the failed step, in s.
        time: f64,
        /// Largest particle speed seen, in m/s (may be NaN or inf).
        max_velocity: f64,
        /// What tripped the check.
        reason: String,
    },
    /// A snapshot or state dictionary does not fit this simulation.
    #[error("invalid state: {0}")]
    State(String),
    /// Reading or writing a file failed.
    #[error("io error: {0}")]
    Io(#[from] std::io::Error),
}

/// Result alias used throughout the crate.
pub type Result<T> = std::result::Result<T, RmiError>;

impl RmiError {
    /// Builds an [`RmiError::InvalidConfig`].
    pub fn config(field: impl Into<String>, value: impl ToString, expected: impl Into<String>) -> Self {
        RmiError::InvalidConfig { field: field.into(), value: value.to_string(), expected: expected.into() }
    }
}
