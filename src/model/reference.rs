//! The f64 CPU reference of the whole network of docs/model.md: the forward pass (keeping every
//! intermediate on a [`Tape`]), the loss of eq. 39 and a hand-written backward pass. Tests
//! check the backward against finite differences of the forward, and the GPU schedule
//! against both.
//!
//! One function per docs/model.md step, its backward next to it. Tensors are row-major
//! `[B, N, C, T]` like the GPU's; loops keep the contiguous T axis innermost (as `axpy` /
//! `dot` over rows of length T) so that the paper shape runs in seconds at opt-level 1.

// The loops index several tensors by the equations' indices at once.
#![allow(clippy::needless_range_loop)]

use super::{ModelConfig, ParamSpec};
use crate::ops::dropout::{keep, Dropout};

/// The dropout of one training step (docs/model.md step 7). Block `l` draws its mask from
/// [`DropoutStep::block`]: element `i` (flat index into Y `[B,N,C,T]`) is kept iff
/// `ops::dropout::keep(&mask, step, i)`, and kept values are scaled by 1/(1−p).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct DropoutStep {
    pub seed: u32,
    pub step: u32,
}

impl DropoutStep {
    /// The mask generator of block `l`: seed + l, p = `config.dropout`.
    pub fn block(&self, config: &ModelConfig, batch: usize, l: usize) -> Dropout {
        Dropout::new(
            batch * config.nodes * config.channels * config.window,
            config.dropout,
            self.seed.wrapping_add(l as u32),
        )
    }
}

/// The weights of the loss (eq. 39).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Loss {
    /// P: weight of the attitude outputs (m ≥ 3) against the position ones.
    pub attitude_penalty: f64,
    /// λ: weight of Σ‖W‖² over the parameters with `spec.decay`.
    pub weight_decay: f64,
}

impl Default for Loss {
    /// docs/model.md's defaults: P = 1, λ = 1e-4.
    fn default() -> Loss {
        Loss {
            attitude_penalty: 1.0,
            weight_decay: 1e-4,
        }
    }
}

/// Everything the forward pass computed, as the backward pass (and step-by-step GPU
/// comparisons) need it.
#[derive(Clone, Debug)]
pub struct Tape {
    pub batch: usize,
    /// The network input x `[B,N,F,T]`.
    pub input: Vec<f64>,
    pub blocks: Vec<BlockTape>,
    /// ŷ `[B,O]`.
    pub output: Vec<f64>,
}

/// One ST block's intermediates. Its input is the previous block's `output` (or
/// [`Tape::input`] for block 0).
#[derive(Clone, Debug)]
pub struct BlockTape {
    /// Step 1 (absent in `iastgcn-a`).
    pub temporal: Option<TemporalAttention>,
    /// Step 2 (absent in `iastgcn-a`).
    pub spatial: Option<SpatialAttention>,
    /// Step 3: Ψ = Σ_k θ_k basis_k `[N,N]`.
    pub psi: Vec<f64>,
    /// Step 3: Q[b,j,o,t] = Σ_c X_s[b,j,c,t]·W[c,o] `[B,N,C,T]` (before the node mixing).
    pub q: Vec<f64>,
    /// Step 3: Z = ReLU(Ψ·Q) `[B,N,C,T]`.
    pub z: Vec<f64>,
    /// Step 4: G_f `[B,N,C,T]` (in `iastgcn-t` the pre-ReLU plain convolution).
    pub filter: Vec<f64>,
    /// Step 4: G_g `[B,N,C,T]` (absent in `iastgcn-t`).
    pub gate: Option<Vec<f64>>,
    /// Step 6: ReLU(H + R) `[B,N,C,T]`, the LayerNorm input.
    pub act: Vec<f64>,
    /// Step 6: LayerNorm mean and 1/√(var + ε) per (b,n,t), `[B,N,T]`.
    pub mean: Vec<f64>,
    pub rstd: Vec<f64>,
    /// Step 7: the dropout mask (`None` without dropout).
    pub mask: Option<Vec<bool>>,
    /// The block output Y after dropout `[B,N,C,T]`.
    pub output: Vec<f64>,
}

/// Step 1 intermediates (eq. 35–37).
#[derive(Clone, Debug)]
pub struct TemporalAttention {
    /// Σ_n X[b,n,c,t]·U1[n], stored `[B,C_in,T]`.
    pub xu1: Vec<f64>,
    /// lhs `[B,T,N]`.
    pub lhs: Vec<f64>,
    /// rhs `[B,N,T]`.
    pub rhs: Vec<f64>,
    /// σ(P + be) `[B,T,T]`.
    pub sig: Vec<f64>,
    /// E = Ve·σ(P + be) `[B,T,T]`.
    pub scores: Vec<f64>,
    /// E' = softmax of E over its first time index `[B,T,T]`.
    pub weights: Vec<f64>,
    /// X_t `[B,N,C_in,T]`.
    pub output: Vec<f64>,
}

/// Step 2 intermediates (eq. 32–34).
#[derive(Clone, Debug)]
pub struct SpatialAttention {
    /// Σ_u X_t[b,n,c,u]·W1[u] `[B,N,C_in]`.
    pub xw1: Vec<f64>,
    /// lhs `[B,N,T]`.
    pub lhs: Vec<f64>,
    /// rhs, stored transposed as `[B,N,T]` (rhs[b,t,m] of docs/model.md at `[b,m,t]`).
    pub rhs: Vec<f64>,
    /// σ(P + bs) `[B,N,N]`.
    pub sig: Vec<f64>,
    /// S = Vs·σ(P + bs) `[B,N,N]`.
    pub scores: Vec<f64>,
    /// S' = softmax of S over j `[B,N,N]`.
    pub weights: Vec<f64>,
    /// X_s `[B,N,C_in,T]`.
    pub output: Vec<f64>,
}

impl Tape {
    /// The on/off state of every ReLU of the forward pass (step 3, step 6, and the plain
    /// convolution of `iastgcn-t`). A finite difference whose two evaluations change this
    /// pattern straddles a kink and is not a derivative.
    pub fn relu_pattern(&self) -> Vec<bool> {
        let mut out = Vec::new();
        for b in &self.blocks {
            out.extend(b.z.iter().map(|&v| v > 0.0));
            if b.gate.is_none() {
                out.extend(b.filter.iter().map(|&v| v > 0.0));
            }
            out.extend(b.act.iter().map(|&v| v > 0.0));
        }
        out
    }
}

// ---------------------------------------------------------------------------------------
// Small helpers.

/// y += a·x over the common length.
#[inline]
fn axpy(y: &mut [f64], a: f64, x: &[f64]) {
    for (y, x) in y.iter_mut().zip(x) {
        *y += a * x;
    }
}

#[inline]
fn dot(a: &[f64], b: &[f64]) -> f64 {
    a.iter().zip(b).map(|(a, b)| a * b).sum()
}

