//! The f64 reference of the recurrent baselines T-GCN and EAT-GCN (`model::recurrent`,
//! docs/model.md "Baselines"): the time loop keeping every step's gates and state, EAT-GCN's
//! attention over time, and backpropagation through time by hand. The loss is
//! [`crate::model::reference::loss`].

use crate::model::exact::{axpy, Grads, Table};
use crate::model::head::reference::{flat_head, flat_head_backward};
use crate::model::recurrent::{attends_over_time, support_count, weight_name};
use crate::model::reference::{add_weight_decay, output_gradient, Loss};
use crate::model::{ModelConfig, ParamSpec};

/// One step's values, each `[B, N, ·]` row-major.
#[derive(Clone, Debug)]
pub struct StepTape {
    /// x_t `[B, N, F]`.
    pub x: Vec<f64>,
    /// The reset gate r.
    pub r: Vec<f64>,
    /// The update gate u.
    pub u: Vec<f64>,
    /// The candidate c.
    pub c: Vec<f64>,
    /// The new state h_t.
    pub h: Vec<f64>,
}

/// EAT-GCN's attention over time.
#[derive(Clone, Debug)]
pub struct AttentionTape {
    /// tanh(h_t·Wa + ba) `[B, A]` of every step.
    pub hidden: Vec<Vec<f64>>,
    /// α = softmax_t(e) `[B, T]`.
    pub weights: Vec<f64>,
    /// Σ_t α_t h_t `[B, N·H]`: the head's input.
    pub context: Vec<f64>,
}

/// Everything the forward pass of a recurrent baseline computed.
#[derive(Clone, Debug)]
pub struct RecurrentTape {
    /// B: windows in the batch.
    pub batch: usize,
    /// One entry per time step.
    pub steps: Vec<StepTape>,
    /// The attention over time (EAT-GCN only).
    pub attention: Option<AttentionTape>,
    /// ŷ `[B, O]`.
    pub output: Vec<f64>,
}

struct Shape {
    b: usize,
    n: usize,
    f: usize,
    h: usize,
    t: usize,
    /// K: graph supports.
    k: usize,
}

impl Shape {
    fn of(config: &ModelConfig, batch: usize) -> Shape {
        Shape {
            b: batch,
            n: config.nodes,
            f: config.features,
            h: config.hidden,
            t: config.window,
            k: support_count(config),
        }
    }
}

/// `out[b, i, :] = Σ_j S[i, j] · p[b, j, :]` for rows of width `w`.
fn mix(s: &Shape, a: &[f64], p: &[f64], w: usize) -> Vec<f64> {
    let mut out = vec![0.0; s.b * s.n * w];
    for b in 0..s.b {
        for i in 0..s.n {
            for j in 0..s.n {
                let (dst, src) = ((b * s.n + i) * w, (b * s.n + j) * w);
                let aij = a[i * s.n + j];
                for k in 0..w {
                    out[dst + k] += aij * p[src + k];
                }
            }
        }
    }
    out
}

/// `x [rows, k] · w [k, h]`.
fn product(x: &[f64], w: &[f64], k: usize, h: usize) -> Vec<f64> {
    let rows = x.len() / k;
    let mut out = vec![0.0; rows * h];
    for r in 0..rows {
        for i in 0..k {
            axpy(
                &mut out[r * h..(r + 1) * h],
                x[r * k + i],
                &w[i * h..(i + 1) * h],
            );
        }
    }
    out
}

fn sigmoid(v: f64) -> f64 {
    1.0 / (1.0 + (-v).exp())
}

/// Support k of `supports` `[K, N, N]`.
fn support<'a>(s: &Shape, supports: &'a [f64], k: usize) -> &'a [f64] {
    &supports[k * s.n * s.n..(k + 1) * s.n * s.n]
}

/// Gate `g` before its activation: Σ_k S_k (x·Wx_k + h·Wh_k) + b.
fn gate(s: &Shape, table: &Table, supports: &[f64], g: &str, x: &[f64], h: &[f64]) -> Vec<f64> {
    let mut z = vec![0.0; s.b * s.n * s.h];
    for k in 0..s.k {
        let w = |kind: &str| table.get(&weight_name(g, kind, k, s.k));
        let mut pre = product(x, w("wx"), s.f, s.h);
        axpy(&mut pre, 1.0, &product(h, w("wh"), s.h, s.h));
        axpy(&mut z, 1.0, &mix(s, support(s, supports, k), &pre, s.h));
    }
    let bias = table.get(&format!("cell.{g}.bias"));
    for (i, v) in z.iter_mut().enumerate() {
        *v += bias[i % s.h];
    }
    z
}

