//! Steps 5–7 on the CPU in f32, forward and backward, in two passes. The first fuses
//! steps 5 and 6 up to the LayerNorm's statistics: the residual R = W_r·X + b_r
//! (docs/model.md step 5), A = ReLU(H + R) with step 4's H, and the
//! mean and 1/σ of A over the channels at each step (step 6), per node so that each
//! node's A is built, activated and reduced while it is in cache, with the nodes split
//! over tasks at the paper's sizes. The second fuses step 6's affine map with step 7's
//! dropout: Y = γ·x̂ + β, then in a training pass the inverted dropout, writing each
//! output element once (into the block output, or the head's input at the last block's
//! last step). The mask's bits are drawn by the device's hash (`dropout_kernel::keep`) and
//! kept on the tape for the backward.

// The LayerNorm loops index several per-channel tensors by the channel.
#![allow(clippy::needless_range_loop)]

use rayon::prelude::*;

use crate::model::block::native::Block;
use crate::model::block::residual_layer_norm::dropout_kernel::{keep_run, Dropout};
use crate::model::block::tape::{BlockTape, Work};
use crate::model::cpu::{flushing_subnormals, gemm, lanes_sum, rows, transposed, View};
use multiversion::multiversion;

impl Block<'_> {
    /// Steps 5–7's forward on this block: [`forward`], then [`affine_dropout_forward`]
    /// into `bt.y` (or `h`, the head's input, in the last block), with the block's
    /// dropout and the optimiser step in `mask` in training.
    pub(crate) fn residual_layer_norm_forward(
        &self,
        p: &[Vec<f32>],
        x: &[f32],
        bt: &mut BlockTape,
        mask: Option<((Dropout, usize), u32)>,
        h: Option<&mut [f32]>,
    ) {
        forward(self, p, x, bt);
        affine_dropout_forward(self, p, bt, mask, h);
    }

    /// Steps 7–5's backward on this block from dY (`w.dy`): dH into `w.da`, dL/dX into
    /// `w.dx` when `need_dx`.
    #[allow(clippy::too_many_arguments)]
    pub(crate) fn residual_layer_norm_backward(
        &self,
        p: &[Vec<f32>],
        x: &[f32],
        bt: &BlockTape,
        dropped: bool,
        need_dx: bool,
        grads: &mut [Vec<f32>],
        w: &mut Work,
    ) {
        affine_dropout_backward(self, bt, dropped, grads, w);
        backward(self, p, x, bt, need_dx, grads, w);
    }
}

