//! The recurrent baselines T-GCN and EAT-GCN (`model::recurrent`, docs/model.md
//! "Baselines") on the CPU in f32, for B windows at a time (one in inference, up to 32
//! of a training step's): the GRU whose gates are graph convolutions, run over the
//! windows' T steps, EAT-GCN's attention over time, the head, and backpropagation through
//! time by hand — the arithmetic of the f64 reference `model::recurrent::reference`. Per
//! step t, with x_t `[N, F]` of each window:
//!
//! ```text
//! gate(x, h) = Σ_k S_k (x·Wx_k + h·Wh_k) + b
//! r = σ(gate_r(x_t, h))   u = σ(gate_u(x_t, h))   c = tanh(gate_c(x_t, r ⊙ h))
//! h' = u ⊙ h + (1 − u) ⊙ c
//! ```
//!
//! Every contraction is a `gemm` product (`model::cpu::gemm`) on row-major slices, for all B
//! windows at once: the per-step arrays are laid out `[N, B, ·]`, so that x_t·Wx and
//! h·Wh are products of N·B rows and S_k·P one `[N, N]·[N, B·H]` product (one window's
//! N = 14 rows leave the products too thin to pay for their calls and packing). S_k = I
//! (T_0 of EAT-GCN's Chebyshev supports) skips its graph mix, as on the device. The models
//! have no dropout, so training and inference share the forward pass.

use crate::graph::Graph;
use crate::model::config::ModelConfig;
use crate::model::cpu::{gemm, rows, sigmoid, softmax_rows, tanh, transposed};
use crate::model::error::ModelError;
use crate::model::head::native::{backward_rows, forward_rows};
use crate::model::params::ParamSpec;
use crate::model::recurrent::{attends_over_time, support_count, supports, weight_name, GATES};
use multiversion::multiversion;

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
pub(crate) struct RecurrentNet {
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
    /// The window's states h_t gathered step-major `[T, N·H]`.
    states: Vec<f32>,
    /// tanh(h_t·Wa + ba) `[T, A]`.
    hidden: Vec<f32>,
    /// α = softmax_t(e) `[T]` (first the scores e).
    weights: Vec<f32>,
    /// ∂ℒ/∂h_t from the attention `[T, N·H]` (backward only).
    d_states: Vec<f32>,
    /// Backward scratch: ∂ℒ/∂α `[T]` and ∂ℒ/∂(h_t·Wa + ba) `[T, A]`.
    d_weights: Vec<f32>,
    d_pre: Vec<f32>,
}