/// EAT-GCN's attention over the states `[B, N·H]` of every step: e_t = v · tanh(h_t·Wa +
/// ba) per window, α = softmax_t(e), context = Σ_t α_t h_t.
fn attention(s: &Shape, table: &Table, states: &[&[f64]]) -> AttentionTape {
    let (nh, a) = (s.n * s.h, s.h);
    let (wa, ba, v) = (
        table.get("attn.W"),
        table.get("attn.b"),
        table.get("attn.v"),
    );
    let mut scores = vec![0.0; s.b * s.t];
    let hidden: Vec<Vec<f64>> = states
        .iter()
        .enumerate()
        .map(|(t, h)| {
            let mut z = product(h, wa, nh, a);
            for (i, z) in z.iter_mut().enumerate() {
                *z = (*z + ba[i % a]).tanh();
            }
            for b in 0..s.b {
                scores[b * s.t + t] = (0..a).map(|i| z[b * a + i] * v[i]).sum();
            }
            z
        })
        .collect();
    let mut weights = vec![0.0; s.b * s.t];
    let mut context = vec![0.0; s.b * nh];
    for b in 0..s.b {
        let e = &scores[b * s.t..(b + 1) * s.t];
        let m = e.iter().copied().fold(f64::NEG_INFINITY, f64::max);
        let z: f64 = e.iter().map(|e| (e - m).exp()).sum();
        for (t, h) in states.iter().enumerate() {
            let alpha = (e[t] - m).exp() / z;
            weights[b * s.t + t] = alpha;
            axpy(
                &mut context[b * nh..(b + 1) * nh],
                alpha,
                &h[b * nh..(b + 1) * nh],
            );
        }
    }
    AttentionTape {
        hidden,
        weights,
        context,
    }
}

/// The forward pass on `x` `[B, N, F, T]`; `supports` are the gates' graph supports
/// `[K, N, N]` (`model::recurrent::supports`).
pub fn forward(
    config: &ModelConfig,
    supports: &[f64],
    specs: &[ParamSpec],
    params: &[Vec<f64>],
    x: &[f64],
    batch: usize,
) -> RecurrentTape {
    let s = Shape::of(config, batch);
    let table = Table::new(specs, params);
    assert_eq!(x.len(), s.b * s.n * s.f * s.t, "x is [B,N,F,T]");
    assert_eq!(supports.len(), s.k * s.n * s.n, "supports are [K,N,N]");
    let mut h = vec![0.0; s.b * s.n * s.h];
    let mut steps = Vec::with_capacity(s.t);
    for t in 0..s.t {
        let xt: Vec<f64> = (0..s.b * s.n * s.f).map(|r| x[r * s.t + t]).collect();
        let r: Vec<f64> = gate(&s, &table, supports, "r", &xt, &h)
            .into_iter()
            .map(sigmoid)
            .collect();
        let u: Vec<f64> = gate(&s, &table, supports, "u", &xt, &h)
            .into_iter()
            .map(sigmoid)
            .collect();
        let rh: Vec<f64> = r.iter().zip(&h).map(|(r, h)| r * h).collect();
        let c: Vec<f64> = gate(&s, &table, supports, "c", &xt, &rh)
            .into_iter()
            .map(f64::tanh)
            .collect();
        h = (0..h.len())
            .map(|i| u[i] * h[i] + (1.0 - u[i]) * c[i])
            .collect();
        steps.push(StepTape {
            x: xt,
            r,
            u,
            c,
            h: h.clone(),
        });
    }
    let attention = attends_over_time(config.variant).then(|| {
        let states: Vec<&[f64]> = steps.iter().map(|st| st.h.as_slice()).collect();
        attention(&s, &table, &states)
    });
    let head_input = attention.as_ref().map_or(&h, |a| &a.context);
    let (w, bias) = (table.get("head.weight"), table.get("head.bias"));
    let output = flat_head(w, bias, head_input, s.b);
    RecurrentTape {
        batch,
        steps,
        attention,
        output,
    }
}

