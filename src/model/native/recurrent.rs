//! The recurrent baselines T-GCN and EAT-GCN (`model::recurrent`, docs/model.md
//! "Baselines") on the CPU in f32, one window at a time: the GRU whose gates are graph
//! convolutions, run over the window's T steps, EAT-GCN's attention over time, the head,
//! and backpropagation through time by hand — the arithmetic of the f64 reference
//! `model::reference::recurrent`. Per step t, with x_t `[N, F]`:
//!
//! ```text
//! gate(x, h) = Σ_k S_k (x·Wx_k + h·Wh_k) + b
//! r = σ(gate_r(x_t, h))   u = σ(gate_u(x_t, h))   c = tanh(gate_c(x_t, r ⊙ h))
//! h' = u ⊙ h + (1 − u) ⊙ c
//! ```
//!
//! Every contraction is a `gemm` product (`super::gemm`) on row-major slices; S_k = I (T_0 of
//! EAT-GCN's Chebyshev supports) skips its graph mix, as on the device. The models have no
//! dropout, so training and inference share the forward pass.

use super::{flat_head, flat_head_backward, gemm, rows, sigmoid, softmax_rows, tanh, transposed};
use crate::graph::Graph;
use crate::model::config::ModelConfig;
use crate::model::network::ModelError;
use crate::model::params::ParamSpec;
use crate::model::recurrent::{attends_over_time, support_count, supports, weight_name, GATES};

/// One gate's tensors: per support k, (Wx_k `[F, H]`, Wh_k `[H, H]`), then the bias `[H]`.
struct GateSlots {
    weights: Vec<(usize, usize)>,
    bias: usize,
}

/// Where EAT-GCN's attention over time finds Wa `[N·H, A]`, ba `[A]` and v `[A]`.
struct AttentionSlots {
    w: usize,
    b: usize,
    v: usize,
}

/// A recurrent baseline's graph supports and where its tensors are.
pub(super) struct RecurrentNet {
    n: usize,
    f: usize,
    h: usize,
    t: usize,
    o: usize,
    /// S_k `[N, N]` row-major in f32; `None` where S_k = I.
    supports: Vec<Option<Vec<f32>>>,
    /// Gates r, u, c.
    gates: [GateSlots; 3],
    attention: Option<AttentionSlots>,
    head: (usize, usize),
}

/// EAT-GCN's saved values for one window.
struct AttentionTape {
    /// tanh(h_t·Wa + ba) `[T, A]`.
    hidden: Vec<f32>,
    /// α = softmax_t(e) `[T]` (first the scores e).
    weights: Vec<f32>,
    /// ∂ℒ/∂h_t from the attention `[T, N·H]` (backward only).
    d_states: Vec<f32>,
    /// Backward scratch `[A]`.
    d_pre: Vec<f32>,
}

/// One window's forward values and the backward pass's working memory.
pub(super) struct RecurrentTape {
    /// x_t of every step `[T, N, F]`.
    x: Vec<f32>,
    /// Gates, r ⊙ h_prev and the states of every step, each `[T, N, H]`.
    r: Vec<f32>,
    u: Vec<f32>,
    rh: Vec<f32>,
    c: Vec<f32>,
    states: Vec<f32>,
    attention: Option<AttentionTape>,
    /// What the head reads `[N·H]`: the last state or the context Σ_t α_t h_t.
    head_input: Vec<f32>,
    /// ŷ `[O]`.
    out: Vec<f32>,
    /// `[N, H]` scratch: one support's products, the gate's sum; in the backward pass
    /// ∂ℒ/∂h_t, ∂ℒ/∂h_{t−1}, ∂ℒ/∂(pre-activation), S_kᵀ·dz, ∂ℒ/∂(r ⊙ h), ∂ℒ/∂u.
    pre: Vec<f32>,
    mixed: Vec<f32>,
    dh: Vec<f32>,
    dh_prev: Vec<f32>,
    dz: Vec<f32>,
    dp: Vec<f32>,
    drh: Vec<f32>,
    du: Vec<f32>,
    /// The zero state before step 0.
    h0: Vec<f32>,
}

impl RecurrentTape {
    /// ŷ `[O]` of the last forward pass.
    pub fn output(&self) -> &[f32] {
        &self.out
    }
}

/// The activation of a gate's pre-activation.
#[derive(Clone, Copy)]
enum Act {
    Sigmoid,
    Tanh,
}

