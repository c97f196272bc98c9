//! The f64 CPU reference of the whole network of docs/model.md: the forward pass (keeping every
//! intermediate on a [`Tape`]), the loss of eq. 39 and a hand-written backward pass. Tests
//! check the backward against finite differences of the forward, and the GPU schedule
//! against both.
//!
//! One function per docs/model.md step, its backward next to it. Tensors are row-major
//! `[B, N, C, T]` like the GPU's; loops keep the contiguous T axis innermost (as `axpy` /
//! `dot` over rows of length T) so that the paper shape runs in seconds at opt-level 1.
//!
//! This folder holds the whole network: the tape, the loss, the forward and backward
//! through the blocks and the head (`model::head::reference`); [`loss`], with its
//! per-output weights, serves every model. The baselines' own forward and backward are in their folders
//! (`model::dense::reference`, `model::recurrent::reference`,
//! `model::conv_lstm::reference`). The ST block's steps
//! are in their folders of `model::block` (each step's `reference.rs`, composed in
//! `block/reference.rs`), the arithmetic they share in `model::exact`. Where an op has its
//! own f64 reference next to its kernels (`gated_dcc::kernel::cpu` for step 4,
//! `layer_norm_kernel::cpu` for step 6), the step composes that one instead of computing the
//! same maths a second time, so the WGSL tests and the network reference check against
//! one implementation.

// The loops index several tensors by the equations' indices at once.
#![allow(clippy::needless_range_loop)]

use super::block::exact::{BlockParams, Dims};
use super::block::reference::{block_backward, block_forward};
pub use super::block::reference::{BlockTape, DropoutStep};
pub use super::block::spatial_attention::reference::SpatialAttention;
pub use super::block::temporal_attention::reference::TemporalAttention;
use super::exact::{axpy, dot, Grads, Table};
use super::{ModelConfig, ParamSpec};
use crate::model::head::reference::{head, head_backward};

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
        "{} is a baseline: use dense::reference, recurrent::reference or conv_lstm::reference",
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
pub(crate) fn output_gradient(
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
pub(crate) fn add_weight_decay(
    specs: &[ParamSpec],
    params: &[Vec<f64>],
    grads: &mut [Vec<f64>],
    loss: &Loss,
) {
    for (i, s) in specs.iter().enumerate() {
        if s.decay {
            axpy(&mut grads[i], 2.0 * loss.weight_decay, &params[i]);
        }
    }
}

/// The weight of output `m` in eq. 39: 1 for position (m < 3), P for attitude.
fn output_weight(m: usize, loss: &Loss) -> f64 {
    if m < 3 {
        1.0
    } else {
        loss.attitude_penalty
    }
}