/// The backward of gate `g` given ∂ℒ/∂(pre-activation) `dz`: adds its parameter
/// gradients, and returns (∂ℒ/∂x_t, ∂ℒ/∂h_in).
fn gate_backward(
    s: &Shape,
    table: &Table,
    grads: &mut Grads,
    supports: &[f64],
    g: &str,
    (x, h): (&[f64], &[f64]),
    dz: &[f64],
) -> (Vec<f64>, Vec<f64>) {
    let mut db = vec![0.0; s.h];
    for (i, v) in dz.iter().enumerate() {
        db[i % s.h] += v;
    }
    grads.add(&format!("cell.{g}.bias"), &db);
    let rows = dz.len() / s.h;
    let (mut dx, mut dh) = (vec![0.0; rows * s.f], vec![0.0; rows * s.h]);
    for k in 0..s.k {
        // ∂ℒ/∂(x·Wx_k + h·Wh_k) = S_kᵀ dz.
        let a = support(s, supports, k);
        let mut at = vec![0.0; s.n * s.n];
        for i in 0..s.n {
            for j in 0..s.n {
                at[j * s.n + i] = a[i * s.n + j];
            }
        }
        let dp = mix(s, &at, dz, s.h);
        let weight_grad = |input: &[f64], w: usize| {
            let mut dw = vec![0.0; w * s.h];
            for r in 0..rows {
                for i in 0..w {
                    axpy(
                        &mut dw[i * s.h..(i + 1) * s.h],
                        input[r * w + i],
                        &dp[r * s.h..(r + 1) * s.h],
                    );
                }
            }
            dw
        };
        let (wx, wh) = (weight_name(g, "wx", k, s.k), weight_name(g, "wh", k, s.k));
        grads.add(&wx, &weight_grad(x, s.f));
        grads.add(&wh, &weight_grad(h, s.h));
        let input_grad = |wt: &[f64], w: usize, d: &mut [f64]| {
            for r in 0..rows {
                for i in 0..w {
                    d[r * w + i] += wt[i * s.h..(i + 1) * s.h]
                        .iter()
                        .zip(&dp[r * s.h..(r + 1) * s.h])
                        .map(|(w, g)| w * g)
                        .sum::<f64>();
                }
            }
        };
        input_grad(table.get(&wx), s.f, &mut dx);
        input_grad(table.get(&wh), s.h, &mut dh);
    }
    (dx, dh)
}

/// The backward of the attention over time from ∂ℒ/∂context `dc` `[B, N·H]`: adds the
/// gradients of Wa, ba and v, and returns ∂ℒ/∂h_t `[B, N·H]` of every step.
fn attention_backward(
    s: &Shape,
    table: &Table,
    grads: &mut Grads,
    tape: &RecurrentTape,
    at: &AttentionTape,
    dc: &[f64],
) -> Vec<Vec<f64>> {
    let (nh, a) = (s.n * s.h, s.h);
    let (wa, v) = (table.get("attn.W"), table.get("attn.v"));
    let state = |t: usize, b: usize| &tape.steps[t].h[b * nh..(b + 1) * nh];
    // ∂ℒ/∂α_t = h_t · dc, then through the softmax over t.
    let mut de = vec![0.0; s.b * s.t];
    for b in 0..s.b {
        let dc = &dc[b * nh..(b + 1) * nh];
        let da: Vec<f64> = (0..s.t)
            .map(|t| state(t, b).iter().zip(dc).map(|(h, d)| h * d).sum())
            .collect();
        let alpha = &at.weights[b * s.t..(b + 1) * s.t];
        let dot: f64 = da.iter().zip(alpha).map(|(d, a)| d * a).sum();
        for t in 0..s.t {
            de[b * s.t + t] = alpha[t] * (da[t] - dot);
        }
    }
    let (mut dwa, mut dba, mut dv) = (vec![0.0; nh * a], vec![0.0; a], vec![0.0; a]);
    let mut dh = Vec::with_capacity(s.t);
    for t in 0..s.t {
        let z = &at.hidden[t];
        let mut d = vec![0.0; s.b * nh];
        for b in 0..s.b {
            let (e, alpha) = (de[b * s.t + t], at.weights[b * s.t + t]);
            axpy(
                &mut d[b * nh..(b + 1) * nh],
                alpha,
                &dc[b * nh..(b + 1) * nh],
            );
            // ∂ℒ/∂(h_t·Wa + ba) = e' v ⊙ (1 − z²).
            let dpre: Vec<f64> = (0..a)
                .map(|i| e * v[i] * (1.0 - z[b * a + i] * z[b * a + i]))
                .collect();
            axpy(&mut dv, e, &z[b * a..(b + 1) * a]);
            axpy(&mut dba, 1.0, &dpre);
            let h = state(t, b);
            for j in 0..nh {
                axpy(&mut dwa[j * a..(j + 1) * a], h[j], &dpre);
                d[b * nh + j] += wa[j * a..(j + 1) * a]
                    .iter()
                    .zip(&dpre)
                    .map(|(w, g)| w * g)
                    .sum::<f64>();
            }
        }
        dh.push(d);
    }
    grads.add("attn.W", &dwa);
    grads.add("attn.b", &dba);
    grads.add("attn.v", &dv);
    dh
}

