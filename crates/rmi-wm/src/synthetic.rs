//! Models with random weights, for tests and benchmarks (no trained run needed).

use std::collections::HashMap;

use crate::model::Tensor;

/// Shape of a GRU world model.
#[derive(Clone, Copy, Debug)]
pub struct Dims {
    /// Observation channels (23 in rmi).
    pub n_obs: usize,
    /// Hidden width (128).
    pub hidden: usize,
    /// GRU layers of encoder and decoder (2).
    pub layers: usize,
    /// Width of the command embedding E_u (64), or None for State-GRU-WM.
    pub embed: Option<usize>,
    /// Commands per step (2).
    pub n_u: usize,
}

impl Dims {
    /// The paper's AC-GRU-WM: 23 observations, width 128, 2 layers, E_u width 64, 2 commands.
    pub const PAPER: Dims = Dims { n_obs: 23, hidden: 128, layers: 2, embed: Some(64), n_u: 2 };
}

/// A `state_dict` with torch's names and uniform values in [-scale, scale), from `seed`.
pub fn random_state(d: Dims, scale: f32, seed: u64) -> HashMap<String, Tensor> {
    let mut s = seed;
    let mut t = |shape: &[usize]| {
        let data = (0..shape.iter().product())
            .map(|_| {
                s = s.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
                scale * (2.0 * ((s >> 40) as f32 / (1u64 << 24) as f32) - 1.0)
            })
            .collect();
        Tensor { shape: shape.to_vec(), data }
    };
    let g = 3 * d.hidden;
    let e = d.embed.unwrap_or(0);
    let mut m = HashMap::new();
    for i in 0..d.layers {
        let (ei, di) = if i == 0 { (2 * d.n_obs, 2 * d.n_obs + e) } else { (d.hidden, d.hidden) };
        m.insert(format!("encoder.weight_ih_l{i}"), t(&[g, ei]));
        m.insert(format!("encoder.weight_hh_l{i}"), t(&[g, d.hidden]));
        m.insert(format!("encoder.bias_ih_l{i}"), t(&[g]));
        m.insert(format!("encoder.bias_hh_l{i}"), t(&[g]));
        m.insert(format!("decoder.{i}.weight_ih"), t(&[g, di]));
        m.insert(format!("decoder.{i}.weight_hh"), t(&[g, d.hidden]));
        m.insert(format!("decoder.{i}.bias_ih"), t(&[g]));
        m.insert(format!("decoder.{i}.bias_hh"), t(&[g]));
    }
    if e > 0 {
        m.insert("E_u.0.weight".into(), t(&[e, d.n_u]));
        m.insert("E_u.0.bias".into(), t(&[e]));
        m.insert("E_u.2.weight".into(), t(&[e, e]));
        m.insert("E_u.2.bias".into(), t(&[e]));
    }
    m.insert("head.weight".into(), t(&[d.n_obs, d.hidden]));
    m.insert("head.bias".into(), t(&[d.n_obs]));
    m
}