#[inline]
fn sigmoid(x: f64) -> f64 {
    1.0 / (1.0 + (-x).exp())
}

/// Row `r` of length `len` of a row-major buffer.
#[inline]
fn row(x: &[f64], r: usize, len: usize) -> &[f64] {
    &x[r * len..(r + 1) * len]
}

#[inline]
fn row_mut(x: &mut [f64], r: usize, len: usize) -> &mut [f64] {
    &mut x[r * len..(r + 1) * len]
}

/// Shapes of block `l`.
#[derive(Clone, Copy, Debug)]
struct Dims {
    b: usize,
    n: usize,
    /// C_in.
    ci: usize,
    c: usize,
    t: usize,
}

impl Dims {
    fn new(config: &ModelConfig, batch: usize, l: usize) -> Dims {
        Dims {
            b: batch,
            n: config.nodes,
            ci: config.block_input(l),
            c: config.channels,
            t: config.window,
        }
    }

    /// Index of the T-row (b, n, c) of a `[B,N,ch,T]` tensor.
    #[inline]
    fn r(&self, ch: usize, b: usize, n: usize, c: usize) -> usize {
        (b * self.n + n) * ch + c
    }
}

/// Parameters looked up by name (docs/model.md names, `param_specs` order).
struct Table<'a> {
    specs: &'a [ParamSpec],
    values: &'a [Vec<f64>],
}

impl<'a> Table<'a> {
    fn new(specs: &'a [ParamSpec], values: &'a [Vec<f64>]) -> Table<'a> {
        assert_eq!(specs.len(), values.len(), "one value tensor per spec");
        for (s, v) in specs.iter().zip(values) {
            assert_eq!(
                v.len(),
                s.numel(),
                "parameter {} has the wrong size",
                s.name
            );
        }
        Table { specs, values }
    }

    fn get(&self, name: &str) -> &'a [f64] {
        &self.values[index(self.specs, name)]
    }
}

fn index(specs: &[ParamSpec], name: &str) -> usize {
    specs
        .iter()
        .position(|s| s.name == name)
        .unwrap_or_else(|| panic!("no parameter named {name}"))
}

/// Gradients in spec order, accumulated by name.
struct Grads<'a> {
    specs: &'a [ParamSpec],
    values: Vec<Vec<f64>>,
}

impl Grads<'_> {
    fn add(&mut self, name: &str, g: &[f64]) {
        let slot = &mut self.values[index(self.specs, name)];
        assert_eq!(slot.len(), g.len(), "gradient of {name} has the wrong size");
        axpy(slot, 1.0, g);
    }
}

struct TemporalParams<'a> {
    u1: &'a [f64],
    u2: &'a [f64],
    u3: &'a [f64],
    be: &'a [f64],
    ve: &'a [f64],
}

struct SpatialParams<'a> {
    w1: &'a [f64],
    w2: &'a [f64],
    w3: &'a [f64],
    bs: &'a [f64],
    vs: &'a [f64],
}

/// The parameters of block `l`.
struct BlockParams<'a> {
    prefix: String,
    temporal: Option<TemporalParams<'a>>,
    spatial: Option<SpatialParams<'a>>,
    theta: &'a [f64],
    w: &'a [f64],
    filter_weight: &'a [f64],
    filter_bias: &'a [f64],
    /// (weight, bias) of the gate; `None` in `iastgcn-t`.
    gate: Option<(&'a [f64], &'a [f64])>,
    res_weight: &'a [f64],
    res_bias: &'a [f64],
    gamma: &'a [f64],
    beta: &'a [f64],
}

