//! `st-gat`'s step 3 in f64: Q = X_s·W over channels (the graph convolution's channel
//! mix), then the multi-head graph attention of `graph_attention::kernel::cpu` and a ReLU,
//! forward and backward.

// The loops index several tensors by the equations' indices at once.
#![allow(clippy::needless_range_loop)]

use crate::model::block::exact::{channel_mix, channel_mix_backward, BlockParams, Dims};
use crate::model::block::graph_attention::kernel::{cpu as gat, GraphAttention};
use crate::model::exact::Grads;

/// The graph attention of `st-gat` on `heads` heads.
fn attention_shape(d: &Dims, heads: usize) -> GraphAttention {
    GraphAttention {
        batch: d.b,
        nodes: d.n,
        channels: d.c,
        steps: d.t,
        heads,
    }
}

/// `st-gat`'s step 3: Q = X_s·W (channels), Z = ReLU(GAT(Q)) with the neighbour `mask`
/// `[N,N]`. Returns (Q, Z).
pub(crate) fn graph_attention(
    d: &Dims,
    heads: usize,
    mask: &[f64],
    p: &BlockParams,
    xs: &[f64],
) -> (Vec<f64>, Vec<f64>) {
    // invariant: called only for the st-gat variant, whose parameters include them.
    let (a_src, a_dst) = p.attention_vectors.expect("st-gat has attention vectors");
    let q = channel_mix(d, p.w, xs);
    let (_, g) = gat::forward(&attention_shape(d, heads), &q, a_src, a_dst, mask);
    (q, g.into_iter().map(|v| v.max(0.0)).collect())
}

/// Backward of [`graph_attention`]: returns dL/dX_s and adds dW, da_src, da_dst.
#[allow(clippy::too_many_arguments)]
pub(crate) fn graph_attention_backward(
    d: &Dims,
    heads: usize,
    mask: &[f64],
    p: &BlockParams,
    q: &[f64],
    z: &[f64],
    xs: &[f64],
    dz: &[f64],
    grads: &mut Grads,
) -> Vec<f64> {
    // invariant: called only for the st-gat variant, whose parameters include them.
    let (a_src, a_dst) = p.attention_vectors.expect("st-gat has attention vectors");
    let dg: Vec<f64> = dz
        .iter()
        .zip(z)
        .map(|(&g, &z)| if z > 0.0 { g } else { 0.0 })
        .collect();
    let (dq, da_src, da_dst) =
        gat::backward(&attention_shape(d, heads), q, a_src, a_dst, mask, &dg);
    grads.add(&p.name("gat.a_src"), &da_src);
    grads.add(&p.name("gat.a_dst"), &da_dst);
    channel_mix_backward(d, p, xs, &dq, grads, "gat.W")
}