/// The forward values and the backward pass's working memory of up to `capacity`
/// windows, run together: every per-step array is laid out node-major `[N, B, ·]` for
/// the B windows of the last forward pass, so that x_t·Wx and h·Wh are one product of
/// N·B rows and the graph mix S_k·(…) one product `[N, N]·[N, B·H]`, for all windows.
pub(crate) struct RecurrentTape {
    capacity: usize,
    /// Windows of the last forward pass.
    windows: usize,
    /// x_t of every step `[T, N, B, F]`.
    x: Vec<f32>,
    /// Gates, r ⊙ h_prev and the states of every step, each `[T, N, B, H]`.
    r: Vec<f32>,
    u: Vec<f32>,
    rh: Vec<f32>,
    c: Vec<f32>,
    states: Vec<f32>,
    /// One per window.
    attention: Vec<AttentionTape>,
    /// What the head reads, per window `[B, N·H]`: the last state or the context
    /// Σ_t α_t h_t.
    head_input: Vec<f32>,
    /// ŷ `[B, O]`.
    out: Vec<f32>,
    /// ∂ℒ/∂(the head's input) of one window `[N·H]`.
    d_head: Vec<f32>,
    /// `[N, B, H]` scratch: one support's products, the gate's sum; in the backward pass
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
    /// ŷ `[B, O]` of the last forward pass.
    pub fn output(&self) -> &[f32] {
        let outputs = self.out.len() / self.capacity;
        &self.out[..self.windows * outputs]
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

    /// A tape for up to `capacity` windows at a time (the only allocations).
    pub fn tape(&self, capacity: usize) -> RecurrentTape {
        let capacity = capacity.max(1);
        let (nh, t) = (self.n * self.h, self.t);
        let nbh = nh * capacity;
        let z = |len: usize| vec![0f32; len];
        RecurrentTape {
            capacity,
            windows: 0,
            x: z(t * self.n * capacity * self.f),
            r: z(t * nbh),
            u: z(t * nbh),
            rh: z(t * nbh),
            c: z(t * nbh),
            states: z(t * nbh),
            attention: match &self.attention {
                Some(_) => (0..capacity)
                    .map(|_| AttentionTape {
                        states: z(t * nh),
                        hidden: z(t * self.h),
                        weights: z(t),
                        d_states: z(t * nh),
                        d_weights: z(t),
                        d_pre: z(t * self.h),
                    })
                    .collect(),
                None => Vec::new(),
            },
            head_input: z(capacity * nh),
            out: z(capacity * self.o),
            d_head: z(nh),
            pre: z(nbh),
            mixed: z(nbh),
            dh: z(nbh),
            dh_prev: z(nbh),
            dz: z(nbh),
            dp: z(nbh),
            drh: z(nbh),
            du: z(nbh),
            h0: z(nbh),
        }
    }

    /// `out = act(Σ_k S_k (x·Wx_k + h·Wh_k) + b)` of gate `g` for `b` windows laid out
    /// `[N, b, ·]`, `pre` and `mixed` scratch.
    #[allow(clippy::too_many_arguments)]
    #[inline(always)]
    fn gate(
        &self,
        params: &[Vec<f32>],
        g: usize,
        act: Act,
        b: usize,
        (x, h): (&[f32], &[f32]),
        out: &mut [f32],
        pre: &mut [f32],
        mixed: &mut [f32],
    ) {
        let (n, f, hh) = (self.n, self.f, self.h);
        let (m, bh) = (n * b, b * hh);
        let slots = &self.gates[g];
        for (k, (support, &(wx, wh))) in self.supports.iter().zip(&slots.weights).enumerate() {
            let first = if k == 0 { 0.0 } else { 1.0 };
            // With S_k = I the products go straight into the sum.
            let (target, beta) = match support {
                Some(_) => (&mut *pre, 0.0),
                None => (&mut *mixed, first),
            };
            gemm(
                m,
                f,
                hh,
                rows(x, f),
                rows(&params[wx], hh),
                beta,
                target,
                hh,
            );
            gemm(
                m,
                hh,
                hh,
                rows(h, hh),
                rows(&params[wh], hh),
                1.0,
                target,
                hh,
            );
            if let Some(s) = support {
                gemm(n, n, bh, rows(s, n), rows(pre, bh), first, mixed, bh);
            }
        }
        // Row by row, with the activation chosen outside the loop, so that it vectorises.
        let bias = &params[slots.bias];
        let rows_of = |out: &mut [f32], f: fn(f32) -> f32| {
            for (o_row, z_row) in out.chunks_exact_mut(hh).zip(mixed.chunks_exact(hh)) {
                for ((o, z), b) in o_row.iter_mut().zip(z_row).zip(bias) {
                    *o = f(z + b);
                }
            }
        };
        match act {
            Act::Sigmoid => rows_of(&mut out[..m * hh], sigmoid),
            Act::Tanh => rows_of(&mut out[..m * hh], tanh),
        }
    }

    /// The forward pass of the standardised windows `x` `[B, N, F, T]` (B at most the
    /// tape's capacity) into `tape`.
    pub fn forward(&self, params: &[Vec<f32>], x: &[f32], tape: &mut RecurrentTape) {
        forward_windows(self, params, x, tape)
    }

    /// Adds ∂L/∂ every parameter to `grads` (`param_specs` order) for the upstream
    /// gradient `dout` `[B, O]` of the windows whose forward pass is in `tape`.
    pub fn backward(
        &self,
        params: &[Vec<f32>],
        tape: &mut RecurrentTape,
        dout: &[f32],
        grads: &mut [Vec<f32>],
    ) {
        backward_windows(self, params, tape, dout, grads)
    }

    /// [`RecurrentNet::forward`]'s body.
    #[inline(always)]
    fn forward_body(&self, params: &[Vec<f32>], x: &[f32], tape: &mut RecurrentTape) {
        let (n, f, t, hh, nh) = (self.n, self.f, self.t, self.h, self.n * self.h);
        let b = x.len() / (n * f * t);
        assert!(
            b >= 1 && b * n * f * t == x.len() && b <= tape.capacity,
            "{} floats are not 1 to {} windows",
            x.len(),
            tape.capacity
        );
        tape.windows = b;
        let nbh = nh * b;
        // x `[B, N, F, T]` → x_t `[T, N, B, F]`.
        for (row_index, row) in x.chunks_exact(t).enumerate() {
            let (window, node, feature) = (row_index / (n * f), row_index / f % n, row_index % f);
            let at = (node * b + window) * f + feature;
            for (step, &v) in row.iter().enumerate() {
                tape.x[step * n * b * f + at] = v;
            }
        }
        for step in 0..t {
            let span = step * nbh..(step + 1) * nbh;
            let (done, rest) = tape.states.split_at_mut(step * nbh);
            let h_prev: &[f32] = if step == 0 {
                &tape.h0[..nbh]
            } else {
                &done[(step - 1) * nbh..]
            };
            let xt = &tape.x[step * n * b * f..][..n * b * f];
            let (pre, mixed) = (&mut tape.pre, &mut tape.mixed);
            let r = &mut tape.r[span.clone()];
            self.gate(params, 0, Act::Sigmoid, b, (xt, h_prev), r, pre, mixed);
            let u = &mut tape.u[span.clone()];
            self.gate(params, 1, Act::Sigmoid, b, (xt, h_prev), u, pre, mixed);
            let rh = &mut tape.rh[span.clone()];
            for ((o, r), h) in rh.iter_mut().zip(r.iter()).zip(h_prev) {
                *o = r * h;
            }
            let c = &mut tape.c[span.clone()];
            self.gate(params, 2, Act::Tanh, b, (xt, rh), c, pre, mixed);
            for (((o, u), h), c) in rest[..nbh]
                .iter_mut()
                .zip(u.iter())
                .zip(h_prev)
                .zip(c.iter())
            {
                *o = u * h + (1.0 - u) * c;
            }
        }
        // Window w's state at a step is rows (node, w) of `[N, B, H]`.
        let gather = |states: &[f32], w: usize, into: &mut [f32]| {
            for (node, dst) in into.chunks_exact_mut(hh).enumerate() {
                dst.copy_from_slice(&states[(node * b + w) * hh..][..hh]);
            }
        };
        for w in 0..b {
            let head_input = &mut tape.head_input[w * nh..][..nh];
            match (&self.attention, tape.attention.get_mut(w)) {
                (Some(slots), Some(a)) => {
                    for (step, into) in a.states.chunks_exact_mut(nh).enumerate() {
                        gather(&tape.states[step * nbh..][..nbh], w, into);
                    }
                    self.attention_forward(params, slots, a, head_input);
                }
                _ => gather(&tape.states[(t - 1) * nbh..], w, head_input),
            }
            let out = &mut tape.out[w * self.o..][..self.o];
            forward_rows(params, self.head, head_input, out);
        }
    }

    /// EAT-GCN's attention over one window's states `a.states`: the context into `context`.
    fn attention_forward(
        &self,
        params: &[Vec<f32>],
        slots: &AttentionSlots,
        a: &mut AttentionTape,
        context: &mut [f32],
    ) {
        let (t, hh, nh) = (self.t, self.h, self.n * self.h);
        let (wa, ba, v) = (&params[slots.w], &params[slots.b], &params[slots.v]);
        // hidden = tanh(states·Wa + ba) `[T, A]`, e_t = hidden_t·v.
        gemm(
            t,
            nh,
            hh,
            rows(&a.states, nh),
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
            rows(&a.states, nh),
            0.0,
            context,
            nh,
        );
    }

    /// The backward of gate `g` for `b` windows given ∂ℒ/∂(pre-activation) `dz`
    /// `[N, b, H]`: adds the gate's parameter gradients to `grads`, and S_kᵀ dz·Wh_kᵀ
    /// (∂ℒ/∂ its state input) to `dh`. `dp` is scratch.
    #[allow(clippy::too_many_arguments)]
    #[inline(always)]
    fn gate_backward(
        &self,
        params: &[Vec<f32>],
        grads: &mut [Vec<f32>],
        g: usize,
        b: usize,
        (x, h): (&[f32], &[f32]),
        dz: &[f32],
        dp: &mut [f32],
        dh: &mut [f32],
    ) {
        let (n, f, hh) = (self.n, self.f, self.h);
        let (m, bh) = (n * b, b * hh);
        let slots = &self.gates[g];
        for row in dz[..m * hh].chunks_exact(hh) {
            for (db, v) in grads[slots.bias].iter_mut().zip(row) {
                *db += v;
            }
        }
        for (support, &(wx, wh)) in self.supports.iter().zip(&slots.weights) {
            // ∂ℒ/∂(x·Wx_k + h·Wh_k) = S_kᵀ dz (dz itself where S_k = I).
            let d_pre: &[f32] = match support {
                Some(s) => {
                    gemm(n, n, bh, transposed(s, n), rows(dz, bh), 0.0, dp, bh);
                    dp
                }
                None => dz,
            };
            gemm(
                f,
                m,
                hh,
                transposed(x, f),
                rows(d_pre, hh),
                1.0,
                &mut grads[wx],
                hh,
            );
            gemm(
                hh,
                m,
                hh,
                transposed(h, hh),
                rows(d_pre, hh),
                1.0,
                &mut grads[wh],
                hh,
            );
            gemm(
                m,
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

    /// [`RecurrentNet::backward`]'s body.
    #[inline(always)]
    fn backward_body(
        &self,
        params: &[Vec<f32>],
        tape: &mut RecurrentTape,
        dout: &[f32],
        grads: &mut [Vec<f32>],
    ) {
        let (n, f, t, hh, nh) = (self.n, self.f, self.t, self.h, self.n * self.h);
        let b = tape.windows;
        assert_eq!(dout.len(), b * self.o, "∂ℒ/∂ŷ of every window");
        let nbh = nh * b;
        // The head (and EAT-GCN's attention): ∂ℒ/∂ the last state into dh.
        tape.dh[..nbh].fill(0.0);
        for w in 0..b {
            let head_input = &tape.head_input[w * nh..][..nh];
            let dout = &dout[w * self.o..][..self.o];
            backward_rows(params, self.head, head_input, dout, grads, &mut tape.d_head);
            match (&self.attention, tape.attention.get_mut(w)) {
                (Some(slots), Some(a)) => {
                    self.attention_backward(params, grads, slots, a, &tape.d_head)
                }
                _ => {
                    for (node, d) in tape.d_head.chunks_exact(hh).enumerate() {
                        tape.dh[(node * b + w) * hh..][..hh].copy_from_slice(d);
                    }
                }
            }
        }
        for step in (0..t).rev() {
            let span = step * nbh..(step + 1) * nbh;
            let h_prev: &[f32] = if step == 0 {
                &tape.h0[..nbh]
            } else {
                &tape.states[(step - 1) * nbh..step * nbh]
            };
            for (w, a) in tape.attention.iter().take(b).enumerate() {
                let d_state = &a.d_states[step * nh..][..nh];
                for (node, d) in d_state.chunks_exact(hh).enumerate() {
                    let dh = &mut tape.dh[(node * b + w) * hh..][..hh];
                    for (dh, d) in dh.iter_mut().zip(d) {
                        *dh += d;
                    }
                }
            }
            let (r, u, c) = (
                &tape.r[span.clone()],
                &tape.u[span.clone()],
                &tape.c[span.clone()],
            );
            let (rh, xt) = (
                &tape.rh[span.clone()],
                &tape.x[step * n * b * f..][..n * b * f],
            );
            // h' = u ⊙ h + (1 − u) ⊙ c.
            for ((((((d, dh_prev), du), dz), u), h), c) in tape.dh[..nbh]
                .iter()
                .zip(&mut tape.dh_prev[..nbh])
                .zip(&mut tape.du[..nbh])
                .zip(&mut tape.dz[..nbh])
                .zip(u)
                .zip(h_prev)
                .zip(c)
            {
                *dh_prev = u * d;
                *du = (h - c) * d;
                *dz = (1.0 - u) * d * (1.0 - c * c);
            }
            tape.drh[..nbh].fill(0.0);
            self.gate_backward(
                params,
                grads,
                2,
                b,
                (xt, rh),
                &tape.dz,
                &mut tape.dp,
                &mut tape.drh,
            );
            for ((((dh_prev, dz), drh), r), h) in tape.dh_prev[..nbh]
                .iter_mut()
                .zip(&mut tape.dz[..nbh])
                .zip(&tape.drh[..nbh])
                .zip(r)
                .zip(h_prev)
            {
                *dh_prev += drh * r;
                *dz = drh * h * r * (1.0 - r);
            }
            let (dz, dp, dh_prev) = (&mut tape.dz, &mut tape.dp, &mut tape.dh_prev);
            self.gate_backward(params, grads, 0, b, (xt, h_prev), dz, dp, dh_prev);
            for ((z, du), u) in dz[..nbh].iter_mut().zip(&tape.du[..nbh]).zip(u) {
                *z = du * u * (1.0 - u);
            }
            self.gate_backward(params, grads, 1, b, (xt, h_prev), dz, dp, dh_prev);
            std::mem::swap(&mut tape.dh, &mut tape.dh_prev);
        }
    }

    /// EAT-GCN's attention backward of one window from ∂ℒ/∂context `dc` `[N·H]`: adds
    /// the gradients of Wa, ba and v, and writes ∂ℒ/∂h_t of every step into
    /// `a.d_states`.
    fn attention_backward(
        &self,
        params: &[Vec<f32>],
        grads: &mut [Vec<f32>],
        slots: &AttentionSlots,
        a: &mut AttentionTape,
        dc: &[f32],
    ) {
        let (t, hh, nh) = (self.t, self.h, self.n * self.h);
        let (wa, v) = (&params[slots.w], &params[slots.v]);
        let states = &a.states;
        // ∂ℒ/∂α_t = h_t·dc, then through the softmax over t: ∂ℒ/∂e_t = α_t(∂α_t − Σ α ∂α).
        for (da, h) in a.d_weights.iter_mut().zip(states.chunks_exact(nh)) {
            *da = h.iter().zip(dc).map(|(h, d)| h * d).sum();
        }
        let mean: f32 = a.d_weights.iter().zip(&a.weights).map(|(d, w)| d * w).sum();
        for step in 0..t {
            let (alpha, e) = (
                a.weights[step],
                a.weights[step] * (a.d_weights[step] - mean),
            );
            for (d, c) in a.d_states[step * nh..][..nh].iter_mut().zip(dc) {
                *d = alpha * c;
            }
            let z = &a.hidden[step * hh..][..hh];
            // ∂ℒ/∂(h_t·Wa + ba) = e' v ⊙ (1 − z²).
            for ((p, v), z) in a.d_pre[step * hh..][..hh].iter_mut().zip(v).zip(z) {
                *p = e * v * (1.0 - z * z);
            }
            for (dv, z) in grads[slots.v].iter_mut().zip(z) {
                *dv += e * z;
            }
        }
        for row in a.d_pre.chunks_exact(hh) {
            for (db, p) in grads[slots.b].iter_mut().zip(row) {
                *db += p;
            }
        }
        // Over all steps at once: ∂ℒ/∂Wa += Σ_t h_tᵀ·d_pre_t, ∂ℒ/∂h_t += d_pre_t·Waᵀ.
        gemm(
            nh,
            t,
            hh,
            transposed(states, nh),
            rows(&a.d_pre, hh),
            1.0,
            &mut grads[slots.w],
            hh,
        );
        gemm(
            t,
            hh,
            nh,
            rows(&a.d_pre, hh),
            transposed(wa, hh),
            1.0,
            &mut a.d_states,
            nh,
        );
    }
}

/// The forward pass compiled for AVX-512 and AVX2/FMA besides baseline x86-64, chosen at
/// the first call, so that the gates' activations and the GRU's elementwise steps run
/// at the machine's vector width.
#[multiversion(targets("x86_64+avx512f", "x86_64+avx2+fma"))]
fn forward_windows(net: &RecurrentNet, params: &[Vec<f32>], x: &[f32], tape: &mut RecurrentTape) {
    net.forward_body(params, x, tape)
}

/// The backward pass, compiled as [`forward_windows`] is.
#[multiversion(targets("x86_64+avx512f", "x86_64+avx2+fma"))]
fn backward_windows(
    net: &RecurrentNet,
    params: &[Vec<f32>],
    tape: &mut RecurrentTape,
    dout: &[f32],
    grads: &mut [Vec<f32>],
) {
    net.backward_body(params, tape, dout, grads)
}
