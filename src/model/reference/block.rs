//! One ST block: the parameters it looks up, and steps 1–7 in order (forward) and in
//! reverse (backward), with the ReLU of step 6 and the dropout of step 7 inline.

use super::attention::{
    spatial_attention, spatial_attention_backward, temporal_attention, temporal_attention_backward,
};
use super::gated_dcc::{gated_dcc_backward, gated_dcc_conv, gated_dcc_output};
use super::graph_conv::{
    graph_attention, graph_attention_backward, graph_conv, graph_conv_backward, graph_kernel,
};
use super::residual_layer_norm::{layer_norm, layer_norm_backward, residual, residual_backward};
use super::{axpy, BlockParams, BlockTape, Dims, DropoutStep, Grads};
use crate::model::ModelConfig;
use crate::ops::dropout::keep;

/// Forward of block `l` on its input `x` `[B,N,C_in,T]`.
#[allow(clippy::too_many_arguments)]
pub(super) fn block_forward(
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
pub(super) fn block_backward(
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
    match (&tape.temporal, &tape.spatial, &p.temporal, &p.spatial) {
        (Some(ta), Some(sa), Some(tp), Some(sp)) => {
            let dxt = spatial_attention_backward(d, &ta.output, sp, sa, &dxs, grads, &p.prefix);
            temporal_attention_backward(d, x, tp, ta, &dxt, &mut dx, grads, &p.prefix);
        }
        (None, None, None, None) => axpy(&mut dx, 1.0, &dxs),
        // invariant: the forward pass fills the tape for exactly the parameters it has.
        _ => unreachable!("attention tape and parameters come together"),
    }
    dx
}
