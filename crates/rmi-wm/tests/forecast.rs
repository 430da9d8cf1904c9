//! The rollout's contract on a small random model: same bits for any thread count and for
//! shared or repeated histories, the persistence forecast from a zero head, errors that name
//! the weight.

use std::collections::HashMap;

use rayon::ThreadPoolBuilder;
use rmi_wm::synthetic::{random_state, Dims};
use rmi_wm::WmError;
use rmi_wm::{Forecast, GruWorldModel, Inputs, Spec, Tensor};

const N_OBS: usize = 7; // 4 continuous, contact, 2 friction classes
const HID: usize = 6;
const E: usize = 5;

fn lcg(s: &mut u64) -> f32 {
    *s = s.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
    ((*s >> 40) as f32 / (1u64 << 24) as f32) - 0.5
}

fn state(seed: u64) -> HashMap<String, Tensor> {
    random_state(Dims { n_obs: N_OBS, hidden: HID, layers: 2, embed: Some(E), n_u: 2 }, 0.5, seed)
}

fn spec() -> Spec {
    // Observation order differs from the head's [z | c | f] order, and channel 5 is ablated.
    Spec {
        keep: vec![1.0, 1.0, 1.0, 1.0, 1.0, 0.0, 1.0],
        assemble: vec![4, 0, 1, 5, 2, 3, 6],
        continuous: vec![1, 2, 4, 5],
    }
}

fn data(b: usize, l: usize, n: usize, h: usize) -> (Vec<f32>, Vec<f32>, Vec<f32>) {
    let mut s = 99;
    let hist = (0..b * l * N_OBS).map(|_| 3.0 * lcg(&mut s)).collect();
    let mask = (0..b * l * N_OBS).map(|_| if lcg(&mut s) > -0.3 { 1.0 } else { 0.0 }).collect();
    let act = (0..n * h * 2).map(|_| 2.0 * lcg(&mut s)).collect();
    (hist, mask, act)
}

fn run(m: &GruWorldModel, x: Inputs<'_>, threads: usize) -> Forecast {
    let pool = ThreadPoolBuilder::new().num_threads(threads).build().unwrap();
    m.forecast(x, (threads > 1).then_some(&pool)).unwrap()
}

fn bits(v: &[f32]) -> Vec<u32> {
    v.iter().map(|x| x.to_bits()).collect()
}

#[test]
fn same_bits_for_any_thread_count_and_shared_or_repeated_histories() {
    let m = GruWorldModel::from_state(&state(1), spec()).unwrap();
    assert!(m.action_conditioned());
    let (b, l, n, h) = (2, 5, 8, 9);
    let (hist, mask, act) = data(b, l, n, h);
    let x = Inputs { hist: &hist, mask: &mask, actions: &act, b, l, n, h, n_u: 2 };
    let one = run(&m, x, 1);
    assert!(one.z.iter().all(|v| v.is_finite()));
    for threads in [2, 3, 5, 8, 11] {
        let f = run(&m, x, threads);
        assert_eq!(bits(&f.z), bits(&one.z), "{threads} threads");
        assert_eq!(bits(&f.contact_logit), bits(&one.contact_logit));
        assert_eq!(bits(&f.friction_logit), bits(&one.friction_logit));
    }
    // Each history repeated per chunk (torch's repeat_interleave) gives the same bits.
    let rep = n / b;
    let per = l * N_OBS;
    let expand = |v: &[f32]| (0..n).flat_map(|i| v[(i / rep) * per..(i / rep + 1) * per].to_vec()).collect::<Vec<_>>();
    let (hist_r, mask_r) = (expand(&hist), expand(&mask));
    let xr = Inputs { hist: &hist_r, mask: &mask_r, b: n, ..x };
    assert_eq!(bits(&run(&m, xr, 2).z), bits(&one.z));
    // The chunks differ (the commands matter) and the horizon's steps differ.
    assert_ne!(one.z[..4], one.z[h * 4..h * 4 + 4]);
    assert_ne!(one.z[..4], one.z[4..8]);
}

