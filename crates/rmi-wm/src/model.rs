//! The GRU world model (AC-GRU-WM, State-GRU-WM) and its free rollout.
//!
//! Same equations as `GRUWorldModel.forward` in `python/rmi_learn/world_models/gru.py`, in
//! standardised units: the encoder reads `[y * keep, m * keep]` over the history; the decoder
//! starts from its final state per layer; its input at step tau is `[y, m, E_u(u_tau)]`, with
//! the last observation and its mask at tau = 0 and afterwards the model's own prediction
//! `[z, sigmoid(c), softmax(f)]` in observation order, masked by `keep`, with mask `keep`;
//! the head gives `[dz | c | f]` and `z` accumulates `dz` from the last observed state.

use std::collections::HashMap;

use crate::error::{Result, WmError};
use rayon::prelude::*;

use crate::gemm::{acc, Mat};
use crate::gru::{exp, fill_rows, sigmoid, GruLayer, Mlp2};

/// A named weight as torch stores it: shape and row-major values.
#[derive(Clone, Debug)]
pub struct Tensor {
    /// Dimensions, e.g. `[384, 128]` for a GRU's `weight_hh`.
    pub shape: Vec<usize>,
    /// Values, row-major.
    pub data: Vec<f32>,
}

/// Observation bookkeeping that the weights do not carry (from `rmi_learn.world_models.common`).
#[derive(Clone, Debug)]
pub struct Spec {
    /// Per observation channel, 1 if the model's state groups keep it, else 0 (`obs_keep`).
    pub keep: Vec<f32>,
    /// Per observation channel, its position in the head's `[z | c | f]` output
    /// (`ASSEMBLE_INDEX`).
    pub assemble: Vec<usize>,
    /// Observation channel of each continuous state entry (`CONTINUOUS_INDEX`).
    pub continuous: Vec<usize>,
}

/// A forecast for `n` chunks of `h` steps, standardised like the training data.
#[derive(Clone, Debug, Default)]
pub struct Forecast {
    /// Continuous states, `n x h x n_z`.
    pub z: Vec<f32>,
    /// Contact logits, `n x h`.
    pub contact_logit: Vec<f32>,
    /// Friction-class logits, `n x h x n_fric`.
    pub friction_logit: Vec<f32>,
}

/// The inputs of one scoring call: `b` histories of `l` steps and `n` command chunks of `h`
/// steps of `n_u` commands; chunk `i` belongs to history `i / (n / b)` (as in torch's
/// `repeat_interleave`).
#[derive(Clone, Copy, Debug)]
pub struct Inputs<'a> {
    /// Standardised observations, `b x l x n_obs`.
    pub hist: &'a [f32],
    /// Their validity mask (1 valid, 0 missing), same shape.
    pub mask: &'a [f32],
    /// Standardised commands, `n x h x n_u`.
    pub actions: &'a [f32],
    /// Number of histories.
    pub b: usize,
    /// History length.
    pub l: usize,
    /// Number of chunks.
    pub n: usize,
    /// Horizon in steps.
    pub h: usize,
    /// Commands per step.
    pub n_u: usize,
}

/// AC-GRU-WM (with the command encoder) or State-GRU-WM (without), ready to roll out.
#[derive(Clone, Debug)]
pub struct GruWorldModel {
    spec: Spec,
    hidden: usize,
    encoder: Vec<GruLayer>,
    decoder: Vec<GruLayer>,
    command: Option<Mlp2>,
    /// Decoder layer 0's input weights split by input: fed-back observation, mask, command.
    w_y: Mat,
    w_m: Mat,
    w_e: Option<Mat>,
    /// Input bias of decoder layer 0 plus the constant mask term of the steps after the first.
    b_rest: Vec<f32>,
    head: Mat,
    b_head: Vec<f32>,
}

/// One thread's share of the outputs: group number and its rows of z, contact, friction.
type Group<'a> = (usize, ((&'a mut [f32], &'a mut [f32]), &'a mut [f32]));