/// A = ReLU(H + R) `bt.act` `[N, C, steps]` and its mean and 1/σ over C, `bt.mean` and
/// `bt.rstd` `[N, steps]`.
#[multiversion(targets("x86_64+avx512f", "x86_64+avx2+fma"))]
pub(super) fn forward(b: &Block, p: &[Vec<f32>], x: &[f32], bt: &mut BlockTape) {
    let (n, t, c, ci) = (b.n, b.t, b.c, b.ci);
    let s = b.s;
    let (t0, steps) = (bt.t0, bt.steps);
    let wide = n * steps;
    let eps = b.cfg.eps as f32;
    let (res_w, res_b) = (&p[s.res.0], &p[s.res.1]);
    let one_step = steps == 1;
    if one_step {
        // R = X[:, :, t0]·W_rᵀ + b_r `[N, C]` for all nodes at once.
        for (a, bias) in bt.act.iter_mut().zip(res_b.iter().cycle()) {
            *a = *bias;
        }
        let xv = View {
            data: &x[t0..],
            rs: ci * t,
            cs: t,
        };
        gemm(n, ci, c, xv, transposed(res_w, ci), 1.0, &mut bt.act, c);
    }
    let hidden = &bt.hidden;
    let node = |i: usize, a: &mut [f32], mean: &mut [f32], rstd: &mut [f32]| {
        if !one_step {
            for (row, &bias) in a.chunks_mut(steps).zip(res_b) {
                row.fill(bias);
            }
            let xv = View {
                data: &x[i * ci * t + t0..],
                rs: t,
                cs: 1,
            };
            gemm(c, ci, steps, rows(res_w, ci), xv, 1.0, a, steps);
        }
        // A = ReLU(R + H), in contiguous runs of steps.
        for (o, a) in a.chunks_mut(steps).enumerate() {
            let h = &hidden[o * wide + i * steps..][..steps];
            for (v, h) in a.iter_mut().zip(h) {
                *v = (*v + h).max(0.0);
            }
        }
        mean.fill(0.0);
        rstd.fill(0.0);
        for row in a.chunks(steps) {
            for (m, v) in mean.iter_mut().zip(row) {
                *m += v;
            }
        }
        for m in mean.iter_mut() {
            *m /= c as f32;
        }
        for row in a.chunks(steps) {
            for ((q, v), m) in rstd.iter_mut().zip(row).zip(mean.iter()) {
                *q += (v - m) * (v - m);
            }
        }
        for q in rstd.iter_mut() {
            *q = 1.0 / (*q / c as f32 + eps).sqrt();
        }
    };
    let tasks = b.node_tasks(c * ci * steps);
    if tasks > 1 {
        // Nodes in `tasks` groups of `per` consecutive ones.
        let per = n.div_ceil(tasks);
        let act = bt.act.par_chunks_mut(per * c * steps);
        act.zip(bt.mean.par_chunks_mut(per * steps))
            .zip(bt.rstd.par_chunks_mut(per * steps))
            .enumerate()
            .for_each(|(j, ((a, m), r))| {
                flushing_subnormals(|| {
                    let nodes = a
                        .chunks_mut(c * steps)
                        .zip(m.chunks_mut(steps))
                        .zip(r.chunks_mut(steps));
                    for (u, ((a, m), r)) in nodes.enumerate() {
                        node(j * per + u, a, m, r);
                    }
                })
            });
    } else {
        let act = bt.act.chunks_mut(c * steps);
        for (i, ((a, m), r)) in act
            .zip(bt.mean.chunks_mut(steps))
            .zip(bt.rstd.chunks_mut(steps))
            .enumerate()
        {
            node(i, a, m, r);
        }
    }
}