impl<'a> BlockParams<'a> {
    fn new(table: &Table<'a>, config: &ModelConfig, l: usize) -> BlockParams<'a> {
        let prefix = format!("blocks.{l}");
        let p = |s: &str| table.get(&format!("{prefix}.{s}"));
        let attention = config.variant.attention();
        BlockParams {
            temporal: attention.then(|| TemporalParams {
                u1: p("tat.U1"),
                u2: p("tat.U2"),
                u3: p("tat.U3"),
                be: p("tat.be"),
                ve: p("tat.Ve"),
            }),
            spatial: attention.then(|| SpatialParams {
                w1: p("sat.W1"),
                w2: p("sat.W2"),
                w3: p("sat.W3"),
                bs: p("sat.bs"),
                vs: p("sat.Vs"),
            }),
            theta: p("gwc.theta"),
            w: p("gwc.W"),
            filter_weight: p("tcn.filter.weight"),
            filter_bias: p("tcn.filter.bias"),
            gate: config
                .variant
                .gated()
                .then(|| (p("tcn.gate.weight"), p("tcn.gate.bias"))),
            res_weight: p("res.weight"),
            res_bias: p("res.bias"),
            gamma: p("ln.gamma"),
            beta: p("ln.beta"),
            prefix,
        }
    }

    fn name(&self, s: &str) -> String {
        format!("{}.{s}", self.prefix)
    }
}

// ---------------------------------------------------------------------------------------
// Softmaxes of the attention steps.

/// Backward of the attention scores `S[b] = V · σ(P[b] + bias)` (`[len, len]` per batch
/// item, both attentions): returns (dV, dP, dbias) from dS and the saved σ.
fn score_gate_backward(
    v: &[f64],
    sig: &[f64],
    dscores: &[f64],
    nb: usize,
    len: usize,
) -> (Vec<f64>, Vec<f64>, Vec<f64>) {
    let mut dv = vec![0.0; len * len];
    let mut dpre = vec![0.0; nb * len * len];
    for b in 0..nb {
        for i in 0..len {
            let dr = row(dscores, b * len + i, len);
            for k in 0..len {
                dv[i * len + k] += dot(dr, row(sig, b * len + k, len));
                axpy(row_mut(&mut dpre, b * len + k, len), v[i * len + k], dr);
            }
        }
    }
    let mut dbias = vec![0.0; len * len];
    for (dm, sm) in dpre
        .chunks_exact_mut(len * len)
        .zip(sig.chunks_exact(len * len))
    {
        for ((g, s), db) in dm.iter_mut().zip(sm).zip(dbias.iter_mut()) {
            *g *= s * (1.0 - s);
            *db += *g;
        }
    }
    (dv, dpre, dbias)
}

/// Softmax over the first index of each `[T,T]` matrix (columns sum to one, step 1).
fn softmax_columns(e: &[f64], nb: usize, nt: usize) -> Vec<f64> {
    let mut w = e.to_vec();
    for m in w.chunks_exact_mut(nt * nt).take(nb) {
        let mut max = vec![f64::NEG_INFINITY; nt];
        for r in m.chunks_exact(nt) {
            for (mx, &v) in max.iter_mut().zip(r) {
                *mx = mx.max(v);
            }
        }
        let mut sum = vec![0.0; nt];
        for r in m.chunks_exact_mut(nt) {
            for ((v, mx), s) in r.iter_mut().zip(&max).zip(sum.iter_mut()) {
                *v = (*v - mx).exp();
                *s += *v;
            }
        }
        for r in m.chunks_exact_mut(nt) {
            for (v, s) in r.iter_mut().zip(&sum) {
                *v /= s;
            }
        }
    }
    w
}

/// Backward of [`softmax_columns`]: dE = E' ⊙ (dE' − Σ_u E'[u,·]·dE'[u,·]).
fn softmax_columns_backward(w: &[f64], dw: &[f64], nb: usize, nt: usize) -> Vec<f64> {
    let mut de = vec![0.0; w.len()];
    for b in 0..nb {
        let (wm, gm) = (row(w, b, nt * nt), row(dw, b, nt * nt));
        let mut s = vec![0.0; nt];
        for (wr, gr) in wm.chunks_exact(nt).zip(gm.chunks_exact(nt)) {
            for ((s, w), g) in s.iter_mut().zip(wr).zip(gr) {
                *s += w * g;
            }
        }
        let dm = row_mut(&mut de, b, nt * nt);
        for ((dr, wr), gr) in dm
            .chunks_exact_mut(nt)
            .zip(wm.chunks_exact(nt))
            .zip(gm.chunks_exact(nt))
        {
            for (((d, w), g), s) in dr.iter_mut().zip(wr).zip(gr).zip(&s) {
                *d = w * (g - s);
            }
        }
    }
    de
}

/// Softmax over the last index of each row of length `len` (step 2).
fn softmax_rows(s: &[f64], len: usize) -> Vec<f64> {
    let mut w = s.to_vec();
    for r in w.chunks_exact_mut(len) {
        let max = r.iter().copied().fold(f64::NEG_INFINITY, f64::max);
        let mut sum = 0.0;
        for v in r.iter_mut() {
            *v = (*v - max).exp();
            sum += *v;
        }
        for v in r.iter_mut() {
            *v /= sum;
        }
    }
    w
}

/// Backward of [`softmax_rows`]: dS = S' ⊙ (dS' − Σ_k S'[·,k]·dS'[·,k]).
fn softmax_rows_backward(w: &[f64], dw: &[f64], len: usize) -> Vec<f64> {
    let mut ds = vec![0.0; w.len()];
    for ((dr, wr), gr) in ds
        .chunks_exact_mut(len)
        .zip(w.chunks_exact(len))
        .zip(dw.chunks_exact(len))
    {
        let s = dot(wr, gr);
        for ((d, w), g) in dr.iter_mut().zip(wr).zip(gr) {
            *d = w * (g - s);
        }
    }
    ds
}

// ---------------------------------------------------------------------------------------
// Step 1: temporal attention (eq. 35–37).

/// lhs = (X·U1)·U2, rhs = U3·X, P = lhs·rhs, E = Ve·σ(P + be), E' = softmax over the first
/// time index, X_t = X·(E' + I).
fn temporal_attention(d: &Dims, x: &[f64], p: &TemporalParams) -> TemporalAttention {
    let Dims {
        b: nb,
        n: nn,
        ci,
        t: nt,
        ..
    } = *d;
    let mut xu1 = vec![0.0; nb * ci * nt];
    let mut rhs = vec![0.0; nb * nn * nt];
    for b in 0..nb {
        for n in 0..nn {
            for c in 0..ci {
                let xr = row(x, d.r(ci, b, n, c), nt);
                axpy(row_mut(&mut xu1, b * ci + c, nt), p.u1[n], xr);
                axpy(row_mut(&mut rhs, b * nn + n, nt), p.u3[c], xr);
            }
        }
    }
    let mut lhs = vec![0.0; nb * nt * nn];
    for b in 0..nb {
        for t in 0..nt {
            let lr = row_mut(&mut lhs, b * nt + t, nn);
            for c in 0..ci {
                axpy(lr, xu1[(b * ci + c) * nt + t], row(p.u2, c, nn));
            }
        }
    }
    let mut sig = vec![0.0; nb * nt * nt];
    for b in 0..nb {
        for t in 0..nt {
            let sr = row_mut(&mut sig, b * nt + t, nt);
            for n in 0..nn {
                axpy(sr, lhs[(b * nt + t) * nn + n], row(&rhs, b * nn + n, nt));
            }
            for (s, be) in sr.iter_mut().zip(row(p.be, t, nt)) {
                *s = sigmoid(*s + be);
            }
        }
    }
    let mut scores = vec![0.0; nb * nt * nt];
    for b in 0..nb {
        for t in 0..nt {
            for k in 0..nt {
                let v = p.ve[t * nt + k];
                let src = row(&sig, b * nt + k, nt);
                axpy(row_mut(&mut scores, b * nt + t, nt), v, src);
            }
        }
    }
    let weights = softmax_columns(&scores, nb, nt);
    let mut output = x.to_vec();
    for b in 0..nb {
        for n in 0..nn {
            for c in 0..ci {
                let r = d.r(ci, b, n, c);
                let (xr, or) = (row(x, r, nt), row_mut(&mut output, r, nt));
                for (t, &xv) in xr.iter().enumerate() {
                    axpy(or, xv, row(&weights, b * nt + t, nt));
                }
            }
        }
    }
    TemporalAttention {
        xu1,
        lhs,
        rhs,
        sig,
        scores,
        weights,
        output,
    }
}

/// Backward of step 1: adds dL/dX to `dx` and the parameter gradients to `grads`.
#[allow(clippy::too_many_arguments)]
fn temporal_attention_backward(
    d: &Dims,
    x: &[f64],
    p: &TemporalParams,
    a: &TemporalAttention,
    dxt: &[f64],
    dx: &mut [f64],
    grads: &mut Grads,
    prefix: &str,
) {
    let Dims {
        b: nb,
        n: nn,
        ci,
        t: nt,
        ..
    } = *d;
    // X_t = X·(E' + I): dX = dX_t·(E' + I)ᵀ, dE'[b,t,t'] = Σ_{n,c} X[t]·dX_t[t'].
    let mut dw = vec![0.0; nb * nt * nt];
    for b in 0..nb {
        for n in 0..nn {
            for c in 0..ci {
                let r = d.r(ci, b, n, c);
                let (xr, gr) = (row(x, r, nt), row(dxt, r, nt));
                let dxr = row_mut(dx, r, nt);
                for t in 0..nt {
                    dxr[t] += gr[t] + dot(gr, row(&a.weights, b * nt + t, nt));
                    axpy(row_mut(&mut dw, b * nt + t, nt), xr[t], gr);
                }
            }
        }
    }
    let de = softmax_columns_backward(&a.weights, &dw, nb, nt);
    // E = Ve·σ(P + be).
    let (dve, dpre, dbe) = score_gate_backward(p.ve, &a.sig, &de, nb, nt);
    // P = lhs·rhs (dpre is now dP).
    let mut dlhs = vec![0.0; nb * nt * nn];
    let mut drhs = vec![0.0; nb * nn * nt];
    for b in 0..nb {
        for t in 0..nt {
            let pr = row(&dpre, b * nt + t, nt);
            for n in 0..nn {
                dlhs[(b * nt + t) * nn + n] = dot(pr, row(&a.rhs, b * nn + n, nt));
                axpy(
                    row_mut(&mut drhs, b * nn + n, nt),
                    a.lhs[(b * nt + t) * nn + n],
                    pr,
                );
            }
        }
    }
    // lhs[b,t,m] = Σ_c xu1[b,c,t]·U2[c,m].
    let mut du2 = vec![0.0; ci * nn];
    let mut dxu1 = vec![0.0; nb * ci * nt];
    for b in 0..nb {
        for t in 0..nt {
            let lr = row(&dlhs, b * nt + t, nn);
            for c in 0..ci {
                axpy(row_mut(&mut du2, c, nn), a.xu1[(b * ci + c) * nt + t], lr);
                dxu1[(b * ci + c) * nt + t] = dot(row(p.u2, c, nn), lr);
            }
        }
    }
    // xu1 = Σ_n U1[n]·X[n], rhs = Σ_c U3[c]·X[c].
    let mut du1 = vec![0.0; nn];
    let mut du3 = vec![0.0; ci];
    for b in 0..nb {
        for n in 0..nn {
            for c in 0..ci {
                let r = d.r(ci, b, n, c);
                let (gu, gr) = (row(&dxu1, b * ci + c, nt), row(&drhs, b * nn + n, nt));
                du1[n] += dot(gu, row(x, r, nt));
                du3[c] += dot(gr, row(x, r, nt));
                let dxr = row_mut(dx, r, nt);
                axpy(dxr, p.u1[n], gu);
                axpy(dxr, p.u3[c], gr);
            }
        }
    }
    grads.add(&format!("{prefix}.tat.U1"), &du1);
    grads.add(&format!("{prefix}.tat.U2"), &du2);
    grads.add(&format!("{prefix}.tat.U3"), &du3);
    grads.add(&format!("{prefix}.tat.be"), &dbe);
    grads.add(&format!("{prefix}.tat.Ve"), &dve);
}

// ---------------------------------------------------------------------------------------
// Step 2: spatial attention (eq. 32–34).

/// lhs = (X_t·W1)·W2, rhs = W3·X_t, P = lhs·rhs, S = Vs·σ(P + bs), S' = softmax over j,
/// X_s = (S' + I)·X_t.
fn spatial_attention(d: &Dims, xt: &[f64], p: &SpatialParams) -> SpatialAttention {
    let Dims {
        b: nb,
        n: nn,
        ci,
        t: nt,
        ..
    } = *d;
    let mut xw1 = vec![0.0; nb * nn * ci];
    let mut lhs = vec![0.0; nb * nn * nt];
    let mut rhs = vec![0.0; nb * nn * nt];
    for b in 0..nb {
        for n in 0..nn {
            for c in 0..ci {
                let xr = row(xt, d.r(ci, b, n, c), nt);
                let v = dot(xr, p.w1);
                xw1[(b * nn + n) * ci + c] = v;
                axpy(row_mut(&mut lhs, b * nn + n, nt), v, row(p.w2, c, nt));
                axpy(row_mut(&mut rhs, b * nn + n, nt), p.w3[c], xr);
            }
        }
    }
    let mut sig = vec![0.0; nb * nn * nn];
    for b in 0..nb {
        for k in 0..nn {
            for j in 0..nn {
                let pv = dot(row(&lhs, b * nn + k, nt), row(&rhs, b * nn + j, nt));
                sig[(b * nn + k) * nn + j] = sigmoid(pv + p.bs[k * nn + j]);
            }
        }
    }
    let mut scores = vec![0.0; nb * nn * nn];
    for b in 0..nb {
        for i in 0..nn {
            for k in 0..nn {
                let v = p.vs[i * nn + k];
                let src = row(&sig, b * nn + k, nn);
                axpy(row_mut(&mut scores, b * nn + i, nn), v, src);
            }
        }
    }
    let weights = softmax_rows(&scores, nn);
    let cs = ci * nt;
    let mut output = xt.to_vec();
    for b in 0..nb {
        for i in 0..nn {
            let or = row_mut(&mut output, b * nn + i, cs);
            for j in 0..nn {
                axpy(or, weights[(b * nn + i) * nn + j], row(xt, b * nn + j, cs));
            }
        }
    }
    SpatialAttention {
        xw1,
        lhs,
        rhs,
        sig,
        scores,
        weights,
        output,
    }
}

/// Backward of step 2: returns dL/dX_t and adds the parameter gradients to `grads`.
fn spatial_attention_backward(
    d: &Dims,
    xt: &[f64],
    p: &SpatialParams,
    a: &SpatialAttention,
    dxs: &[f64],
    grads: &mut Grads,
    prefix: &str,
) -> Vec<f64> {
    let Dims {
        b: nb,
        n: nn,
        ci,
        t: nt,
        ..
    } = *d;
    let cs = ci * nt;
    // X_s = (S' + I)·X_t: dX_t = (S' + I)ᵀ·dX_s, dS'[b,i,j] = Σ_{c,t} dX_s[i]·X_t[j].
    let mut dxt = dxs.to_vec();
    let mut dw = vec![0.0; nb * nn * nn];
    for b in 0..nb {
        for i in 0..nn {
            let gi = row(dxs, b * nn + i, cs);
            for j in 0..nn {
                dw[(b * nn + i) * nn + j] = dot(gi, row(xt, b * nn + j, cs));
                axpy(
                    row_mut(&mut dxt, b * nn + j, cs),
                    a.weights[(b * nn + i) * nn + j],
                    gi,
                );
            }
        }
    }
    let ds = softmax_rows_backward(&a.weights, &dw, nn);
    // S = Vs·σ(P + bs).
    let (dvs, dpre, dbs) = score_gate_backward(p.vs, &a.sig, &ds, nb, nn);
    // P[b,n,m] = Σ_t lhs[b,n,t]·rhs[b,m,t] (dpre is now dP).
    let mut dlhs = vec![0.0; nb * nn * nt];
    let mut drhs = vec![0.0; nb * nn * nt];
    for b in 0..nb {
        for n in 0..nn {
            for m in 0..nn {
                let g = dpre[(b * nn + n) * nn + m];
                axpy(
                    row_mut(&mut dlhs, b * nn + n, nt),
                    g,
                    row(&a.rhs, b * nn + m, nt),
                );
                axpy(
                    row_mut(&mut drhs, b * nn + m, nt),
                    g,
                    row(&a.lhs, b * nn + n, nt),
                );
            }
        }
    }
    // lhs = Σ_c xw1[c]·W2[c], xw1 = X_t·W1, rhs = Σ_c W3[c]·X_t[c].
    let mut dw1 = vec![0.0; nt];
    let mut dw2 = vec![0.0; ci * nt];
    let mut dw3 = vec![0.0; ci];
    for b in 0..nb {
        for n in 0..nn {
            let (gl, gr) = (row(&dlhs, b * nn + n, nt), row(&drhs, b * nn + n, nt));
            for c in 0..ci {
                let r = d.r(ci, b, n, c);
                let xr = row(xt, r, nt);
                dw3[c] += dot(gr, xr);
                axpy(row_mut(&mut dw2, c, nt), a.xw1[(b * nn + n) * ci + c], gl);
                let g = dot(row(p.w2, c, nt), gl);
                axpy(&mut dw1, g, xr);
                let dxr = row_mut(&mut dxt, r, nt);
                axpy(dxr, p.w3[c], gr);
                axpy(dxr, g, p.w1);
            }
        }
    }
    grads.add(&format!("{prefix}.sat.W1"), &dw1);
    grads.add(&format!("{prefix}.sat.W2"), &dw2);
    grads.add(&format!("{prefix}.sat.W3"), &dw3);
    grads.add(&format!("{prefix}.sat.bs"), &dbs);
    grads.add(&format!("{prefix}.sat.Vs"), &dvs);
    dxt
}

// ---------------------------------------------------------------------------------------
// Step 3: graph convolution (eq. 29; Chebyshev basis in `iastgcn-s`).

/// Ψ[i,j] = Σ_k θ_k·basis[k,i,j].
fn graph_kernel(nn: usize, basis: &[f64], theta: &[f64]) -> Vec<f64> {
    let mut psi = vec![0.0; nn * nn];
    for (k, &th) in theta.iter().enumerate() {
        axpy(&mut psi, th, row(basis, k, nn * nn));
    }
    psi
}

/// Q = X_s·W (channels), Z = ReLU(Ψ·Q) (nodes). Returns (Q, Z).
fn graph_conv(d: &Dims, psi: &[f64], w: &[f64], xs: &[f64]) -> (Vec<f64>, Vec<f64>) {
    let Dims {
        b: nb,
        n: nn,
        ci,
        c: nc,
        t: nt,
    } = *d;
    let mut q = vec![0.0; nb * nn * nc * nt];
    for b in 0..nb {
        for j in 0..nn {
            for o in 0..nc {
                let qr = row_mut(&mut q, d.r(nc, b, j, o), nt);
                for c in 0..ci {
                    axpy(qr, w[c * nc + o], row(xs, d.r(ci, b, j, c), nt));
                }
            }
        }
    }
    let ct = nc * nt;
    let mut z = vec![0.0; nb * nn * ct];
    for b in 0..nb {
        for i in 0..nn {
            let zr = row_mut(&mut z, b * nn + i, ct);
            for j in 0..nn {
                axpy(zr, psi[i * nn + j], row(&q, b * nn + j, ct));
            }
            for v in zr.iter_mut() {
                *v = v.max(0.0);
            }
        }
    }
    (q, z)
}

/// Backward of step 3: returns dL/dX_s and adds dθ, dW to `grads`.
#[allow(clippy::too_many_arguments)]
fn graph_conv_backward(
    d: &Dims,
    basis: &[f64],
    p: &BlockParams,
    psi: &[f64],
    q: &[f64],
    z: &[f64],
    xs: &[f64],
    dz: &[f64],
    grads: &mut Grads,
) -> Vec<f64> {
    let Dims {
        b: nb,
        n: nn,
        ci,
        c: nc,
        t: nt,
    } = *d;
    let ct = nc * nt;
    // ReLU.
    let dg: Vec<f64> = dz
        .iter()
        .zip(z)
        .map(|(&g, &z)| if z > 0.0 { g } else { 0.0 })
        .collect();
    // G = Ψ·Q over nodes; Ψ = Σ_k θ_k basis_k.
    let mut dpsi = vec![0.0; nn * nn];
    let mut dq = vec![0.0; q.len()];
    for b in 0..nb {
        for i in 0..nn {
            let gi = row(&dg, b * nn + i, ct);
            for j in 0..nn {
                dpsi[i * nn + j] += dot(gi, row(q, b * nn + j, ct));
                axpy(row_mut(&mut dq, b * nn + j, ct), psi[i * nn + j], gi);
            }
        }
    }
    let dtheta: Vec<f64> = (0..p.theta.len())
        .map(|k| dot(&dpsi, row(basis, k, nn * nn)))
        .collect();
    // Q = X_s·W over channels.
    let mut dw = vec![0.0; ci * nc];
    let mut dxs = vec![0.0; xs.len()];
    for b in 0..nb {
        for j in 0..nn {
            for o in 0..nc {
                let gr = row(&dq, d.r(nc, b, j, o), nt);
                for c in 0..ci {
                    let r = d.r(ci, b, j, c);
                    dw[c * nc + o] += dot(row(xs, r, nt), gr);
                    axpy(row_mut(&mut dxs, r, nt), p.w[c * nc + o], gr);
                }
            }
        }
    }
    grads.add(&p.name("gwc.theta"), &dtheta);
    grads.add(&p.name("gwc.W"), &dw);
    dxs
}

// ---------------------------------------------------------------------------------------
// Step 4: dilated causal convolution (eq. 30–31), also the plain one of `iastgcn-t`.

/// G[b,n,o,t] = bias[o] + Σ_c Σ_k weight[o,c,k]·Z[b,n,c,t − dil·k] (zero before t = 0).
fn causal_conv(d: &Dims, dil: usize, weight: &[f64], bias: &[f64], z: &[f64]) -> Vec<f64> {
    let Dims {
        b: nb,
        n: nn,
        c: nc,
        t: nt,
        ..
    } = *d;
    let nk = weight.len() / (nc * nc);
    let mut g = vec![0.0; z.len()];
    for b in 0..nb {
        for n in 0..nn {
            for o in 0..nc {
                let gr = row_mut(&mut g, d.r(nc, b, n, o), nt);
                gr.fill(bias[o]);
                for c in 0..nc {
                    let zr = row(z, d.r(nc, b, n, c), nt);
                    for k in 0..nk {
                        let s = dil * k;
                        if s < nt {
                            axpy(&mut gr[s..], weight[(o * nc + c) * nk + k], &zr[..nt - s]);
                        }
                    }
                }
            }
        }
    }
    g
}

/// Backward of [`causal_conv`]: adds dL/dZ to `dz`, returns (dweight, dbias).
fn causal_conv_backward(
    d: &Dims,
    dil: usize,
    weight: &[f64],
    z: &[f64],
    dg: &[f64],
    dz: &mut [f64],
) -> (Vec<f64>, Vec<f64>) {
    let Dims {
        b: nb,
        n: nn,
        c: nc,
        t: nt,
        ..
    } = *d;
    let nk = weight.len() / (nc * nc);
    let mut dw = vec![0.0; weight.len()];
    let mut db = vec![0.0; nc];
    for b in 0..nb {
        for n in 0..nn {
            for o in 0..nc {
                let gr = row(dg, d.r(nc, b, n, o), nt);
                db[o] += gr.iter().sum::<f64>();
                for c in 0..nc {
                    let r = d.r(nc, b, n, c);
                    for k in 0..nk {
                        let s = dil * k;
                        if s < nt {
                            let i = (o * nc + c) * nk + k;
                            dw[i] += dot(&gr[s..], &row(z, r, nt)[..nt - s]);
                            axpy(&mut row_mut(dz, r, nt)[..nt - s], weight[i], &gr[s..]);
                        }
                    }
                }
            }
        }
    }
    (dw, db)
}

/// H = tanh(G_f) ⊙ σ(G_g) (gated, eq. 31) or ReLU(G_f) (`iastgcn-t`).
fn temporal_output(filter: &[f64], gate: Option<&[f64]>) -> Vec<f64> {
    match gate {
        Some(gate) => filter
            .iter()
            .zip(gate)
            .map(|(&f, &g)| f.tanh() * sigmoid(g))
            .collect(),
        None => filter.iter().map(|&f| f.max(0.0)).collect(),
    }
}

/// Backward of step 4 from dL/dH: returns dL/dZ, adds the convolution gradients.
#[allow(clippy::too_many_arguments)]
fn temporal_conv_backward(
    d: &Dims,
    dil: usize,
    p: &BlockParams,
    z: &[f64],
    filter: &[f64],
    gate: Option<&[f64]>,
    dh: &[f64],
    grads: &mut Grads,
) -> Vec<f64> {
    let mut dz = vec![0.0; z.len()];
    match (gate, p.gate) {
        (Some(gate), Some((gate_weight, _))) => {
            let mut df = vec![0.0; dh.len()];
            let mut dgate = vec![0.0; dh.len()];
            for i in 0..dh.len() {
                let (th, sg) = (filter[i].tanh(), sigmoid(gate[i]));
                df[i] = dh[i] * sg * (1.0 - th * th);
                dgate[i] = dh[i] * th * sg * (1.0 - sg);
            }
            let (dw, db) = causal_conv_backward(d, dil, p.filter_weight, z, &df, &mut dz);
            grads.add(&p.name("tcn.filter.weight"), &dw);
            grads.add(&p.name("tcn.filter.bias"), &db);
            let (dw, db) = causal_conv_backward(d, dil, gate_weight, z, &dgate, &mut dz);
            grads.add(&p.name("tcn.gate.weight"), &dw);
            grads.add(&p.name("tcn.gate.bias"), &db);
        }
        (None, None) => {
            let df: Vec<f64> = dh
                .iter()
                .zip(filter)
                .map(|(&g, &f)| if f > 0.0 { g } else { 0.0 })
                .collect();
            let (dw, db) = causal_conv_backward(d, dil, p.filter_weight, z, &df, &mut dz);
            grads.add(&p.name("tcn.filter.weight"), &dw);
            grads.add(&p.name("tcn.filter.bias"), &db);
        }
        _ => unreachable!("gate tape and gate parameters come together"),
    }
    dz
}

// ---------------------------------------------------------------------------------------
// Step 5: residual 1×1 convolution.

/// R[b,n,o,t] = res.bias[o] + Σ_c res.weight[o,c]·X[b,n,c,t].
fn residual(d: &Dims, weight: &[f64], bias: &[f64], x: &[f64]) -> Vec<f64> {
    let Dims {
        b: nb,
        n: nn,
        ci,
        c: nc,
        t: nt,
    } = *d;
    let mut r = vec![0.0; nb * nn * nc * nt];
    for b in 0..nb {
        for n in 0..nn {
            for o in 0..nc {
                let rr = row_mut(&mut r, d.r(nc, b, n, o), nt);
                rr.fill(bias[o]);
                for c in 0..ci {
                    axpy(rr, weight[o * ci + c], row(x, d.r(ci, b, n, c), nt));
                }
            }
        }
    }
    r
}

/// Backward of step 5: adds dL/dX to `dx`, returns (dweight, dbias).
fn residual_backward(
    d: &Dims,
    weight: &[f64],
    x: &[f64],
    dr: &[f64],
    dx: &mut [f64],
) -> (Vec<f64>, Vec<f64>) {
    let Dims {
        b: nb,
        n: nn,
        ci,
        c: nc,
        t: nt,
    } = *d;
    let mut dw = vec![0.0; nc * ci];
    let mut db = vec![0.0; nc];
    for b in 0..nb {
        for n in 0..nn {
            for o in 0..nc {
                let gr = row(dr, d.r(nc, b, n, o), nt);
                db[o] += gr.iter().sum::<f64>();
                for c in 0..ci {
                    let r = d.r(ci, b, n, c);
                    dw[o * ci + c] += dot(gr, row(x, r, nt));
                    axpy(row_mut(dx, r, nt), weight[o * ci + c], gr);
                }
            }
        }
    }
    (dw, db)
}

// ---------------------------------------------------------------------------------------
// Step 6: Y = LayerNorm_C(ReLU(H + R)).

/// LayerNorm over the channel axis for each (b,n,t), biased variance. Returns
/// (Y, mean, rstd) with mean and rstd `[B,N,T]`.
fn layer_norm(
    d: &Dims,
    a: &[f64],
    gamma: &[f64],
    beta: &[f64],
    eps: f64,
) -> (Vec<f64>, Vec<f64>, Vec<f64>) {
    let Dims {
        b: nb,
        n: nn,
        c: nc,
        t: nt,
        ..
    } = *d;
    let ct = nc * nt;
    let mut y = vec![0.0; a.len()];
    let mut mean = vec![0.0; nb * nn * nt];
    let mut rstd = vec![0.0; nb * nn * nt];
    for bn in 0..nb * nn {
        let am = row(a, bn, ct);
        let mu = row_mut(&mut mean, bn, nt);
        for ar in am.chunks_exact(nt) {
            axpy(mu, 1.0 / nc as f64, ar);
        }
        let mut var = vec![0.0; nt];
        for ar in am.chunks_exact(nt) {
            for ((v, x), m) in var.iter_mut().zip(ar).zip(mu.iter()) {
                *v += (x - m) * (x - m) / nc as f64;
            }
        }
        let rs = row_mut(&mut rstd, bn, nt);
        for (r, v) in rs.iter_mut().zip(&var) {
            *r = 1.0 / (v + eps).sqrt();
        }
        let mu = row(&mean, bn, nt);
        let rs = row(&rstd, bn, nt);
        let ym = row_mut(&mut y, bn, ct);
        for (c, (yr, ar)) in ym.chunks_exact_mut(nt).zip(am.chunks_exact(nt)).enumerate() {
            for (((y, x), m), r) in yr.iter_mut().zip(ar).zip(mu).zip(rs) {
                *y = gamma[c] * (x - m) * r + beta[c];
            }
        }
    }
    (y, mean, rstd)
}

/// Backward of [`layer_norm`]: returns (dA, dγ, dβ).
fn layer_norm_backward(
    d: &Dims,
    a: &[f64],
    mean: &[f64],
    rstd: &[f64],
    gamma: &[f64],
    dy: &[f64],
) -> (Vec<f64>, Vec<f64>, Vec<f64>) {
    let Dims {
        b: nb,
        n: nn,
        c: nc,
        t: nt,
        ..
    } = *d;
    let ct = nc * nt;
    let inv_c = 1.0 / nc as f64;
    let mut da = vec![0.0; a.len()];
    let mut dgamma = vec![0.0; nc];
    let mut dbeta = vec![0.0; nc];
    let mut xhat = vec![0.0; ct];
    let mut dxhat = vec![0.0; ct];
    for bn in 0..nb * nn {
        let (am, gm) = (row(a, bn, ct), row(dy, bn, ct));
        let (mu, rs) = (row(mean, bn, nt), row(rstd, bn, nt));
        // Σ_c dx̂ and Σ_c dx̂·x̂ per t.
        let mut s1 = vec![0.0; nt];
        let mut s2 = vec![0.0; nt];
        for c in 0..nc {
            let (ar, gr) = (row(am, c, nt), row(gm, c, nt));
            let xr = row_mut(&mut xhat, c, nt);
            for (((xh, x), m), r) in xr.iter_mut().zip(ar).zip(mu).zip(rs) {
                *xh = (x - m) * r;
            }
            dgamma[c] += dot(gr, xr);
            dbeta[c] += gr.iter().sum::<f64>();
            let dr = row_mut(&mut dxhat, c, nt);
            for (dh, g) in dr.iter_mut().zip(gr) {
                *dh = g * gamma[c];
            }
            for (((s1, s2), dh), xh) in s1
                .iter_mut()
                .zip(s2.iter_mut())
                .zip(dr.iter())
                .zip(xr.iter())
            {
                *s1 += dh;
                *s2 += dh * xh;
            }
        }
        let dm = row_mut(&mut da, bn, ct);
        for c in 0..nc {
            let (xr, dr) = (row(&xhat, c, nt), row(&dxhat, c, nt));
            let out = row_mut(dm, c, nt);
            for t in 0..nt {
                out[t] = rs[t] * (dr[t] - s1[t] * inv_c - xr[t] * s2[t] * inv_c);
            }
        }
    }
    (da, dgamma, dbeta)
}

// ---------------------------------------------------------------------------------------
// One ST block: steps 1–7.

/// Forward of block `l` on its input `x` `[B,N,C_in,T]`.
#[allow(clippy::too_many_arguments)]
fn block_forward(
    config: &ModelConfig,
    d: &Dims,
    l: usize,
    basis: &[f64],
    p: &BlockParams,
    x: &[f64],
    dropout: Option<DropoutStep>,
) -> BlockTape {
    // Steps 1–2 (X_s = X in `iastgcn-a`).
    let temporal = p.temporal.as_ref().map(|tp| temporal_attention(d, x, tp));
    let spatial = match (&temporal, &p.spatial) {
        (Some(ta), Some(sp)) => Some(spatial_attention(d, &ta.output, sp)),
        _ => None,
    };
    let xs = spatial.as_ref().map_or(x, |s| &s.output[..]);
    // Step 3.
    let psi = graph_kernel(d.n, basis, p.theta);
    let (q, z) = graph_conv(d, &psi, p.w, xs);
    // Step 4.
    let dil = config.dilation(l);
    let filter = causal_conv(d, dil, p.filter_weight, p.filter_bias, &z);
    let gate = p.gate.map(|(w, b)| causal_conv(d, dil, w, b, &z));
    let h = temporal_output(&filter, gate.as_deref());
    // Step 5, and the ReLU of step 6.
    let mut act = residual(d, p.res_weight, p.res_bias, x);
    for (a, h) in act.iter_mut().zip(&h) {
        *a = (*a + h).max(0.0);
    }
    // Step 6.
    let (mut output, mean, rstd) = layer_norm(d, &act, p.gamma, p.beta, config.eps);
    // Step 7.
    let mask = dropout.map(|ds| {
        let m = ds.block(config, d.b, l);
        let scale = 1.0 / (1.0 - config.dropout);
        let mask: Vec<bool> = (0..output.len()).map(|i| keep(&m, ds.step, i)).collect();
        for (y, &k) in output.iter_mut().zip(&mask) {
            *y = if k { *y * scale } else { 0.0 };
        }
        mask
    });
    BlockTape {
        temporal,
        spatial,
        psi,
        q,
        z,
        filter,
        gate,
        act,
        mean,
        rstd,
        mask,
        output,
    }
}

/// Backward of block `l` from dL/d(output): returns dL/dX, adds the block's gradients.
#[allow(clippy::too_many_arguments)]
fn block_backward(
    config: &ModelConfig,
    d: &Dims,
    l: usize,
    basis: &[f64],
    p: &BlockParams,
    x: &[f64],
    tape: &BlockTape,
    dout: &[f64],
    grads: &mut Grads,
) -> Vec<f64> {
    // Step 7.
    let scale = 1.0 / (1.0 - config.dropout);
    let dy: Vec<f64> = match &tape.mask {
        Some(mask) => dout
            .iter()
            .zip(mask)
            .map(|(&g, &k)| if k { g * scale } else { 0.0 })
            .collect(),
        None => dout.to_vec(),
    };
    // Step 6.
    let (mut dpre, dgamma, dbeta) =
        layer_norm_backward(d, &tape.act, &tape.mean, &tape.rstd, p.gamma, &dy);
    grads.add(&p.name("ln.gamma"), &dgamma);
    grads.add(&p.name("ln.beta"), &dbeta);
    for (g, &a) in dpre.iter_mut().zip(&tape.act) {
        if a <= 0.0 {
            *g = 0.0;
        }
    }
    // Step 5 (dpre is dR = dH).
    let mut dx = vec![0.0; x.len()];
    let (dw, db) = residual_backward(d, p.res_weight, x, &dpre, &mut dx);
    grads.add(&p.name("res.weight"), &dw);
    grads.add(&p.name("res.bias"), &db);
    // Step 4.
    let dil = config.dilation(l);
    let dz = temporal_conv_backward(
        d,
        dil,
        p,
        &tape.z,
        &tape.filter,
        tape.gate.as_deref(),
        &dpre,
        grads,
    );
    // Step 3.
    let xs = tape.spatial.as_ref().map_or(x, |s| &s.output[..]);
    let dxs = graph_conv_backward(d, basis, p, &tape.psi, &tape.q, &tape.z, xs, &dz, grads);
    // Steps 2–1.
    match (&tape.temporal, &tape.spatial, &p.temporal, &p.spatial) {
        (Some(ta), Some(sa), Some(tp), Some(sp)) => {
            let dxt = spatial_attention_backward(d, &ta.output, sp, sa, &dxs, grads, &p.prefix);
            temporal_attention_backward(d, x, tp, ta, &dxt, &mut dx, grads, &p.prefix);
        }
        (None, None, None, None) => axpy(&mut dx, 1.0, &dxs),
        _ => unreachable!("attention tape and parameters come together"),
    }
    dx
}

// ---------------------------------------------------------------------------------------
// Head, loss, and the whole network.

/// ŷ[b,o] = head.bias[o] + Σ_{n,c} head.weight[o, n·C + c]·Y_L[b,n,c,T−1].
fn head(config: &ModelConfig, batch: usize, w: &[f64], bias: &[f64], y: &[f64]) -> Vec<f64> {
    let (nn, nc, nt, no) = (config.nodes, config.channels, config.window, config.outputs);
    let mut out = vec![0.0; batch * no];
    for b in 0..batch {
        for o in 0..no {
            let wr = row(w, o, nn * nc);
            out[b * no + o] = bias[o]
                + (0..nn * nc)
                    .map(|nc_| wr[nc_] * y[(b * nn * nc + nc_) * nt + nt - 1])
                    .sum::<f64>();
        }
    }
    out
}

/// The weight of output `m` in eq. 39: 1 for position (m < 3), P for attitude.
fn output_weight(m: usize, loss: &Loss) -> f64 {
    if m < 3 {
        1.0
    } else {
        loss.attitude_penalty
    }
}

/// The forward pass of docs/model.md on `x` `[B,N,F,T]` (`batch` = B). `basis` is
/// `graph_basis(graph, config)`, `params` in `param_specs(config)` order. With `dropout`
/// the blocks apply the masks of that training step; without, the pass is the
/// evaluation one.
pub fn forward(
    config: &ModelConfig,
    basis: &[f64],
    specs: &[ParamSpec],
    params: &[Vec<f64>],
    x: &[f64],
    batch: usize,
    dropout: Option<DropoutStep>,
) -> Tape {
    config.validate().unwrap_or_else(|e| panic!("{e}"));
    let table = Table::new(specs, params);
    let (nn, nt) = (config.nodes, config.window);
    assert_eq!(x.len(), batch * nn * config.features * nt, "x is [B,N,F,T]");
    assert_eq!(
        basis.len(),
        config.graph_terms() * nn * nn,
        "basis is [terms,N,N]"
    );
    let mut blocks: Vec<BlockTape> = Vec::with_capacity(config.blocks);
    for l in 0..config.blocks {
        let input = blocks.last().map_or(x, |b| &b.output[..]);
        let d = Dims::new(config, batch, l);
        let p = BlockParams::new(&table, config, l);
        let tape = block_forward(config, &d, l, basis, &p, input, dropout);
        blocks.push(tape);
    }
    let last = blocks.last().map_or(x, |b| &b.output[..]);
    let output = head(
        config,
        batch,
        table.get("head.weight"),
        table.get("head.bias"),
        last,
    );
    Tape {
        batch,
        input: x.to_vec(),
        blocks,
        output,
    }
}

/// Eq. 39: (1/B) Σ_b [Σ_{m<3} (ŷ−y)² + P·Σ_{m≥3} (ŷ−y)²] + λ·Σ_{spec.decay} ‖W‖².
pub fn loss(
    config: &ModelConfig,
    specs: &[ParamSpec],
    params: &[Vec<f64>],
    output: &[f64],
    y: &[f64],
    batch: usize,
    loss: &Loss,
) -> f64 {
    let no = config.outputs;
    assert_eq!(output.len(), batch * no, "ŷ is [B,O]");
    assert_eq!(y.len(), batch * no, "y is [B,O]");
    let table = Table::new(specs, params);
    let mut data = 0.0;
    for (i, (&p, &t)) in output.iter().zip(y).enumerate() {
        data += output_weight(i % no, loss) * (p - t) * (p - t);
    }
    let decay: f64 = specs
        .iter()
        .zip(table.values)
        .filter(|(s, _)| s.decay)
        .map(|(_, w)| dot(w, w))
        .sum();
    data / batch as f64 + loss.weight_decay * decay
}

/// The gradient of [`loss`]`(forward(..))` with respect to every parameter (in spec
/// order) and to x, from the tape of [`forward`] (its dropout masks included).
#[allow(clippy::too_many_arguments)]
pub fn backward(
    config: &ModelConfig,
    basis: &[f64],
    specs: &[ParamSpec],
    params: &[Vec<f64>],
    tape: &Tape,
    y: &[f64],
    batch: usize,
    loss: &Loss,
) -> (Vec<Vec<f64>>, Vec<f64>) {
    let table = Table::new(specs, params);
    let (nn, nc, nt, no) = (config.nodes, config.channels, config.window, config.outputs);
    assert_eq!(tape.batch, batch, "tape of another batch size");
    assert_eq!(y.len(), batch * no, "y is [B,O]");
    let mut grads = Grads {
        specs,
        values: specs.iter().map(|s| vec![0.0; s.numel()]).collect(),
    };
    // Eq. 39, data term.
    let dout: Vec<f64> = tape
        .output
        .iter()
        .zip(y)
        .enumerate()
        .map(|(i, (&p, &t))| 2.0 / batch as f64 * output_weight(i % no, loss) * (p - t))
        .collect();
    // Head.
    let last = tape.blocks.last().map_or(&tape.input, |b| &b.output);
    let hw = table.get("head.weight");
    let mut dhw = vec![0.0; hw.len()];
    let mut dhb = vec![0.0; no];
    let mut dy = vec![0.0; last.len()];
    for b in 0..batch {
        for o in 0..no {
            let g = dout[b * no + o];
            dhb[o] += g;
            for k in 0..nn * nc {
                let i = (b * nn * nc + k) * nt + nt - 1;
                dhw[o * nn * nc + k] += g * last[i];
                dy[i] += g * hw[o * nn * nc + k];
            }
        }
    }
    grads.add("head.weight", &dhw);
    grads.add("head.bias", &dhb);
    // Blocks, last to first.
    for l in (0..config.blocks).rev() {
        let x = if l == 0 {
            &tape.input
        } else {
            &tape.blocks[l - 1].output
        };
        let d = Dims::new(config, batch, l);
        let p = BlockParams::new(&table, config, l);
        dy = block_backward(
            config,
            &d,
            l,
            basis,
            &p,
            x,
            &tape.blocks[l],
            &dy,
            &mut grads,
        );
    }
    // Eq. 39, weight decay.
    for (i, s) in specs.iter().enumerate() {
        if s.decay {
            axpy(&mut grads.values[i], 2.0 * loss.weight_decay, &params[i]);
        }
    }
    (grads.values, dy)
}
