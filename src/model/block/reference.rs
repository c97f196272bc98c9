//! One ST block in f64: what its forward keeps ([`BlockTape`]), and its call list, each
//! step's reference (the step's `reference.rs`) in order (forward) and in reverse
//! (backward), with the ReLU of step 5 and the dropout of step 7 inline. The whole
//! network's reference (`model::reference`) runs the blocks and the head.

// The loops index several tensors by the equations' indices at once.
#![allow(clippy::needless_range_loop)]

use super::exact::{BlockParams, Dims};
use super::gated_dcc::reference::{gated_dcc_backward, gated_dcc_conv, gated_dcc_output};
use super::graph_attention::reference::{graph_attention, graph_attention_backward};
use super::graph_conv::reference::{graph_conv, graph_conv_backward, graph_kernel};
use super::residual_layer_norm::reference::{
    layer_norm, layer_norm_backward, residual, residual_backward,
};
use super::spatial_attention::reference::{
    spatial_attention, spatial_attention_backward, SpatialAttention, SpatialParams,
};
use super::temporal_attention::reference::{
    temporal_attention, temporal_attention_backward, TemporalAttention, TemporalParams,
};
use crate::model::block::residual_layer_norm::dropout_kernel::{keep, Dropout};
use crate::model::exact::{axpy, Grads};
use crate::model::ModelConfig;

/// One ST block's intermediates. Its input is the previous block's `output` (or
/// the network input for block 0).
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

/// The dropout of one training step (docs/model.md step 7). Block `l` draws its mask from
/// [`DropoutStep::block`]: element `i` (flat index into Y `[B,N,C,T]`) is kept iff
/// `dropout_kernel::keep(&mask, step, i)`, and kept values are scaled by 1/(1−p).
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

/// Forward of block `l` on its input `x` `[B,N,C_in,T]`.
#[allow(clippy::too_many_arguments)]
pub(crate) fn block_forward(
    config: &ModelConfig,
    d: &Dims,
    l: usize,
    basis: &[f64],
    p: &BlockParams,
    x: &[f64],
    dropout: Option<DropoutStep>,
) -> BlockTape {
    // Steps 1–2 (X_s = X in `iastgcn-a`).
    let attends = config.variant.attention();
    let temporal = attends.then(|| temporal_attention(d, x, &TemporalParams::of(p)));
    let spatial = temporal
        .as_ref()
        .map(|ta| spatial_attention(d, &ta.output, &SpatialParams::of(p)));
    let xs = spatial.as_ref().map_or(x, |s| &s.output[..]);
    // Step 3 (in `st-gat` the graph attention, whose basis is the neighbour mask).
    let (psi, (q, z)) = if config.variant.graph_attention() {
        (Vec::new(), graph_attention(d, config.heads, basis, p, xs))
    } else {
        let psi = graph_kernel(d.n, basis, p.theta);
        let qz = graph_conv(d, &psi, p.w, xs);
        (psi, qz)
    };
    // Step 4.
    let dil = config.dilation(l);
    let filter = gated_dcc_conv(d, dil, p.filter_weight, p.filter_bias, &z);
    let gate = p.gate.map(|(w, b)| gated_dcc_conv(d, dil, w, b, &z));
    let h = gated_dcc_output(&filter, gate.as_deref());
    // Step 5, and the ReLU of step 6.
    let mut act = residual(d, p.res_weight, p.res_bias, x);
    for (a, h) in act.iter_mut().zip(&h) {
        *a = (*a + h).max(0.0);
    }
    // Step 6.
    let mut output = layer_norm(d, &act, p.gamma, p.beta, config.eps);
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
        mask,
        output,
    }
}

/// Backward of block `l` from dL/d(output): returns dL/dX, adds the block's gradients.
#[allow(clippy::too_many_arguments)]
pub(crate) fn block_backward(
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
    let (mut dpre, dgamma, dbeta) = layer_norm_backward(d, &tape.act, p.gamma, config.eps, &dy);
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
    let dz = gated_dcc_backward(
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
    let dxs = if config.variant.graph_attention() {
        graph_attention_backward(d, config.heads, basis, p, &tape.q, &tape.z, xs, &dz, grads)
    } else {
        graph_conv_backward(d, basis, p, &tape.psi, &tape.q, &tape.z, xs, &dz, grads)
    };
    // Steps 2–1.
    match (&tape.temporal, &tape.spatial) {
        (Some(ta), Some(sa)) => {
            let sp = SpatialParams::of(p);
            let dxt = spatial_attention_backward(d, &ta.output, &sp, sa, &dxs, grads, &p.prefix);
            let tp = TemporalParams::of(p);
            temporal_attention_backward(d, x, &tp, ta, &dxt, &mut dx, grads, &p.prefix);
        }
        (None, None) => axpy(&mut dx, 1.0, &dxs),
        // invariant: the forward pass fills the tape for exactly the parameters it has.
        _ => unreachable!("attention tape and parameters come together"),
    }
    dx
}