fn shape_err(key: &str, got: &[usize], want: &[usize]) -> WmError {
    WmError::config(key, format!("shape {got:?}"), format!("shape {want:?}"))
}

struct Weights<'a>(&'a HashMap<String, Tensor>);

impl Weights<'_> {
    fn get(&self, key: &str, want: &[usize]) -> Result<&[f32]> {
        let t =
            self.0.get(key).ok_or_else(|| WmError::config(key, "missing", format!("a weight of shape {want:?}")))?;
        if t.shape != want || t.data.len() != want.iter().product::<usize>() {
            return Err(shape_err(key, &t.shape, want));
        }
        if let Some(bad) = t.data.iter().find(|v| !v.is_finite()) {
            return Err(WmError::config(key, bad, "finite values"));
        }
        Ok(&t.data)
    }

    fn layer(&self, names: [String; 4], inputs: usize, hidden: usize) -> Result<GruLayer> {
        let g = 3 * hidden;
        Ok(GruLayer {
            hidden,
            w_ih: Mat::from_torch(self.get(&names[0], &[g, inputs])?, g, inputs),
            w_hh: Mat::from_torch(self.get(&names[1], &[g, hidden])?, g, hidden),
            b_ih: self.get(&names[2], &[g])?.to_vec(),
            b_hh: self.get(&names[3], &[g])?.to_vec(),
        })
    }
}

impl GruWorldModel {
    /// Builds the model from a torch `state_dict` (names as in `GRUWorldModel`:
    /// `encoder.weight_ih_l0`, ..., `decoder.0.weight_ih`, ..., `E_u.0.weight`, `E_u.2.weight`
    /// (absent for State-GRU-WM), `head.weight`, `head.bias`). Any missing or misshapen
    /// weight, non-finite value or inconsistent spec is an error naming it.
    pub fn from_state(state: &HashMap<String, Tensor>, spec: Spec) -> Result<Self> {
        let n_obs = spec.keep.len();
        let n_z = spec.continuous.len();
        if spec.assemble.len() != n_obs {
            return Err(WmError::config(
                "spec.assemble",
                spec.assemble.len(),
                format!("{n_obs} entries (one per channel)"),
            ));
        }
        // The head is [z (n_z) | contact (1) | friction (at least 1)], z not empty.
        if n_z == 0 || n_z + 2 > n_obs {
            return Err(WmError::config(
                "spec.continuous",
                format!("{n_z} entries"),
                format!("1 to {} entries", n_obs.saturating_sub(2)),
            ));
        }
        if let Some(&i) = spec.assemble.iter().chain(&spec.continuous).find(|&&i| i >= n_obs) {
            return Err(WmError::config("spec.assemble/continuous", i, format!("indices in [0, {n_obs})")));
        }
        let w = Weights(state);
        let hh = state
            .get("encoder.weight_hh_l0")
            .ok_or_else(|| WmError::config("encoder.weight_hh_l0", "missing", "a GRU encoder weight"))?;
        let hidden = hh.shape.get(1).copied().unwrap_or(0);
        if hidden == 0 {
            return Err(shape_err("encoder.weight_hh_l0", &hh.shape, &[384, 128]));
        }
        let layers = (0..).take_while(|i| state.contains_key(&format!("encoder.weight_ih_l{i}"))).count();
        let dec_layers = (0..).take_while(|i| state.contains_key(&format!("decoder.{i}.weight_ih"))).count();
        if dec_layers != layers {
            return Err(WmError::config(
                "decoder",
                format!("{dec_layers} layers"),
                format!("{layers} layers, as the encoder"),
            ));
        }
        let command = if state.contains_key("E_u.0.weight") {
            let e0 = &state["E_u.0.weight"].shape;
            let (e, n_u) = (e0.first().copied().unwrap_or(0), e0.get(1).copied().unwrap_or(0));
            Some(Mlp2 {
                w1: Mat::from_torch(w.get("E_u.0.weight", &[e, n_u])?, e, n_u),
                b1: w.get("E_u.0.bias", &[e])?.to_vec(),
                w2: Mat::from_torch(w.get("E_u.2.weight", &[e, e])?, e, e),
                b2: w.get("E_u.2.bias", &[e])?.to_vec(),
            })
        } else {
            None
        };
        let e = command.as_ref().map_or(0, Mlp2::width);
        let mut encoder = Vec::with_capacity(layers);
        let mut decoder = Vec::with_capacity(layers);
        for i in 0..layers {
            let names = ["weight_ih", "weight_hh", "bias_ih", "bias_hh"];
            let enc_in = if i == 0 { 2 * n_obs } else { hidden };
            let dec_in = if i == 0 { 2 * n_obs + e } else { hidden };
            encoder.push(w.layer(names.map(|s| format!("encoder.{s}_l{i}")), enc_in, hidden)?);
            decoder.push(w.layer(names.map(|s| format!("decoder.{i}.{s}")), dec_in, hidden)?);
        }
        let head = Mat::from_torch(w.get("head.weight", &[n_obs, hidden])?, n_obs, hidden);
        let b_head = w.get("head.bias", &[n_obs])?.to_vec();
        let d0 = &decoder[0];
        let (w_y, w_m) = (d0.w_ih.row_range(0, n_obs), d0.w_ih.row_range(n_obs, 2 * n_obs));
        let w_e = command.as_ref().map(|_| d0.w_ih.row_range(2 * n_obs, 2 * n_obs + e));
        let mut b_rest = d0.b_ih.clone();
        acc(&spec.keep, n_obs, 1, &w_m, &mut b_rest, 3 * hidden);
        Ok(GruWorldModel { spec, hidden, encoder, decoder, command, w_y, w_m, w_e, b_rest, head, b_head })
    }

