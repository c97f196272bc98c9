//! Step 6's affine map fused with step 7's dropout (docs/model.md), forward and backward:
//! Y = γ·x̂ + β from `residual_layer_norm`'s A, mean and 1/σ, then in a training pass the
//! inverted dropout, in one pass that writes each output element once (into the block
//! output, or the head's input at the last block's last step). The mask's bits are drawn
//! by the device's hash (`ops::dropout::keep`) and kept on the tape for the backward.

// The loops index several per-channel tensors by the channel.
#![allow(clippy::needless_range_loop)]

use super::tape::{BlockTape, Work};
use super::Block;
use crate::model::native::lanes_sum;
use crate::ops::dropout::{keep, Dropout};
use multiversion::multiversion;

/// Y = γ·x̂ + β into `bt.y` (`[N, C, T]` at the output steps), or into `h` `[N·C]` in the
/// last block; with `mask` (the block's dropout and the optimiser step) the dropout too,
/// keeping its mask in `bt.kept`.
#[multiversion(targets("x86_64+avx512f", "x86_64+avx2+fma"))]
pub(super) fn forward(
    b: &Block,
    p: &[Vec<f32>],
    bt: &mut BlockTape,
    mask: Option<((Dropout, usize), u32)>,
    h: Option<&mut [f32]>,
) {
    let (n, t, c) = (b.n, b.t, b.c);
    let (t0, steps) = (bt.t0, bt.steps);
    let scale = 1.0 / (1.0 - b.cfg.dropout as f32);
    let (gamma, beta) = (&p[b.s.gamma], &p[b.s.beta]);
    let mut out = h;
    for i in 0..n {
        let mean = &bt.mean[i * steps..][..steps];
        let rstd = &bt.rstd[i * steps..][..steps];
        for o in 0..c {
            let a = &bt.act[(i * c + o) * steps..][..steps];
            // Where (node i, channel o, step t0) sits in the whole [N, C, T] output.
            let full = (i * c + o) * t + t0;
            let dst = match out.as_deref_mut() {
                Some(h) => &mut h[i * c + o..][..steps],
                None => &mut bt.y[full..][..steps],
            };
            for (((d, a), m), r) in dst.iter_mut().zip(a).zip(mean).zip(rstd) {
                *d = gamma[o] * (a - m) * r + beta[o];
            }
            if let Some(((drop, offset), step)) = &mask {
                let kept = &mut bt.kept[(i * c + o) * steps..][..steps];
                for (tau, k) in kept.iter_mut().enumerate() {
                    *k = keep(drop, *step, offset + full + tau);
                }
                for (d, &k) in dst.iter_mut().zip(kept.iter()) {
                    *d = if k { *d * scale } else { 0.0 };
                }
            }
        }
    }
}

/// From dL/d(block output) (`w.dy`, `[N, C, steps]`): the dropout's mask in place (when
/// the forward `dropped`), then dγ and dβ; dx̂ = γ·dY is left to
/// `residual_layer_norm::backward`, whose channel sums need it.
#[multiversion(targets("x86_64+avx512f", "x86_64+avx2+fma"))]
pub(super) fn backward(
    b: &Block,
    bt: &BlockTape,
    dropped: bool,
    grads: &mut [Vec<f32>],
    w: &mut Work,
) {
    let (n, c) = (b.n, b.c);
    let steps = bt.steps;
    let scale = 1.0 / (1.0 - b.cfg.dropout as f32);
    let dy = &mut w.dy[..n * c * steps];
    if dropped {
        for (v, &k) in dy.iter_mut().zip(&bt.kept) {
            *v = if k { *v * scale } else { 0.0 };
        }
    }
    // dγ and dβ summed over nodes at each (channel, step), then over the steps.
    let (dgamma, dbeta) = w.ln_params.split_at_mut(c * steps);
    let dgamma = &mut dgamma[..c * steps];
    let dbeta = &mut dbeta[..c * steps];
    dgamma.fill(0.0);
    dbeta.fill(0.0);
    for i in 0..n {
        let mean = &bt.mean[i * steps..][..steps];
        let rstd = &bt.rstd[i * steps..][..steps];
        for o in 0..c {
            let row = (i * c + o) * steps..(i * c + o + 1) * steps;
            let (act, g) = (&bt.act[row.clone()], &dy[row]);
            let dgamma = &mut dgamma[o * steps..][..steps];
            let dbeta = &mut dbeta[o * steps..][..steps];
            for ((((dga, dbe), &g), &a), (&m, &r)) in dgamma
                .iter_mut()
                .zip(dbeta.iter_mut())
                .zip(g)
                .zip(act)
                .zip(mean.iter().zip(rstd))
            {
                // x̂, as `residual_layer_norm` computes it.
                let xh = (a - m) * r;
                *dga += g * xh;
                *dbe += g;
            }
        }
    }
    for (o, (dga, dbe)) in dgamma.chunks(steps).zip(dbeta.chunks(steps)).enumerate() {
        grads[b.s.gamma][o] += lanes_sum(dga);
        grads[b.s.beta][o] += lanes_sum(dbe);
    }
}
