//! The f64 CPU reference of the whole network of docs/model.md: the forward pass (keeping every
//! intermediate on a [`Tape`]), the loss of eq. 39 and a hand-written backward pass. Tests
//! check the backward against finite differences of the forward, and the GPU schedule
//! against both.
//!
//! One function per docs/model.md step, its backward next to it. Tensors are row-major
//! `[B, N, C, T]` like the GPU's; loops keep the contiguous T axis innermost (as `axpy` /
//! `dot` over rows of length T) so that the paper shape runs in seconds at opt-level 1.
//!
//! This file holds the tape, the helpers and parameter lookup every step uses, and the
//! whole network; one file per op family holds the steps: `attention.rs` (steps 1–2),
//! `graph_conv.rs` (step 3), `gated_dcc.rs` (step 4), `residual_layer_norm.rs` (steps 5–6),
//! `block.rs` (one ST block, steps 1–7) and `head.rs` (the head and the loss weights).
//! Where an op has its own f64 reference next to its kernels (`ops::gated_dcc::cpu` for
//! step 4, `ops::layer_norm::cpu` for step 6), the step here composes that one instead of
//! computing the same maths a second time, so the WGSL tests and the network reference
//! check against one implementation.
//! The dense baselines have their own forward and backward in `dense.rs`, the recurrent
//! ones in `recurrent.rs` and `conv_lstm.rs`; [`loss`] serves
//! every model.

// The loops index several tensors by the equations' indices at once.
#![allow(clippy::needless_range_loop)]

pub mod conv_lstm;
pub mod dense;
pub mod recurrent;

pub(crate) mod attention;
mod block;
mod gated_dcc;
pub(crate) mod graph_conv;
mod head;
mod residual_layer_norm;

use super::{ModelConfig, ParamSpec};
use crate::ops::dropout::Dropout;
use attention::{SpatialParams, TemporalParams};
use block::{block_backward, block_forward};
use head::{head, head_backward, output_weight};

/// The dropout of one training step (docs/model.md step 7). Block `l` draws its mask from
/// [`DropoutStep::block`]: element `i` (flat index into Y `[B,N,C,T]`) is kept iff
/// `ops::dropout::keep(&mask, step, i)`, and kept values are scaled by 1/(1−p).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct DropoutStep {
    /// The masks' base seed (block `l` uses seed + l); in training, the two 32-bit
    /// halves of `[train] seed` XORed together.
    pub seed: u32,
    /// The optimiser step, counted from 0 within the training stage.
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
    /// B: windows in the batch.
    pub batch: usize,
    /// The network input x `[B,N,F,T]`.
    pub input: Vec<f64>,
    /// Each block's intermediates, block 0 first.
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
    /// Step 3: Ψ = Σ_k θ_k basis_k `[N,N]` (empty in `st-gat`).
    pub psi: Vec<f64>,
    /// Step 3: `Q[b,j,o,t] = Σ_c X_s[b,j,c,t]·W[c,o]` `[B,N,C,T]` (before the node mixing).
    pub q: Vec<f64>,
    /// Step 3: Z = ReLU(Ψ·Q) `[B,N,C,T]` (in `st-gat`, ReLU of the graph attention of Q).
    pub z: Vec<f64>,
    /// Step 4: G_f `[B,N,C,T]` (in `iastgcn-t` the pre-ReLU plain convolution).
    pub filter: Vec<f64>,
    /// Step 4: G_g `[B,N,C,T]` (absent in `iastgcn-t`).
    pub gate: Option<Vec<f64>>,
    /// Step 6: ReLU(H + R) `[B,N,C,T]`, the LayerNorm input.
    pub act: Vec<f64>,
    /// Step 7: the dropout mask (`None` without dropout).
    pub mask: Option<Vec<bool>>,
    /// The block output Y after dropout `[B,N,C,T]`.
    pub output: Vec<f64>,
}