impl RecurrentNet {
    /// The supports of `config`'s recurrent variant on `graph` and its tensors in
    /// `specs`; an error names a missing tensor.
    pub fn new(
        config: &ModelConfig,
        graph: &Graph,
        specs: &[ParamSpec],
    ) -> Result<RecurrentNet, ModelError> {
        let n = config.nodes;
        if graph.len() != n {
            return Err(ModelError::Config(format!(
                "the graph has {} nodes, the model config {n}",
                graph.len()
            )));
        }
        let find = |name: String| {
            specs
                .iter()
                .position(|s| s.name == name)
                .ok_or_else(|| ModelError::Config(format!("the parameters lack {name}")))
        };
        let terms = support_count(config);
        let gate = |g: &str| -> Result<GateSlots, ModelError> {
            Ok(GateSlots {
                weights: (0..terms)
                    .map(|k| {
                        Ok((
                            find(weight_name(g, "wx", k, terms))?,
                            find(weight_name(g, "wh", k, terms))?,
                        ))
                    })
                    .collect::<Result<_, ModelError>>()?,
                bias: find(format!("cell.{g}.bias"))?,
            })
        };
        let attention = if attends_over_time(config.variant) {
            Some(AttentionSlots {
                w: find("attn.W".into())?,
                b: find("attn.b".into())?,
                v: find("attn.v".into())?,
            })
        } else {
            None
        };
        let supports = supports(graph, config)
            .chunks(n * n)
            .map(|s| {
                let identity = (0..n * n).all(|i| s[i] == if i % (n + 1) == 0 { 1.0 } else { 0.0 });
                (!identity).then(|| s.iter().map(|&v| v as f32).collect())
            })
            .collect();
        Ok(RecurrentNet {
            n,
            f: config.features,
            h: config.hidden,
            t: config.window,
            o: config.outputs,
            supports,
            gates: [gate(GATES[0])?, gate(GATES[1])?, gate(GATES[2])?],
            attention,
            head: (find("head.weight".into())?, find("head.bias".into())?),
        })
    }

    /// A tape sized for this network (the only allocations).
    pub fn tape(&self) -> RecurrentTape {
        let (nh, t) = (self.n * self.h, self.t);
        let z = |len: usize| vec![0f32; len];
        RecurrentTape {
            x: z(t * self.n * self.f),
            r: z(t * nh),
            u: z(t * nh),
            rh: z(t * nh),
            c: z(t * nh),
            states: z(t * nh),
            attention: self.attention.as_ref().map(|_| AttentionTape {
                hidden: z(t * self.h),
                weights: z(t),
                d_states: z(t * nh),
                d_pre: z(self.h),
            }),
            head_input: z(nh),
            out: z(self.o),
            pre: z(nh),
            mixed: z(nh),
            dh: z(nh),
            dh_prev: z(nh),
            dz: z(nh),
            dp: z(nh),
            drh: z(nh),
            du: z(nh),
            h0: z(nh),
        }
    }

    /// `out = act(Σ_k S_k (x·Wx_k + h·Wh_k) + b)` of gate `g`, `pre` and `mixed` scratch.
    #[allow(clippy::too_many_arguments)]
    fn gate(
        &self,
        params: &[Vec<f32>],
        g: usize,
        act: Act,
        (x, h): (&[f32], &[f32]),
        out: &mut [f32],
        pre: &mut [f32],
        mixed: &mut [f32],
    ) {
        let (n, f, hh) = (self.n, self.f, self.h);
        let slots = &self.gates[g];
        for (k, (support, &(wx, wh))) in self.supports.iter().zip(&slots.weights).enumerate() {
            let first = if k == 0 { 0.0 } else { 1.0 };
            // With S_k = I the products go straight into the sum.
            let (target, beta) = match support {
                Some(_) => (&mut *pre, 0.0),
                None => (&mut *mixed, first),
            };
            gemm(
                n,
                f,
                hh,
                rows(x, f),
                rows(&params[wx], hh),
                beta,
                target,
                hh,
            );
            gemm(
                n,
                hh,
                hh,
                rows(h, hh),
                rows(&params[wh], hh),
                1.0,
                target,
                hh,
            );
            if let Some(s) = support {
                gemm(n, n, hh, rows(s, n), rows(pre, hh), first, mixed, hh);
            }
        }
        let bias = &params[slots.bias];
        for ((o, z), b) in out.iter_mut().zip(mixed.iter()).zip(bias.iter().cycle()) {
            let v = z + b;
            *o = match act {
                Act::Sigmoid => sigmoid(v),
                Act::Tanh => tanh(v),
            };
        }
    }

