//! The backward pass of one window from dL/dŷ, reading the [`Tape`] of its training
//! forward (`tape.rs`) and adding every parameter's gradient into `grads`. Step by step
//! the reverse of the forward, the same algebra as the f64 reference
//! (`model::reference`), with every contraction a `gemm` product (`super::gemm`).

// The LayerNorm loops index several per-channel tensors by the channel.
#![allow(clippy::needless_range_loop)]

use super::slots::{BlockSlots, Slots};
use super::tape::{BlockTape, Tape};
use super::{gemm, lanes_dot, lanes_sum, rows, transposed, View};
use crate::model::config::ModelConfig;
use multiversion::multiversion;

/// Working memory of the backward pass, sized for the widest block.
pub(super) struct Work {
    /// dL/d(block output) and dL/d(block input), `[N, C_max, T]`, swapped per block.
    dy: Vec<f32>,
    dx: Vec<f32>,
    /// dA `[N, C, T]`, dG `[outs, N·T]`, d[W_f; W_g] `[outs, C·K]`, dcol `[C·K, N·T]`,
    /// dZ `[N, C, T]`.
    da: Vec<f32>,
    dg: Vec<f32>,
    dwcat: Vec<f32>,
    dcol: Vec<f32>,
    dz: Vec<f32>,
    /// dM and dX_t `[N, C_in, T]`, and dX_t in the taps' layout `[N, K, C_in]`.
    dm: Vec<f32>,
    dxt: Vec<f32>,
    taps: Vec<f32>,
    /// dQ, dΨ, dS', dS, dσ `[N, N]` or `[T, T]`.
    dq: Vec<f32>,
    dpsi: Vec<f32>,
    dsp: Vec<f32>,
    dscore: Vec<f32>,
    dsig: Vec<f32>,
    /// dE' `[T, T]`.
    de: Vec<f32>,
    /// The spatial attention's dv `[T]` and dr `[N, T]` (its v = (I + E')·W1 and
    /// r[m] = W3ᵀ·X[m], see `tape.rs`).
    dv: Vec<f32>,
    dr: Vec<f32>,
    /// Attention lhs/rhs gradients `[T, N]`/`[N, T]`, and `[C_in, T]` or `[N, C_in]`.
    dlhs: Vec<f32>,
    drhs: Vec<f32>,
    dred: Vec<f32>,
    /// The LayerNorm backward's per-step channel sums `[2, T]` and a node's x̂ `[C, T]`.
    ln: Vec<f32>,
    xhat: Vec<f32>,
    /// Its dγ and dβ at each (channel, step) `[2, C, T]`.
    ln_params: Vec<f32>,
}

impl Work {
    pub fn new(cfg: &ModelConfig) -> Work {
        let (n, t, c, k) = (cfg.nodes, cfg.window, cfg.channels, cfg.kernel);
        let wide = c.max(cfg.features);
        let big = t.max(n);
        let z = |len: usize| vec![0f32; len];
        Work {
            dy: z(n * wide * t),
            dx: z(n * wide * t),
            da: z(n * c * t),
            dg: z(2 * c * n * t),
            dwcat: z(2 * c * c * k),
            dcol: z(c * k * n * t),
            dz: z(n * c * t),
            dm: z(n * wide * t),
            dxt: z(n * wide * t),
            taps: z(n * wide * k),
            dq: z(n * n),
            dpsi: z(n * n),
            dsp: z(n * n),
            dscore: z(big * big),
            dsig: z(big * big),
            de: z(t * t),
            dv: z(t),
            dr: z(n * t),
            dlhs: z(t * n),
            drhs: z(n * t),
            // Also the graph attention's scratch (graph_attention::GatShape::work_len).
            dred: z((wide * big).max(n + 2 * c)),
            ln: z(2 * t),
            xhat: z(c * t),
            ln_params: z(2 * c * t),
        }
    }
}