/// The gradient of [`crate::model::reference::loss`]`(forward(..))` with respect to every parameter (in
/// spec order) and to x, from the tape of [`forward`].
#[allow(clippy::too_many_arguments)]
pub fn backward(
    config: &ModelConfig,
    supports: &[f64],
    specs: &[ParamSpec],
    params: &[Vec<f64>],
    tape: &RecurrentTape,
    y: &[f64],
    batch: usize,
    loss: &Loss,
) -> (Vec<Vec<f64>>, Vec<f64>) {
    let s = Shape::of(config, batch);
    let table = Table::new(specs, params);
    let o = config.outputs;
    assert_eq!(tape.batch, batch, "tape of another batch size");
    let mut grads = Grads {
        specs,
        values: specs.iter().map(|s| vec![0.0; s.numel()]).collect(),
    };
    let dout = output_gradient(&tape.output, y, o, batch, loss);
    // Head.
    let nh = s.n * s.h;
    let head_input = tape
        .attention
        .as_ref()
        .map_or(&tape.steps[s.t - 1].h, |a| &a.context);
    let mut dh = flat_head_backward(table.get("head.weight"), head_input, &dout, s.b, &mut grads);
    // The attention's share of every ∂ℒ/∂h_t; without it, ∂ℒ/∂h_{T−1} is the head's.
    let from_attention = tape
        .attention
        .as_ref()
        .map(|a| attention_backward(&s, &table, &mut grads, tape, a, &dh));
    if from_attention.is_some() {
        dh.iter_mut().for_each(|d| *d = 0.0);
    }
    // Through time.
    let mut dx = vec![0.0; s.b * s.n * s.f * s.t];
    let zeros = vec![0.0; s.b * nh];
    for t in (0..s.t).rev() {
        let st = &tape.steps[t];
        let h = if t == 0 { &zeros } else { &tape.steps[t - 1].h };
        if let Some(d) = &from_attention {
            axpy(&mut dh, 1.0, &d[t]);
        }
        let mut dh_prev: Vec<f64> = (0..dh.len()).map(|i| st.u[i] * dh[i]).collect();
        let du: Vec<f64> = (0..dh.len()).map(|i| (h[i] - st.c[i]) * dh[i]).collect();
        let dzc: Vec<f64> = (0..dh.len())
            .map(|i| (1.0 - st.u[i]) * dh[i] * (1.0 - st.c[i] * st.c[i]))
            .collect();
        let rh: Vec<f64> = st.r.iter().zip(h).map(|(r, h)| r * h).collect();
        let (mut dxt, drh) =
            gate_backward(&s, &table, &mut grads, supports, "c", (&st.x, &rh), &dzc);
        let mut dzr = vec![0.0; dh.len()];
        for i in 0..dh.len() {
            dh_prev[i] += drh[i] * st.r[i];
            dzr[i] = drh[i] * h[i] * st.r[i] * (1.0 - st.r[i]);
        }
        let dzu: Vec<f64> = (0..dh.len())
            .map(|i| du[i] * st.u[i] * (1.0 - st.u[i]))
            .collect();
        for (g, dz) in [("r", &dzr), ("u", &dzu)] {
            let (dxg, dhg) = gate_backward(&s, &table, &mut grads, supports, g, (&st.x, h), dz);
            axpy(&mut dxt, 1.0, &dxg);
            axpy(&mut dh_prev, 1.0, &dhg);
        }
        for (r, v) in dxt.iter().enumerate() {
            dx[r * s.t + t] += v;
        }
        dh = dh_prev;
    }
    add_weight_decay(specs, params, &mut grads.values, loss);
    (grads.values, dx)
}