    /// Whether the model reads commands (AC-GRU-WM).
    pub fn action_conditioned(&self) -> bool {
        self.command.is_some()
    }

    /// Hidden width.
    pub fn hidden(&self) -> usize {
        self.hidden
    }

    /// Observation channels (23).
    pub fn n_obs(&self) -> usize {
        self.spec.keep.len()
    }

    /// Continuous state entries (18).
    pub fn n_z(&self) -> usize {
        self.spec.continuous.len()
    }

    /// Friction classes (4).
    pub fn n_fric(&self) -> usize {
        self.n_obs() - self.n_z() - 1
    }

    fn check(&self, x: &Inputs<'_>) -> Result<()> {
        let n_obs = self.spec.keep.len();
        let pos = |field: &str, v: usize| if v == 0 { Err(WmError::config(field, v, "at least 1")) } else { Ok(()) };
        pos("histories", x.b)?;
        pos("history length", x.l)?;
        pos("chunks", x.n)?;
        pos("horizon", x.h)?;
        if !x.n.is_multiple_of(x.b) {
            return Err(WmError::config("chunks", x.n, format!("a multiple of the {} histories", x.b)));
        }
        let want = x.b * x.l * n_obs;
        for (field, got) in [("hist", x.hist.len()), ("hist_mask", x.mask.len())] {
            if got != want {
                return Err(WmError::config(
                    field,
                    format!("{got} values"),
                    format!("{} x {} x {n_obs} = {want}", x.b, x.l),
                ));
            }
        }
        if x.actions.len() != x.n * x.h * x.n_u {
            return Err(WmError::config(
                "actions",
                format!("{} values", x.actions.len()),
                format!("{} x {} x {}", x.n, x.h, x.n_u),
            ));
        }
        if let Some(c) = &self.command {
            if x.n_u != c.w1.rows {
                return Err(WmError::config(
                    "actions",
                    format!("{} commands per step", x.n_u),
                    format!("{}", c.w1.rows),
                ));
            }
        }
        Ok(())
    }

