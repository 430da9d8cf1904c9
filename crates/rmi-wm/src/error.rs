//! The error type of the rollout. The Python binding maps it to the same exception as the
//! engine's invalid configurations (`ConfigError`), with the same text.

use thiserror::Error;

/// A failure of model construction or of a rollout call: a weight or an input that does not
/// fit the model.
#[derive(Debug, Error)]
pub enum WmError {
    /// A weight, a bookkeeping index or an input is missing, misshapen or out of range.
    #[error("invalid config: `{field}` = {value} is not accepted; expected {expected}")]
    InvalidConfig {
        /// What is wrong, e.g. the torch name of a weight (`decoder.1.weight_hh`) or `chunks`.
        field: String,
        /// The offending value, as text.
        value: String,
        /// The accepted shape, range or form.
        expected: String,
    },
}

/// Result alias of the crate.
pub type Result<T> = std::result::Result<T, WmError>;

impl WmError {
    /// Builds a [`WmError::InvalidConfig`].
    pub fn config(field: impl Into<String>, value: impl ToString, expected: impl Into<String>) -> Self {
        WmError::InvalidConfig { field: field.into(), value: value.to_string(), expected: expected.into() }
    }
}