/// Adds dL/dθ of one window to `grads` (in `param_specs` order) from `dout` = dL/dŷ
/// `[O]` and the tape of its forward on `x` (its dropout masks too, when it drew them).
#[allow(clippy::too_many_arguments)]
pub(super) fn backward(
    cfg: &ModelConfig,
    basis: &[f32],
    slots: &Slots,
    p: &[Vec<f32>],
    x: &[f32],
    tape: &Tape,
    dout: &[f32],
    grads: &mut [Vec<f32>],
    w: &mut Work,
) {
    let (n, c, o) = (cfg.nodes, cfg.channels, cfg.outputs);
    let nc = n * c;
    // The head: ŷ = W_h·h + b.
    gemm(
        o,
        1,
        nc,
        rows(dout, 1),
        rows(&tape.h, nc),
        1.0,
        &mut grads[slots.head_weight],
        nc,
    );
    for (g, d) in grads[slots.head_bias].iter_mut().zip(dout) {
        *g += d;
    }
    gemm(
        nc,
        o,
        1,
        transposed(&p[slots.head_weight], nc),
        rows(dout, 1),
        0.0,
        &mut w.dy[..nc],
        1,
    );
    for l in (0..slots.blocks.len()).rev() {
        let input = if l == 0 { x } else { &tape.blocks[l - 1].y[..] };
        block(
            cfg,
            basis,
            &slots.blocks[l],
            p,
            input,
            &tape.blocks[l],
            tape.dropped,
            l > 0,
            grads,
            w,
        );
        std::mem::swap(&mut w.dy, &mut w.dx);
    }
}