/// From dY (`w.dy`, after `affine_dropout_backward`): the LayerNorm's backward with
/// dx̂ = γ·dY, A's ReLU, dA into `w.da` (= dR = dH), then the residual's gradients, and
/// dL/dX into `w.dx` (which this step starts) when `need_dx`.
#[multiversion(targets("x86_64+avx512f", "x86_64+avx2+fma"))]
pub(super) fn backward(
    b: &Block,
    p: &[Vec<f32>],
    x: &[f32],
    bt: &BlockTape,
    need_dx: bool,
    grads: &mut [Vec<f32>],
    w: &mut Work,
) {
    let (n, t, c, ci) = (b.n, b.t, b.c, b.ci);
    let s = b.s;
    let (t0, steps) = (bt.t0, bt.steps);
    let dy = &w.dy[..n * c * steps];
    // Per node, row by row over the steps (contiguous, so the loops vectorise): the
    // channel sums s1 = Σ_o dx̂, s2 = Σ_o dx̂·x̂ at each step, then dA.
    let gamma = &p[s.gamma];
    let da = &mut w.da[..n * c * steps];
    let inv_c = 1.0 / c as f32;
    let (s1, s2) = w.ln.split_at_mut(steps);
    let s2 = &mut s2[..steps];
    // x̂ of the node's channels `[C, steps]`, from the first pass for the second.
    let xhat_node = &mut w.xhat[..c * steps];
    for i in 0..n {
        let mean = &bt.mean[i * steps..][..steps];
        let rstd = &bt.rstd[i * steps..][..steps];
        let rows_of = |o: usize| (i * c + o) * steps..(i * c + o + 1) * steps;
        s1.fill(0.0);
        s2.fill(0.0);
        for o in 0..c {
            let (act, g) = (&bt.act[rows_of(o)], &dy[rows_of(o)]);
            let xhat = &mut xhat_node[o * steps..][..steps];
            normalised(act, mean, rstd, xhat);
            for (((a1, a2), &g), &xh) in s1.iter_mut().zip(s2.iter_mut()).zip(g).zip(&*xhat) {
                let dxhat = g * gamma[o];
                *a1 += dxhat;
                *a2 += dxhat * xh;
            }
        }
        for o in 0..c {
            let (act, g) = (&bt.act[rows_of(o)], &dy[rows_of(o)]);
            let xhat = &xhat_node[o * steps..][..steps];
            let dst = &mut da[rows_of(o)];
            for (((((d, &a), &g), &xh), &r), (&a1, &a2)) in dst
                .iter_mut()
                .zip(act)
                .zip(g)
                .zip(xhat)
                .zip(rstd)
                .zip(s1.iter().zip(s2.iter()))
            {
                let v = r * (g * gamma[o] - a1 * inv_c - xh * a2 * inv_c);
                *d = if a > 0.0 { v } else { 0.0 };
            }
        }
    }
    // R = W_r·X + b_r at the output steps (dR = dA).
    let dx = &mut w.dx[..n * ci * t];
    if need_dx {
        dx.fill(0.0);
    }
    let (res_w, res_b) = s.res;
    if steps == 1 {
        // One step, all nodes at once: dW_r += dAᵀ·X[:, :, t0], dX[:, :, t0] += dA·W_r.
        let xv = View {
            data: &x[t0..],
            rs: ci * t,
            cs: t,
        };
        gemm(c, n, ci, transposed(da, c), xv, 1.0, &mut grads[res_w], ci);
        for row in da.chunks(c) {
            for (g, d) in grads[res_b].iter_mut().zip(row) {
                *g += d;
            }
        }
        if need_dx {
            let part = &mut w.dred[..n * ci];
            gemm(n, c, ci, rows(da, c), rows(&p[res_w], ci), 0.0, part, ci);
            for (i, row) in part.chunks(ci).enumerate() {
                for (ch, v) in row.iter().enumerate() {
                    dx[(i * ci + ch) * t + t0] += v;
                }
            }
        }
    } else {
        for i in 0..n {
            let dai = &da[i * c * steps..][..c * steps];
            let xv = View {
                data: &x[i * ci * t + t0..],
                rs: 1,
                cs: t,
            };
            gemm(
                c,
                steps,
                ci,
                rows(dai, steps),
                xv,
                1.0,
                &mut grads[res_w],
                ci,
            );
            for (g, row) in grads[res_b].iter_mut().zip(dai.chunks(steps)) {
                *g += lanes_sum(row);
            }
            if need_dx {
                // Rows of this node's dX start `t0` into each row of T.
                let out = &mut dx[i * ci * t + t0..];
                gemm(
                    ci,
                    c,
                    steps,
                    transposed(&p[res_w], ci),
                    rows(dai, steps),
                    1.0,
                    out,
                    t,
                );
            }
        }
    }
}

/// x̂ = (a − mean)·rstd along one row of steps.
#[inline(always)]
fn normalised(act: &[f32], mean: &[f32], rstd: &[f32], xhat: &mut [f32]) {
    for (((x, a), m), r) in xhat.iter_mut().zip(act).zip(mean).zip(rstd) {
        *x = (a - m) * r;
    }
}

/// Y = γ·x̂ + β into `bt.y` (`[N, C, T]` at the output steps), or into `h` `[N·C]` in the
/// last block; with `mask` (the block's dropout and the optimiser step) the dropout too,
/// keeping its mask in `bt.kept`.
#[multiversion(targets("x86_64+avx512f", "x86_64+avx2+fma"))]
pub(super) fn affine_dropout_forward(
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
                keep_run(drop, *step, offset + full, kept);
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
pub(super) fn affine_dropout_backward(
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
