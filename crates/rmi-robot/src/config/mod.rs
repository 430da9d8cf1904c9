//! The trial's configuration, built and checked in one place for every caller (Rust, the
//! Python binding, stored runs).
//!
//! - [`TrialConfig`]: the fields, their defaults and checks, and the simulation scene they
//!   describe (`trial_config.rs`); [`TrialConfig::from_json_value`] builds one from a JSON
//!   value over the defaults, with errors naming the dotted field;
//! - [`overlay()`]: a JSON value laid over a default of the same shape, checked key by key
//!   (`overlay.rs`);
//! - [`PaperTrial`] and [`trial_config`]: configs of the paper's sponges from their size in
//!   centimetres, porosity and forces, with overrides by name (`paper.rs`).

mod overlay;
mod paper;
mod trial_config;

pub use overlay::{field_path, overlay};
pub use paper::{paper_sponge_size, trial_config, PaperTrial};
pub use trial_config::TrialConfig;

/// The field an [`rmi_sph::RmiError::InvalidConfig`] names (tests of this module's parts).
#[cfg(test)]
fn invalid_field(e: rmi_sph::RmiError) -> String {
    match e {
        rmi_sph::RmiError::InvalidConfig { field, .. } => field,
        other => panic!("not a config error: {other}"),
    }
}
