//! Steps 5 and 6 up to the LayerNorm's statistics, fused, forward and backward: the
//! residual R = W_r·X + b_r (docs/model.md step 5), A = ReLU(H + R) with step 4's
//! H = tanh(G_f) ⊙ σ(G_g), and the mean and 1/σ of A over the channels at each step
//! (step 6). Fused per node so that each node's A is built, activated and reduced while
//! it is in cache, with the nodes split over tasks at the paper's sizes. Step 6's affine
//! map is `layer_norm_dropout`'s.

// The LayerNorm loops index several per-channel tensors by the channel.
#![allow(clippy::needless_range_loop)]

use rayon::prelude::*;

use super::tape::{BlockTape, Work};
use super::Block;
use crate::model::native::{flushing_subnormals, gemm, lanes_sum, rows, transposed, View};
use multiversion::multiversion;

/// A = ReLU(H + R) `bt.act` `[N, C, steps]` and its mean and 1/σ over C, `bt.mean` and
/// `bt.rstd` `[N, steps]`.
#[multiversion(targets("x86_64+avx512f", "x86_64+avx2+fma"))]
pub(super) fn forward(b: &Block, p: &[Vec<f32>], x: &[f32], bt: &mut BlockTape) {
    let (n, t, c, ci) = (b.n, b.t, b.c, b.ci);
    let s = b.s;
    let (t0, steps) = (bt.t0, bt.steps);
    let wide = n * steps;
    let gated = s.gate.is_some();
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
    let g = &bt.g;
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
        // Contiguous runs of steps, so that the gate's exp and divisions vectorise.
        for (o, a) in a.chunks_mut(steps).enumerate() {
            let f = &g[o * wide + i * steps..][..steps];
            if gated {
                let q = &g[(c + o) * wide + i * steps..][..steps];
                for ((v, f), q) in a.iter_mut().zip(f).zip(q) {
                    *v = (*v + f * q).max(0.0);
                }
            } else {
                for (v, f) in a.iter_mut().zip(f) {
                    *v = (*v + f.max(0.0)).max(0.0);
                }
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

/// From dY (`w.dy`, after `layer_norm_dropout::backward`): the LayerNorm's backward with
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