#[test]
fn zero_head_gives_the_persistence_forecast() {
    let mut st = state(2);
    for key in ["head.weight", "head.bias"] {
        st.get_mut(key).unwrap().data.iter_mut().for_each(|v| *v = 0.0);
    }
    let m = GruWorldModel::from_state(&st, spec()).unwrap();
    let (b, l, n, h) = (1, 4, 3, 6);
    let (hist, mask, act) = data(b, l, n, h);
    let f = run(&m, Inputs { hist: &hist, mask: &mask, actions: &act, b, l, n, h, n_u: 2 }, 1);
    let last = &hist[(l - 1) * N_OBS..l * N_OBS];
    let sp = spec();
    for step in f.z.chunks_exact(4) {
        for (k, &j) in sp.continuous.iter().enumerate() {
            assert_eq!(step[k], last[j] * sp.keep[j]);
        }
    }
    assert!(f.contact_logit.iter().chain(&f.friction_logit).all(|&v| v == 0.0));
}

#[test]
fn bad_weights_and_inputs_name_the_field() {
    let field = |e: WmError| {
        let WmError::InvalidConfig { field, .. } = e;
        field
    };
    let mut st = state(3);
    st.get_mut("decoder.1.weight_hh").unwrap().shape = vec![HID, 3 * HID];
    assert_eq!(field(GruWorldModel::from_state(&st, spec()).unwrap_err()), "decoder.1.weight_hh");
    let mut st = state(3);
    st.remove("E_u.2.bias");
    assert_eq!(field(GruWorldModel::from_state(&st, spec()).unwrap_err()), "E_u.2.bias");
    let mut st = state(3);
    st.get_mut("head.bias").unwrap().data[2] = f32::INFINITY;
    assert_eq!(field(GruWorldModel::from_state(&st, spec()).unwrap_err()), "head.bias");
    let mut bad = spec();
    bad.assemble[0] = N_OBS;
    assert!(GruWorldModel::from_state(&state(3), bad).is_err());
    for continuous in [vec![], vec![0, 1, 2, 3, 4, 5]] {
        let bad = Spec { continuous, ..spec() };
        assert_eq!(field(GruWorldModel::from_state(&state(3), bad).unwrap_err()), "spec.continuous");
    }

    let m = GruWorldModel::from_state(&state(3), spec()).unwrap();
    let (hist, mask, act) = data(2, 3, 4, 5);
    let x = Inputs { hist: &hist, mask: &mask, actions: &act, b: 2, l: 3, n: 4, h: 5, n_u: 2 };
    assert_eq!(field(m.forecast(Inputs { n: 3, ..x }, None).unwrap_err()), "chunks");
    assert_eq!(field(m.forecast(Inputs { l: 4, ..x }, None).unwrap_err()), "hist");
    assert_eq!(field(m.forecast(Inputs { h: 0, ..x }, None).unwrap_err()), "horizon");
    assert_eq!(field(m.forecast(Inputs { n_u: 1, h: 10, ..x }, None).unwrap_err()), "actions");
}

#[test]
fn state_only_model_ignores_the_commands() {
    let mut st = state(4);
    st.retain(|k, _| !k.starts_with("E_u"));
    // Decoder input without the command embedding.
    let w = st.get_mut("decoder.0.weight_ih").unwrap();
    w.shape = vec![3 * HID, 2 * N_OBS];
    w.data.truncate(3 * HID * 2 * N_OBS);
    let m = GruWorldModel::from_state(&st, spec()).unwrap();
    assert!(!m.action_conditioned());
    let (hist, mask, act) = data(1, 3, 2, 4);
    let x = Inputs { hist: &hist, mask: &mask, actions: &act, b: 1, l: 3, n: 2, h: 4, n_u: 2 };
    let other: Vec<f32> = act.iter().map(|v| v + 1.0).collect();
    let a = run(&m, x, 1);
    let b = run(&m, Inputs { actions: &other, ..x }, 1);
    assert_eq!(bits(&a.z), bits(&b.z));
}