    /// Free rollout of every chunk. With a pool, its threads take contiguous groups of
    /// chunks (each group encodes the histories it needs); the result is the same bits for
    /// any pool size.
    pub fn forecast(&self, x: Inputs<'_>, pool: Option<&rayon::ThreadPool>) -> Result<Forecast> {
        self.check(&x)?;
        let (n_z, n_obs) = (self.spec.continuous.len(), self.spec.keep.len());
        let n_fric = n_obs - n_z - 1;
        let mut out = Forecast {
            z: vec![0.0; x.n * x.h * n_z],
            contact_logit: vec![0.0; x.n * x.h],
            friction_logit: vec![0.0; x.n * x.h * n_fric],
        };
        let groups = pool.map_or(1, |p| p.current_num_threads()).clamp(1, x.n);
        let per = x.n.div_ceil(groups);
        let run = |(g, ((z, c), f)): Group<'_>| {
            let lo = g * per;
            let rows = c.len() / x.h;
            self.group(&x, lo, rows, z, c, f);
        };
        let (zl, cl, fl) = (per * x.h * n_z, per * x.h, per * x.h * n_fric);
        let Forecast { z, contact_logit, friction_logit } = &mut out;
        match pool {
            Some(p) if groups > 1 => p.install(|| {
                z.par_chunks_mut(zl)
                    .zip(contact_logit.par_chunks_mut(cl))
                    .zip(friction_logit.par_chunks_mut(fl))
                    .enumerate()
                    .for_each(run)
            }),
            _ => z
                .chunks_mut(zl)
                .zip(contact_logit.chunks_mut(cl))
                .zip(friction_logit.chunks_mut(fl))
                .enumerate()
                .for_each(run),
        }
        Ok(out)
    }

    /// Chunks `lo..lo + rows`: encode their histories, then step the decoder.
    fn group(&self, x: &Inputs<'_>, lo: usize, rows: usize, z_out: &mut [f32], c_out: &mut [f32], f_out: &mut [f32]) {
        let Spec { keep, assemble, continuous } = &self.spec;
        let (n_obs, n_z, hd) = (keep.len(), continuous.len(), self.hidden);
        let (g3, n_head, h_len) = (3 * hd, n_obs, x.h);
        let rep = x.n / x.b;
        let b0 = lo / rep;
        let nb = (lo + rows - 1) / rep - b0 + 1;
        let layers = self.encoder.len();

        // History encoder over the nb histories of this group.
        let mut henc = vec![vec![0.0f32; nb * hd]; layers];
        let mut inp = vec![0.0f32; nb * 2 * n_obs];
        let m = rows.max(nb);
        let (mut gi, mut gh) = (vec![0.0f32; m * g3], vec![0.0f32; m * g3]);
        for t in 0..x.l {
            for (bi, row) in inp.chunks_exact_mut(2 * n_obs).enumerate() {
                let at = ((b0 + bi) * x.l + t) * n_obs;
                for j in 0..n_obs {
                    row[j] = x.hist[at + j] * keep[j];
                    row[n_obs + j] = x.mask[at + j] * keep[j];
                }
            }
            for i in 0..layers {
                let (below, rest) = henc.split_at_mut(i);
                let (src, ld) = if i == 0 { (&inp[..], 2 * n_obs) } else { (&below[i - 1][..], hd) };
                self.encoder[i].input_gates(src, ld, nb, &mut gi);
                self.encoder[i].step(&gi, &mut rest[0], nb, &mut gh);
            }
        }

        // Decoder state, last observation and accumulated continuous state per chunk.
        let hist_of = |r: usize| (lo + r) / rep - b0;
        let mut h: Vec<Vec<f32>> = henc
            .iter()
            .map(|he| (0..rows).flat_map(|r| he[hist_of(r) * hd..(hist_of(r) + 1) * hd].iter().copied()).collect())
            .collect();
        let last = |r: usize| ((b0 + hist_of(r)) * x.l + x.l - 1) * n_obs;
        let mut obs: Vec<f32> =
            (0..rows).flat_map(|r| (0..n_obs).map(move |j| x.hist[last(r) + j] * keep[j])).collect();
        let mut z: Vec<f32> =
            (0..rows).flat_map(|r| continuous.iter().map(move |&j| x.hist[last(r) + j] * keep[j])).collect();

        // Layer-0 input gates that do not depend on the rollout: bias, mask term, commands.
        // Step 0 sees the observed mask (its term is accumulated here); later steps see
        // `keep`, whose term is folded into `b_rest`.
        let mut pre = vec![0.0f32; rows * h_len * g3];
        for slots in pre.chunks_exact_mut(h_len * g3) {
            slots[..g3].copy_from_slice(&self.decoder[0].b_ih);
            fill_rows(&mut slots[g3..], h_len - 1, &self.b_rest);
        }
        let mask0: Vec<f32> = (0..rows).flat_map(|r| (0..n_obs).map(move |j| x.mask[last(r) + j] * keep[j])).collect();
        acc(&mask0, n_obs, rows, &self.w_m, &mut pre, h_len * g3);
        if let (Some(enc), Some(w_e)) = (&self.command, &self.w_e) {
            let e = enc.width();
            let mut hidden = vec![0.0f32; rows * h_len * e];
            let mut cmd = vec![0.0f32; rows * h_len * e];
            enc.forward(
                &x.actions[lo * h_len * x.n_u..(lo + rows) * h_len * x.n_u],
                rows * h_len,
                &mut hidden,
                &mut cmd,
            );
            acc(&cmd, e, rows * h_len, w_e, &mut pre, g3);
        }

        let mut head = vec![0.0f32; rows * n_head];
        let mut q = vec![0.0f32; n_head];
        let n_fric = n_obs - n_z - 1;
        for tau in 0..h_len {
            for r in 0..rows {
                let at = (r * h_len + tau) * g3;
                gi[r * g3..(r + 1) * g3].copy_from_slice(&pre[at..at + g3]);
            }
            acc(&obs, n_obs, rows, &self.w_y, &mut gi, g3);
            for i in 0..layers {
                let (below, rest) = h.split_at_mut(i);
                if i > 0 {
                    self.decoder[i].input_gates(&below[i - 1], hd, rows, &mut gi);
                }
                self.decoder[i].step(&gi, &mut rest[0], rows, &mut gh);
            }
            fill_rows(&mut head, rows, &self.b_head);
            acc(&h[layers - 1], hd, rows, &self.head, &mut head, n_head);
            for r in 0..rows {
                let hr = &head[r * n_head..(r + 1) * n_head];
                let zr = &mut z[r * n_z..(r + 1) * n_z];
                for (zi, d) in zr.iter_mut().zip(&hr[..n_z]) {
                    *zi += d;
                }
                let o = r * h_len + tau;
                z_out[o * n_z..(o + 1) * n_z].copy_from_slice(zr);
                c_out[o] = hr[n_z];
                f_out[o * n_fric..(o + 1) * n_fric].copy_from_slice(&hr[n_z + 1..]);
                if tau + 1 < h_len {
                    q[..n_z].copy_from_slice(zr);
                    q[n_z] = sigmoid(hr[n_z]);
                    softmax(&hr[n_z + 1..], &mut q[n_z + 1..]);
                    for j in 0..n_obs {
                        obs[r * n_obs + j] = q[assemble[j]] * keep[j];
                    }
                }
            }
        }
    }
}

fn softmax(logits: &[f32], out: &mut [f32]) {
    let m = logits.iter().copied().fold(f32::NEG_INFINITY, f32::max);
    let mut s = 0.0;
    for (o, &l) in out.iter_mut().zip(logits) {
        *o = exp(l - m);
        s += *o;
    }
    for o in out.iter_mut() {
        *o /= s;
    }
}