    /// The forward pass of one standardised window `x` `[N, F, T]` into `tape`.
    pub fn forward(&self, params: &[Vec<f32>], x: &[f32], tape: &mut RecurrentTape) {
        let (n, f, t, nh) = (self.n, self.f, self.t, self.n * self.h);
        for (r, row) in x.chunks_exact(t).enumerate() {
            for (step, &v) in row.iter().enumerate() {
                tape.x[step * n * f + r] = v;
            }
        }
        for step in 0..t {
            let span = step * nh..(step + 1) * nh;
            let (done, rest) = tape.states.split_at_mut(step * nh);
            let h_prev: &[f32] = if step == 0 {
                &tape.h0
            } else {
                &done[(step - 1) * nh..]
            };
            let xt = &tape.x[step * n * f..][..n * f];
            let (pre, mixed) = (&mut tape.pre, &mut tape.mixed);
            let r = &mut tape.r[span.clone()];
            self.gate(params, 0, Act::Sigmoid, (xt, h_prev), r, pre, mixed);
            let u = &mut tape.u[span.clone()];
            self.gate(params, 1, Act::Sigmoid, (xt, h_prev), u, pre, mixed);
            let rh = &mut tape.rh[span.clone()];
            for ((o, r), h) in rh.iter_mut().zip(r.iter()).zip(h_prev) {
                *o = r * h;
            }
            let c = &mut tape.c[span.clone()];
            self.gate(params, 2, Act::Tanh, (xt, rh), c, pre, mixed);
            for (((o, u), h), c) in rest[..nh]
                .iter_mut()
                .zip(u.iter())
                .zip(h_prev)
                .zip(c.iter())
            {
                *o = u * h + (1.0 - u) * c;
            }
        }
        match (&self.attention, &mut tape.attention) {
            (Some(slots), Some(a)) => {
                let hh = self.h;
                let (wa, ba, v) = (&params[slots.w], &params[slots.b], &params[slots.v]);
                // hidden = tanh(states·Wa + ba) `[T, A]`, e_t = hidden_t·v.
                gemm(
                    t,
                    nh,
                    hh,
                    rows(&tape.states, nh),
                    rows(wa, hh),
                    0.0,
                    &mut a.hidden,
                    hh,
                );
                for (row, e) in a.hidden.chunks_exact_mut(hh).zip(a.weights.iter_mut()) {
                    for (z, b) in row.iter_mut().zip(ba) {
                        *z = tanh(*z + b);
                    }
                    *e = row.iter().zip(v).map(|(z, v)| z * v).sum();
                }
                softmax_rows(&mut a.weights, t);
                gemm(
                    1,
                    t,
                    nh,
                    rows(&a.weights, t),
                    rows(&tape.states, nh),
                    0.0,
                    &mut tape.head_input,
                    nh,
                );
            }
            _ => tape
                .head_input
                .copy_from_slice(&tape.states[(t - 1) * nh..]),
        }
        flat_head(params, self.head, &tape.head_input, &mut tape.out);
    }

    /// The backward of gate `g` given ∂ℒ/∂(pre-activation) `dz` `[N, H]`: adds the gate's
    /// parameter gradients to `grads`, and S_kᵀ dz·Wh_kᵀ (∂ℒ/∂ its state input) to `dh`.
    /// `dp` is scratch.
    #[allow(clippy::too_many_arguments)]
    fn gate_backward(
        &self,
        params: &[Vec<f32>],
        grads: &mut [Vec<f32>],
        g: usize,
        (x, h): (&[f32], &[f32]),
        dz: &[f32],
        dp: &mut [f32],
        dh: &mut [f32],
    ) {
        let (n, f, hh) = (self.n, self.f, self.h);
        let slots = &self.gates[g];
        for row in dz.chunks_exact(hh) {
            for (db, v) in grads[slots.bias].iter_mut().zip(row) {
                *db += v;
            }
        }
        for (support, &(wx, wh)) in self.supports.iter().zip(&slots.weights) {
            // ∂ℒ/∂(x·Wx_k + h·Wh_k) = S_kᵀ dz (dz itself where S_k = I).
            let d_pre: &[f32] = match support {
                Some(s) => {
                    gemm(n, n, hh, transposed(s, n), rows(dz, hh), 0.0, dp, hh);
                    dp
                }
                None => dz,
            };
            gemm(
                f,
                n,
                hh,
                transposed(x, f),
                rows(d_pre, hh),
                1.0,
                &mut grads[wx],
                hh,
            );
            gemm(
                hh,
                n,
                hh,
                transposed(h, hh),
                rows(d_pre, hh),
                1.0,
                &mut grads[wh],
                hh,
            );
            gemm(
                n,
                hh,
                hh,
                rows(d_pre, hh),
                transposed(&params[wh], hh),
                1.0,
                dh,
                hh,
            );
        }
    }