/// dL/dθ of block `l` from `w.dy` (`[N, C, steps]`); dL/dX into `w.dx` when `need_dx`.
#[allow(clippy::too_many_arguments)]
#[multiversion(targets("x86_64+avx512f", "x86_64+avx2+fma"))]
fn block(
    cfg: &ModelConfig,
    basis: &[f32],
    s: &BlockSlots,
    p: &[Vec<f32>],
    x: &[f32],
    bt: &BlockTape,
    dropped: bool,
    need_dx: bool,
    grads: &mut [Vec<f32>],
    w: &mut Work,
) {
    let (n, t, c, k) = (cfg.nodes, cfg.window, cfg.channels, cfg.kernel);
    let ci = s.c_in;
    let (t0, steps) = (bt.t0, bt.steps);
    let wide = n * steps;
    // Step 7: the dropout mask, then step 6's LayerNorm and the ReLU before it.
    let scale = 1.0 / (1.0 - cfg.dropout as f32);
    let dy = &mut w.dy[..n * c * steps];
    if dropped {
        for (v, &k) in dy.iter_mut().zip(&bt.kept) {
            *v = if k { *v * scale } else { 0.0 };
        }
    }
    // Per node, row by row over the steps (contiguous, so the loops vectorise): the
    // channel sums s1 = Σ_o dx̂, s2 = Σ_o dx̂·x̂ at each step, then dA.
    let gamma = &p[s.gamma];
    let da = &mut w.da[..n * c * steps];
    let inv_c = 1.0 / c as f32;
    let (s1, s2) = w.ln.split_at_mut(steps);
    let s2 = &mut s2[..steps];
    // x̂ of the node's channels `[C, steps]`, from the first pass for the second.
    let xhat_node = &mut w.xhat[..c * steps];
    // dγ and dβ summed over nodes at each (channel, step), then over the steps.
    let (dgamma, dbeta) = w.ln_params.split_at_mut(c * steps);
    let dbeta = &mut dbeta[..c * steps];
    dgamma[..c * steps].fill(0.0);
    dbeta.fill(0.0);
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
            let dgamma = &mut dgamma[o * steps..][..steps];
            let dbeta = &mut dbeta[o * steps..][..steps];
            for (((((a1, a2), &g), &xh), dga), dbe) in s1
                .iter_mut()
                .zip(s2.iter_mut())
                .zip(g)
                .zip(&*xhat)
                .zip(dgamma.iter_mut())
                .zip(dbeta.iter_mut())
            {
                let dxhat = g * gamma[o];
                *a1 += dxhat;
                *a2 += dxhat * xh;
                *dga += g * xh;
                *dbe += g;
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
    for (o, (dga, dbe)) in dgamma.chunks(steps).zip(dbeta.chunks(steps)).enumerate() {
        grads[s.gamma][o] += lanes_sum(dga);
        grads[s.beta][o] += lanes_sum(dbe);
    }
    // Step 5: R = W_r·X + b_r at the output steps (dR = dA).
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
    // Step 4: dG from dH = dA, then the convolution weights and dcol = Wᵀ·dG.
    let gated = s.gate.is_some();
    let outs = if gated { 2 * c } else { c };
    let dg = &mut w.dg[..outs * wide];
    let (dg_f, dg_g) = dg.split_at_mut(c * wide);
    for i in 0..n {
        for o in 0..c {
            // Node i's steps of output channel o: dH, G_f, G_g and their gradients.
            let dh = &da[(i * c + o) * steps..][..steps];
            let at = o * wide + i * steps;
            let f = &bt.g[at..][..steps];
            let df = &mut dg_f[at..][..steps];
            if gated {
                let q = &bt.g[c * wide + at..][..steps];
                let dq = &mut dg_g[at..][..steps];
                for ((((df, dq), dh), f), q) in df.iter_mut().zip(dq).zip(dh).zip(f).zip(q) {
                    // The tape holds tanh(G_f) and σ(G_g).
                    let (th, sg) = (*f, *q);
                    *df = dh * sg * (1.0 - th * th);
                    *dq = dh * th * sg * (1.0 - sg);
                }
            } else {
                for ((df, dh), f) in df.iter_mut().zip(dh).zip(f) {
                    *df = if *f > 0.0 { *dh } else { 0.0 };
                }
            }
        }
    }
    // Both halves in one product each ([W_f; W_g] is on the tape): d[W_f; W_g] =
    // dG·colᵀ, dcol = [W_f; W_g]ᵀ·dG.
    let ck = c * k;
    let dw = &mut w.dwcat[..outs * ck];
    gemm(
        outs,
        wide,
        ck,
        rows(dg, wide),
        transposed(&bt.col, wide),
        0.0,
        dw,
        ck,
    );
    let convs = std::iter::once(s.filter).chain(s.gate);
    for (half, (wt, b)) in convs.enumerate() {
        for (g, d) in grads[wt].iter_mut().zip(&dw[half * c * ck..][..c * ck]) {
            *g += d;
        }
        let dgh = &dg[half * c * wide..][..c * wide];
        for (g, row) in grads[b].iter_mut().zip(dgh.chunks(wide)) {
            *g += lanes_sum(row);
        }
    }
    let weights: &[f32] = if gated { &bt.wcat } else { &p[s.filter.0] };
    let dcol = &mut w.dcol[..ck * wide];
    gemm(
        ck,
        outs,
        wide,
        transposed(weights, ck),
        rows(dg, wide),
        0.0,
        dcol,
        wide,
    );
    // The unfolding's adjoint: dZ[i][ch][t0 + τ − d·lag] += dcol[ch·K + lag][i·steps + τ]
    // (at the taps, Z `[N, taps, C]` holds lag's tap at taps − 1 − lag); then Z's ReLU.
    let (cols, kept) = (bt.cols, bt.cols.len);
    let dz = &mut w.dz[..n * c * kept];
    dz.fill(0.0);
    let d = s.dilation;
    for ch in 0..c {
        for lag in 0..k {
            let row = &dcol[(ch * k + lag) * wide..][..wide];
            if cols.taps {
                if lag < kept {
                    for (i, v) in row.iter().enumerate() {
                        dz[(i * kept + kept - 1 - lag) * c + ch] += v;
                    }
                }
                continue;
            }
            let shift = d * lag;
            let zeros = shift.saturating_sub(t0).min(steps);
            if zeros == steps {
                continue;
            }
            for (i, seg) in row.chunks(steps).enumerate() {
                let from = t0 + zeros - shift;
                let dst = &mut dz[(i * c + ch) * t + from..][..steps - zeros];
                for (a, b) in dst.iter_mut().zip(&seg[zeros..]) {
                    *a += b;
                }
            }
        }
    }
    // A select, not a conditional store: the loop vectorises.
    for (g, &z) in dz.iter_mut().zip(&bt.z) {
        *g = if z > 0.0 { *g } else { 0.0 };
    }
    if let (Some(shape), Some(tape)) = (s.gat, bt.gat.as_ref()) {
        // `st-gat`: the graph attention on the input.
        let dx = if need_dx {
            Some(&mut w.dx[..n * ci * t])
        } else {
            None
        };
        let dq = &mut w.dm[..n * c * t];
        let work = &mut w.dred[..shape.work_len()];
        shape.backward(p, basis, x, tape, dz, dq, dx, grads, work);
        return;
    }
    // Step 3: Z[i] = ReLU(Wᵀ·M[i]), M = Q·X_t; at the taps (in their layout) Z = ReLU(M·W):
    // dW += Mᵀ·dZ, dM = dZ·Wᵀ.
    let width = ci * kept;
    let dm = &mut w.dm[..n * width];
    if cols.taps {
        gemm(
            ci,
            n * kept,
            c,
            transposed(&bt.m, ci),
            rows(dz, c),
            1.0,
            &mut grads[s.w],
            c,
        );
        gemm(
            n * kept,
            c,
            ci,
            rows(dz, c),
            transposed(&p[s.w], c),
            0.0,
            dm,
            ci,
        );
    } else {
        for i in 0..n {
            let mi = &bt.m[i * width..][..width];
            let dzi = &dz[i * c * kept..][..c * kept];
            gemm(
                ci,
                kept,
                c,
                rows(mi, kept),
                transposed(dzi, kept),
                1.0,
                &mut grads[s.w],
                c,
            );
            gemm(
                ci,
                c,
                kept,
                rows(&p[s.w], c),
                rows(dzi, kept),
                0.0,
                &mut dm[i * width..][..width],
                kept,
            );
        }
    }
    let attends = s.temporal.is_some();
    let xt: &[f32] = if cols.taps {
        &bt.xtt
    } else if attends {
        &bt.xt
    } else {
        x
    };
    let dq = &mut w.dq;
    gemm(
        n,
        width,
        n,
        rows(dm, width),
        transposed(xt, width),
        0.0,
        dq,
        n,
    );
    if attends || need_dx {
        // dX_t = Qᵀ·dM, at the taps through their layout back to `[N, C_in, taps]`.
        let dxt = if cols.taps {
            &mut w.taps[..n * width]
        } else {
            &mut w.dxt[..n * width]
        };
        gemm(
            n,
            n,
            width,
            transposed(&bt.q, n),
            rows(dm, width),
            0.0,
            dxt,
            width,
        );
        if cols.taps {
            cols.transpose(n, ci, &w.taps, &mut w.dxt, true);
        }
    }
    // Q = Ψ·(I + S'): dΨ = dQ·(I + S')ᵀ, dS' = Ψᵀ·dQ (Q = Ψ without attention).
    let dpsi = &mut w.dpsi;
    dpsi.copy_from_slice(dq);
    if attends {
        gemm(n, n, n, rows(dq, n), transposed(&bt.s, n), 1.0, dpsi, n);
        gemm(
            n,
            n,
            n,
            transposed(&bt.psi, n),
            rows(dq, n),
            0.0,
            &mut w.dsp,
            n,
        );
    }
    // invariant: every block but st-gat's has gwc.theta (slots::Slots::new).
    let theta = s.theta.expect("a graph convolution has gwc.theta");
    for (g, b) in grads[theta].iter_mut().zip(basis.chunks(n * n)) {
        *g += lanes_dot(dpsi, b);
    }
    if let (Some(ts), Some(ss)) = (s.temporal, s.spatial) {
        spatial_backward(n, ci, t, p, ss, x, bt, need_dx, grads, w);
        temporal_backward(n, ci, t, p, ts, x, bt, need_dx, grads, w);
    } else if need_dx {
        cols.scatter_add(&w.dxt[..n * width], t, &mut w.dx[..n * ci * t]);
    }
}

/// x̂ = (a − mean)·rstd along one row of steps.
#[inline(always)]
fn normalised(act: &[f32], mean: &[f32], rstd: &[f32], xhat: &mut [f32]) {
    for (((x, a), m), r) in xhat.iter_mut().zip(act).zip(mean).zip(rstd) {
        *x = (a - m) * r;
    }
}

/// The score gate S = V·σ(P + bias) of both attentions, backward: from dS (`w.dscore`,
/// `[len, len]`) adds dV and dbias, leaves dP in `w.dsig`.
#[multiversion(targets("x86_64+avx512f", "x86_64+avx2+fma"))]
fn score_gate_backward(
    len: usize,
    v: &[f32],
    sig: &[f32],
    grads: &mut [Vec<f32>],
    iv: usize,
    ib: usize,
    w: &mut Work,
) {
    let ds = &w.dscore[..len * len];
    gemm(
        len,
        len,
        len,
        rows(ds, len),
        transposed(sig, len),
        1.0,
        &mut grads[iv],
        len,
    );
    let dsig = &mut w.dsig[..len * len];
    gemm(
        len,
        len,
        len,
        transposed(v, len),
        rows(ds, len),
        0.0,
        dsig,
        len,
    );
    for ((g, &s), db) in dsig.iter_mut().zip(sig).zip(grads[ib].iter_mut()) {
        *g *= s * (1.0 - s);
        *db += *g;
    }
}

/// Step 2 backward from dS' (`w.dsp`): adds its gradients and writes `w.de`: its part of
/// dL/dE' and dL/dX (into `w.dx` when `need_dx`) where it read X and E', zero and dL/dX_t
/// (into `w.dxt`) where it read X_t.
#[allow(clippy::too_many_arguments)]
#[multiversion(targets("x86_64+avx512f", "x86_64+avx2+fma"))]
fn spatial_backward(
    n: usize,
    ci: usize,
    t: usize,
    p: &[Vec<f32>],
    ix: [usize; 5],
    x: &[f32],
    bt: &BlockTape,
    need_dx: bool,
    grads: &mut [Vec<f32>],
    w: &mut Work,
) {
    let [w1, w2, w3, bs, vs] = ix;
    // Softmax over each row: dS = S' ⊙ (dS' − Σ_j S'·dS').
    for ((dr, sr), gr) in w.dscore[..n * n]
        .chunks_mut(n)
        .zip(bt.s.chunks(n))
        .zip(w.dsp.chunks(n))
    {
        let dot: f32 = sr.iter().zip(gr).map(|(a, b)| a * b).sum();
        for ((d, s), g) in dr.iter_mut().zip(sr).zip(gr) {
            *d = s * (g - dot);
        }
    }
    score_gate_backward(n, &p[vs], &bt.s_sig, grads, vs, bs, w);
    // P = lhs·rhsᵀ.
    let dp = &w.dsig[..n * n];
    let dlhs = &mut w.dlhs[..n * t];
    gemm(n, n, t, rows(dp, n), rows(&bt.s_rhs, t), 0.0, dlhs, t);
    let drhs = &mut w.drhs[..n * t];
    gemm(n, n, t, transposed(dp, n), rows(&bt.s_lhs, t), 0.0, drhs, t);
    // lhs = xw1·W2, xw1 = X·v, rhs = r·(I + E').
    gemm(
        ci,
        n,
        t,
        transposed(&bt.xw1, ci),
        rows(dlhs, t),
        1.0,
        &mut grads[w2],
        t,
    );
    let dxw1 = &mut w.dred[..n * ci];
    gemm(
        n,
        t,
        ci,
        rows(dlhs, t),
        transposed(&p[w2], t),
        0.0,
        dxw1,
        ci,
    );
    // The attention read X_t (kept at every step), or X and E' through v and r (see
    // `tape.rs`); d(what it read) goes to dX_t, for step 1's backward, or to dX.
    let every = !bt.cols.taps;
    let (src, w1v): (&[f32], &[f32]) = if every { (&bt.xt, &p[w1]) } else { (x, &bt.sv) };
    let mut dsrc = if every {
        Some(&mut w.dxt[..n * ci * t])
    } else if need_dx {
        Some(&mut w.dx[..n * ci * t])
    } else {
        None
    };
    let de = &mut w.de[..t * t];
    if every {
        // xw1 = X_t·W1; step 1's backward adds all of dE'.
        gemm(
            1,
            n * ci,
            t,
            rows(dxw1, n * ci),
            rows(src, t),
            1.0,
            &mut grads[w1],
            t,
        );
        de.fill(0.0);
    } else {
        // xw1 = X·v, v = (I + E')·W1: dv = Xᵀ·dxw1, dW1 += dv + E'ᵀ·dv, dE' = dv·W1ᵀ;
        // rhs = r·(I + E'): dE' += rᵀ·drhs.
        let dv = &mut w.dv[..t];
        gemm(1, n * ci, t, rows(dxw1, n * ci), rows(x, t), 0.0, dv, t);
        for (g, d) in grads[w1].iter_mut().zip(dv.iter()) {
            *g += d;
        }
        gemm(
            t,
            t,
            1,
            transposed(&bt.e, t),
            rows(dv, 1),
            1.0,
            &mut grads[w1],
            1,
        );
        gemm(t, 1, t, rows(dv, 1), rows(&p[w1], t), 0.0, de, t);
        gemm(t, n, t, transposed(&bt.sr, t), rows(drhs, t), 1.0, de, t);
    }
    if let Some(d) = dsrc.as_deref_mut() {
        gemm(n * ci, 1, t, rows(dxw1, 1), rows(w1v, t), 1.0, d, t);
    }
    // rhs[m] = W3ᵀ·src[m] (times (I + E') when from X: dr = drhs + drhs·E'ᵀ).
    let dr: &[f32] = if every {
        drhs
    } else {
        let dr = &mut w.dr[..n * t];
        dr.copy_from_slice(drhs);
        gemm(n, t, t, rows(drhs, t), transposed(&bt.e, t), 1.0, dr, t);
        dr
    };
    for m in 0..n {
        let drm = &dr[m * t..][..t];
        let sm = &src[m * ci * t..][..ci * t];
        gemm(
            1,
            t,
            ci,
            rows(drm, t),
            transposed(sm, t),
            1.0,
            &mut grads[w3],
            ci,
        );
        if let Some(d) = dsrc.as_deref_mut() {
            gemm(
                ci,
                1,
                t,
                rows(&p[w3], 1),
                rows(drm, t),
                1.0,
                &mut d[m * ci * t..][..ci * t],
                t,
            );
        }
    }
}

/// Step 1 backward from dX_t at the kept steps (`w.dxt`) and the spatial attention's
/// part of dE' (`w.de`): adds its gradients, and dL/dX into `w.dx` when `need_dx`.
#[allow(clippy::too_many_arguments)]
#[multiversion(targets("x86_64+avx512f", "x86_64+avx2+fma"))]
fn temporal_backward(
    n: usize,
    ci: usize,
    t: usize,
    p: &[Vec<f32>],
    ix: [usize; 5],
    x: &[f32],
    bt: &BlockTape,
    need_dx: bool,
    grads: &mut [Vec<f32>],
    w: &mut Work,
) {
    let [u1, u2, u3, be, ve] = ix;
    // X_t = X[:, cols] + X·E'[:, cols]: dE'[:, cols] += Xᵀ·dX_t (dX gets dX_t + dX_t·
    // E'[:, cols]ᵀ below).
    let cols = bt.cols;
    let width = ci * cols.len;
    let de = &mut w.de[..t * t];
    let part = &mut w.dscore[..t * cols.len];
    gemm(
        t,
        n * ci,
        cols.len,
        transposed(x, t),
        rows(&w.dxt[..n * width], cols.len),
        0.0,
        part,
        cols.len,
    );
    cols.scatter_add(part, t, de);
    // Softmax over each column: dE = E' ⊙ (dE' − Σ_u E'·dE').
    // Row by row, so that the loops run along contiguous rows (each column's dot still
    // sums in row order).
    let ds = &mut w.dscore[..t * t];
    let dot = &mut w.ln[..t];
    dot.fill(0.0);
    for (e, d) in bt.e.chunks(t).zip(de.chunks(t)) {
        for ((s, e), d) in dot.iter_mut().zip(e).zip(d) {
            *s += e * d;
        }
    }
    for ((out, e), d) in ds.chunks_mut(t).zip(bt.e.chunks(t)).zip(de.chunks(t)) {
        for (((o, e), d), s) in out.iter_mut().zip(e).zip(d).zip(dot.iter()) {
            *o = e * (d - s);
        }
    }
    score_gate_backward(t, &p[ve], &bt.t_sig, grads, ve, be, w);
    // P = lhs·rhs (lhs [T, N], rhs [N, T]).
    let dp = &w.dsig[..t * t];
    let dlhs = &mut w.dlhs[..t * n];
    gemm(t, t, n, rows(dp, t), transposed(&bt.t_rhs, t), 0.0, dlhs, n);
    let drhs = &mut w.drhs[..n * t];
    gemm(n, t, t, transposed(&bt.t_lhs, n), rows(dp, t), 0.0, drhs, t);
    // lhs = xu1ᵀ·U2, xu1 = Σ_n U1[n]·X[n], rhs[n] = U3ᵀ·X[n].
    gemm(
        ci,
        t,
        n,
        rows(&bt.xu1, t),
        rows(dlhs, n),
        1.0,
        &mut grads[u2],
        n,
    );
    let dxu1 = &mut w.dred[..ci * t];
    gemm(ci, n, t, rows(&p[u2], n), transposed(dlhs, n), 0.0, dxu1, t);
    gemm(
        n,
        ci * t,
        1,
        rows(x, ci * t),
        rows(dxu1, 1),
        1.0,
        &mut grads[u1],
        1,
    );
    for i in 0..n {
        let xi = &x[i * ci * t..][..ci * t];
        gemm(
            1,
            t,
            ci,
            rows(&drhs[i * t..][..t], t),
            transposed(xi, t),
            1.0,
            &mut grads[u3],
            ci,
        );
    }
    if !need_dx {
        return;
    }
    let dxt = &w.dxt[..n * width];
    let dx = &mut w.dx[..n * ci * t];
    cols.scatter_add(dxt, t, dx);
    gemm(
        n * ci,
        cols.len,
        t,
        rows(dxt, cols.len),
        cols.of(&bt.e, t, true),
        1.0,
        dx,
        t,
    );
    gemm(
        n,
        1,
        ci * t,
        rows(&p[u1], 1),
        rows(dxu1, ci * t),
        1.0,
        dx,
        ci * t,
    );
    for i in 0..n {
        let dr = &drhs[i * t..][..t];
        gemm(
            ci,
            1,
            t,
            rows(&p[u3], 1),
            rows(dr, t),
            1.0,
            &mut dx[i * ci * t..][..ci * t],
            t,
        );
    }
}
