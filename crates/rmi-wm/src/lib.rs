//! Fused CPU inference of rmi's recurrent world models.
//!
//! A planner scores a handful of candidate command chunks against one history at every
//! decision, within the latency target of docs/benchmarks.md ("World-model scoring latency").
//! In eager torch
//! each decoder step of AC-GRU-WM is about 20 small kernels at batch 8, and their dispatch,
//! not their arithmetic, sets the time. This crate runs the whole free rollout of the
//! GRU world models of `python/rmi_learn/world_models/gru.py` (history encoder, command encoder
//! E_u, GRU-cell decoder, heads, fed-back predictions) in one call, with the weights of a
//! torch `state_dict`, so the Python side pays one crossing per scoring call.
//!
//! - [`gemm`]: the one product it needs, rows times a weight matrix, blocked in registers.
//! - [`gru`]: GRU layers (torch's gate equations) and the two-layer command encoder.
//! - [`model`]: the world model, its construction from named weights, and the rollout.
//! - [`synthetic`]: random weights of a given shape, for tests and benchmarks.
//! - [`error`]: what construction and rollout calls report.
//!
//! Everything is `f32`, as the trained models are. Results do not depend on the thread
//! count: rows (chunks) are independent, and every output element is accumulated in the same
//! order however rows are grouped.

pub mod error;
pub mod gemm;
pub mod gru;
pub mod model;
pub mod synthetic;

pub use error::{Result, WmError};
pub use model::{Forecast, GruWorldModel, Inputs, Spec, Tensor};