    /// Adds ∂L/∂ every parameter to `grads` (`param_specs` order) for the upstream
    /// gradient `dout` `[O]` of the window whose forward pass is in `tape`.
    pub fn backward(
        &self,
        params: &[Vec<f32>],
        tape: &mut RecurrentTape,
        dout: &[f32],
        grads: &mut [Vec<f32>],
    ) {
        let (n, f, t, nh) = (self.n, self.f, self.t, self.n * self.h);
        // The head: ∂ℒ/∂(its input) into dh.
        let h = &tape.head_input;
        flat_head_backward(params, self.head, h, dout, grads, &mut tape.dh);
        if let (Some(slots), Some(a)) = (&self.attention, &mut tape.attention) {
            self.attention_backward(params, grads, slots, a, &tape.states, &tape.dh);
            tape.dh.fill(0.0);
        }
        for step in (0..t).rev() {
            let span = step * nh..(step + 1) * nh;
            let h_prev: &[f32] = if step == 0 {
                &tape.h0
            } else {
                &tape.states[(step - 1) * nh..step * nh]
            };
            if let Some(a) = &tape.attention {
                for (d, v) in tape.dh.iter_mut().zip(&a.d_states[span.clone()]) {
                    *d += v;
                }
            }
            let (r, u, c) = (
                &tape.r[span.clone()],
                &tape.u[span.clone()],
                &tape.c[span.clone()],
            );
            let (rh, xt) = (&tape.rh[span.clone()], &tape.x[step * n * f..][..n * f]);
            // h' = u ⊙ h + (1 − u) ⊙ c.
            for i in 0..nh {
                let d = tape.dh[i];
                tape.dh_prev[i] = u[i] * d;
                tape.du[i] = (h_prev[i] - c[i]) * d;
                tape.dz[i] = (1.0 - u[i]) * d * (1.0 - c[i] * c[i]);
            }
            tape.drh.fill(0.0);
            self.gate_backward(
                params,
                grads,
                2,
                (xt, rh),
                &tape.dz,
                &mut tape.dp,
                &mut tape.drh,
            );
            for i in 0..nh {
                tape.dh_prev[i] += tape.drh[i] * r[i];
                tape.dz[i] = tape.drh[i] * h_prev[i] * r[i] * (1.0 - r[i]);
            }
            let (dz, dp, dh_prev) = (&mut tape.dz, &mut tape.dp, &mut tape.dh_prev);
            self.gate_backward(params, grads, 0, (xt, h_prev), dz, dp, dh_prev);
            for ((z, du), u) in dz.iter_mut().zip(&tape.du).zip(u) {
                *z = du * u * (1.0 - u);
            }
            self.gate_backward(params, grads, 1, (xt, h_prev), dz, dp, dh_prev);
            std::mem::swap(&mut tape.dh, &mut tape.dh_prev);
        }
    }

    /// EAT-GCN's attention backward from ∂ℒ/∂context `dc` `[N·H]`: adds the gradients of
    /// Wa, ba and v, and writes ∂ℒ/∂h_t of every step into `a.d_states`.
    fn attention_backward(
        &self,
        params: &[Vec<f32>],
        grads: &mut [Vec<f32>],
        slots: &AttentionSlots,
        a: &mut AttentionTape,
        states: &[f32],
        dc: &[f32],
    ) {
        let (t, hh, nh) = (self.t, self.h, self.n * self.h);
        let (wa, v) = (&params[slots.w], &params[slots.v]);
        // ∂ℒ/∂α_t = h_t·dc, then through the softmax over t: ∂ℒ/∂e_t = α_t(∂α_t − Σ α ∂α).
        let da: Vec<f32> = states
            .chunks_exact(nh)
            .map(|h| h.iter().zip(dc).map(|(h, d)| h * d).sum())
            .collect();
        let mean: f32 = da.iter().zip(&a.weights).map(|(d, w)| d * w).sum();
        for step in 0..t {
            let (alpha, e) = (a.weights[step], a.weights[step] * (da[step] - mean));
            let d_state = &mut a.d_states[step * nh..][..nh];
            for (d, c) in d_state.iter_mut().zip(dc) {
                *d = alpha * c;
            }
            let z = &a.hidden[step * hh..][..hh];
            // ∂ℒ/∂(h_t·Wa + ba) = e' v ⊙ (1 − z²).
            for ((p, v), z) in a.d_pre.iter_mut().zip(v).zip(z) {
                *p = e * v * (1.0 - z * z);
            }
            for (dv, z) in grads[slots.v].iter_mut().zip(z) {
                *dv += e * z;
            }
            for (db, p) in grads[slots.b].iter_mut().zip(&a.d_pre) {
                *db += p;
            }
            let h = &states[step * nh..][..nh];
            gemm(
                nh,
                1,
                hh,
                transposed(h, nh),
                rows(&a.d_pre, hh),
                1.0,
                &mut grads[slots.w],
                hh,
            );
            gemm(
                1,
                hh,
                nh,
                rows(&a.d_pre, hh),
                transposed(wa, hh),
                1.0,
                d_state,
                nh,
            );
        }
    }
}