/// Step 1 intermediates (eq. 35–37).
#[derive(Clone, Debug)]
pub struct TemporalAttention {
    /// `Σ_n X[b,n,c,t]·U1[n]`, stored `[B,C_in,T]`.
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
    /// `Σ_u X_t[b,n,c,u]·W1[u]` `[B,N,C_in]`.
    pub xw1: Vec<f64>,
    /// lhs `[B,N,T]`.
    pub lhs: Vec<f64>,
    /// rhs, stored transposed as `[B,N,T]` (`rhs[b,t,m]` of docs/model.md at `[b,m,t]`).
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
pub(crate) struct Dims {
    b: usize,
    n: usize,
    /// C_in.
    ci: usize,
    c: usize,
    t: usize,
}

impl Dims {
    pub(crate) fn new(config: &ModelConfig, batch: usize, l: usize) -> Dims {
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
pub(crate) struct Table<'a> {
    specs: &'a [ParamSpec],
    values: &'a [Vec<f64>],
}

impl<'a> Table<'a> {
    pub(crate) fn new(specs: &'a [ParamSpec], values: &'a [Vec<f64>]) -> Table<'a> {
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
    // invariant: the f64 reference is a test oracle; it looks up the names of param_specs(config).
    specs
        .iter()
        .position(|s| s.name == name)
        .unwrap_or_else(|| panic!("no parameter named {name}"))
}

/// Gradients in spec order, accumulated by name.
pub(crate) struct Grads<'a> {
    pub(crate) specs: &'a [ParamSpec],
    pub(crate) values: Vec<Vec<f64>>,
}

impl Grads<'_> {
    fn add(&mut self, name: &str, g: &[f64]) {
        let slot = &mut self.values[index(self.specs, name)];
        assert_eq!(slot.len(), g.len(), "gradient of {name} has the wrong size");
        axpy(slot, 1.0, g);
    }
}

// ---------------------------------------------------------------------------------------
// The whole network.

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
    // invariant: the f64 reference is a test oracle, not used by any command; its callers pass validated configs.
    config.validate().unwrap_or_else(|e| panic!("{e}"));
    assert!(
        config.variant.family() == super::Family::StBlocks,
        "{} is a baseline: use reference::dense, reference::recurrent or reference::conv_lstm",
        config.variant
    );
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
    let no = config.outputs;
    assert_eq!(tape.batch, batch, "tape of another batch size");
    assert_eq!(y.len(), batch * no, "y is [B,O]");
    let mut grads = Grads {
        specs,
        values: specs.iter().map(|s| vec![0.0; s.numel()]).collect(),
    };
    let dout = output_gradient(&tape.output, y, no, batch, loss);
    // Head.
    let last = tape.blocks.last().map_or(&tape.input, |b| &b.output);
    let mut dy = head_backward(
        config,
        batch,
        table.get("head.weight"),
        last,
        &dout,
        &mut grads,
    );
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
    add_weight_decay(specs, params, &mut grads.values, loss);
    (grads.values, dy)
}

/// Eq. 39's data term differentiated by ŷ `[B, O]`: every model's backward starts here.
fn output_gradient(
    output: &[f64],
    y: &[f64],
    outputs: usize,
    batch: usize,
    loss: &Loss,
) -> Vec<f64> {
    output
        .iter()
        .zip(y)
        .enumerate()
        .map(|(i, (&p, &t))| 2.0 / batch as f64 * output_weight(i % outputs, loss) * (p - t))
        .collect()
}

/// Eq. 39's weight-decay term: adds 2λW to the gradient of every parameter with `decay`.
fn add_weight_decay(specs: &[ParamSpec], params: &[Vec<f64>], grads: &mut [Vec<f64>], loss: &Loss) {
    for (i, s) in specs.iter().enumerate() {
        if s.decay {
            axpy(&mut grads[i], 2.0 * loss.weight_decay, &params[i]);
        }
    }
}

/// The parameters of block `l`.
pub(crate) struct BlockParams<'a> {
    prefix: String,
    pub(crate) temporal: Option<TemporalParams<'a>>,
    pub(crate) spatial: Option<SpatialParams<'a>>,
    /// θ of the graph convolution (empty in `st-gat`).
    theta: &'a [f64],
    /// The channel mix W of step 3 (`gwc.W`, or `gat.W` in `st-gat`).
    w: &'a [f64],
    /// (a_src, a_dst) of `st-gat`'s graph attention.
    attention_vectors: Option<(&'a [f64], &'a [f64])>,
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
    pub(crate) fn new(table: &Table<'a>, config: &ModelConfig, l: usize) -> BlockParams<'a> {
        let prefix = format!("blocks.{l}");
        let p = |s: &str| table.get(&format!("{prefix}.{s}"));
        let attention = config.variant.attention();
        let gat = config.variant.graph_attention();
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
            theta: if gat { &[] } else { p("gwc.theta") },
            w: p(if gat { "gat.W" } else { "gwc.W" }),
            attention_vectors: gat.then(|| (p("gat.a_src"), p("gat.a_dst"))),
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
