//! The backward pass of one window from dL/dŷ, reading the [`Tape`] of its training
//! forward (`tape.rs`) and adding every parameter's gradient into `grads`. Step by step
//! the reverse of the forward, the same algebra as the f64 reference
//! (`model::reference`), with every contraction a `gemm` product (`super::gemm`).

// The LayerNorm loops index several per-channel tensors by the channel.
#![allow(clippy::needless_range_loop)]

use super::slots::{BlockSlots, Slots};
use super::tape::{BlockTape, Masks, Tape};
use super::{gemm, rows, sigmoid, tanh, transposed, View};
use crate::model::config::ModelConfig;
use crate::ops::dropout::{keep, Dropout};

/// Working memory of the backward pass, sized for the widest block.
pub(super) struct Work {
    /// dL/d(block output) and dL/d(block input), `[N, C_max, T]`, swapped per block.
    dy: Vec<f32>,
    dx: Vec<f32>,
    /// dA `[N, C, T]`, dG `[outs, N·T]`, dcol `[C·K, N·T]`, dZ `[N, C, T]`.
    da: Vec<f32>,
    dg: Vec<f32>,
    dcol: Vec<f32>,
    dz: Vec<f32>,
    /// dM and dX_t `[N, C_in, T]`.
    dm: Vec<f32>,
    dxt: Vec<f32>,
    /// dQ, dΨ, dS', dS, dσ `[N, N]` or `[T, T]`.
    dq: Vec<f32>,
    dpsi: Vec<f32>,
    dsp: Vec<f32>,
    dscore: Vec<f32>,
    dsig: Vec<f32>,
    /// dE' `[T, T]`.
    de: Vec<f32>,
    /// Attention lhs/rhs gradients `[T, N]`/`[N, T]`, and `[C_in, T]` or `[N, C_in]`.
    dlhs: Vec<f32>,
    drhs: Vec<f32>,
    dred: Vec<f32>,
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
            dcol: z(c * k * n * t),
            dz: z(n * c * t),
            dm: z(n * wide * t),
            dxt: z(n * wide * t),
            dq: z(n * n),
            dpsi: z(n * n),
            dsp: z(n * n),
            dscore: z(big * big),
            dsig: z(big * big),
            de: z(t * t),
            dlhs: z(t * n),
            drhs: z(n * t),
            // Also the graph attention's scratch (graph_attention::GatShape::work_len).
            dred: z((wide * big).max(n + 2 * c)),
        }
    }
}

/// Adds dL/dθ of one window to `grads` (in `param_specs` order) from `dout` = dL/dŷ
/// `[O]`, the tape of its forward on `x` and the same `masks`.
#[allow(clippy::too_many_arguments)]
pub(super) fn backward(
    cfg: &ModelConfig,
    basis: &[f32],
    slots: &Slots,
    p: &[Vec<f32>],
    x: &[f32],
    tape: &Tape,
    masks: Option<Masks>,
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
        let mask = masks.map(|m| (m.block(cfg, l), m.step));
        block(
            cfg,
            basis,
            &slots.blocks[l],
            p,
            input,
            &tape.blocks[l],
            mask,
            l > 0,
            grads,
            w,
        );
        std::mem::swap(&mut w.dy, &mut w.dx);
    }
}

/// dL/dθ of block `l` from `w.dy` (`[N, C, steps]`); dL/dX into `w.dx` when `need_dx`.
#[allow(clippy::too_many_arguments)]
fn block(
    cfg: &ModelConfig,
    basis: &[f32],
    s: &BlockSlots,
    p: &[Vec<f32>],
    x: &[f32],
    bt: &BlockTape,
    mask: Option<((Dropout, usize), u32)>,
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
    if let Some(((drop, offset), step)) = &mask {
        for i in 0..n {
            for o in 0..c {
                for tau in 0..steps {
                    let full = (i * c + o) * t + t0 + tau;
                    let v = &mut dy[(i * c + o) * steps + tau];
                    *v = if keep(drop, *step, offset + full) {
                        *v * scale
                    } else {
                        0.0
                    };
                }
            }
        }
    }
    let gamma = &p[s.gamma];
    let da = &mut w.da[..n * c * steps];
    let inv_c = 1.0 / c as f32;
    for i in 0..n {
        for tau in 0..steps {
            let j = i * steps + tau;
            let (mean, rstd) = (bt.mean[j], bt.rstd[j]);
            let (mut s1, mut s2) = (0f32, 0f32);
            for o in 0..c {
                let e = (i * c + o) * steps + tau;
                let xhat = (bt.act[e] - mean) * rstd;
                let g = dy[e];
                grads[s.gamma][o] += g * xhat;
                grads[s.beta][o] += g;
                let dxhat = g * gamma[o];
                s1 += dxhat;
                s2 += dxhat * xhat;
            }
            for o in 0..c {
                let e = (i * c + o) * steps + tau;
                let xhat = (bt.act[e] - mean) * rstd;
                let v = rstd * (dy[e] * gamma[o] - s1 * inv_c - xhat * s2 * inv_c);
                da[e] = if bt.act[e] > 0.0 { v } else { 0.0 };
            }
        }
    }
    // Step 5: R = W_r·X + b_r at the output steps (dR = dA).
    let dx = &mut w.dx[..n * ci * t];
    if need_dx {
        dx.fill(0.0);
    }
    let (res_w, res_b) = s.res;
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
            *g += row.iter().sum::<f32>();
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
                    let (th, sg) = (tanh(*f), sigmoid(*q));
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
    let ck = c * k;
    let dcol = &mut w.dcol[..ck * wide];
    let convs = std::iter::once(s.filter).chain(s.gate);
    for (half, (wt, b)) in convs.enumerate() {
        let dgh = &dg[half * c * wide..][..c * wide];
        gemm(
            c,
            wide,
            ck,
            rows(dgh, wide),
            transposed(&bt.col, wide),
            1.0,
            &mut grads[wt],
            ck,
        );
        for (g, row) in grads[b].iter_mut().zip(dgh.chunks(wide)) {
            *g += row.iter().sum::<f32>();
        }
        let beta = if half == 0 { 0.0 } else { 1.0 };
        gemm(
            ck,
            c,
            wide,
            transposed(&p[wt], ck),
            rows(dgh, wide),
            beta,
            dcol,
            wide,
        );
    }
    // The unfolding's adjoint: dZ[i][ch][t0 + τ − d·lag] += dcol[ch·K + lag][i·steps + τ];
    // then Z's ReLU.
    let dz = &mut w.dz[..n * c * t];
    dz.fill(0.0);
    let d = s.dilation;
    for ch in 0..c {
        for lag in 0..k {
            let row = &dcol[(ch * k + lag) * wide..][..wide];
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
    for (g, &z) in dz.iter_mut().zip(&bt.z) {
        if z <= 0.0 {
            *g = 0.0;
        }
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
    // Step 3: Z[i] = ReLU(Wᵀ·M[i]), M = Q·X_t.
    let dm = &mut w.dm[..n * ci * t];
    for i in 0..n {
        let mi = &bt.m[i * ci * t..][..ci * t];
        let dzi = &dz[i * c * t..][..c * t];
        gemm(
            ci,
            t,
            c,
            rows(mi, t),
            transposed(dzi, t),
            1.0,
            &mut grads[s.w],
            c,
        );
        gemm(
            ci,
            c,
            t,
            rows(&p[s.w], c),
            rows(dzi, t),
            0.0,
            &mut dm[i * ci * t..][..ci * t],
            t,
        );
    }
    let attends = s.temporal.is_some();
    let xt: &[f32] = if attends { &bt.xt } else { x };
    let dq = &mut w.dq;
    gemm(
        n,
        ci * t,
        n,
        rows(dm, ci * t),
        transposed(xt, ci * t),
        0.0,
        dq,
        n,
    );
    let dxt = &mut w.dxt[..n * ci * t];
    if attends || need_dx {
        gemm(
            n,
            n,
            ci * t,
            transposed(&bt.q, n),
            rows(dm, ci * t),
            0.0,
            dxt,
            ci * t,
        );
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
        *g += dpsi.iter().zip(b).map(|(a, b)| a * b).sum::<f32>();
    }
    if let (Some(ts), Some(ss)) = (s.temporal, s.spatial) {
        spatial_backward(n, ci, t, p, ss, bt, grads, w);
        temporal_backward(n, ci, t, p, ts, x, bt, need_dx, grads, w);
    } else if need_dx {
        for (a, b) in w.dx[..n * ci * t].iter_mut().zip(&w.dxt[..n * ci * t]) {
            *a += b;
        }
    }
}

/// The score gate S = V·σ(P + bias) of both attentions, backward: from dS (`w.dscore`,
/// `[len, len]`) adds dV and dbias, leaves dP in `w.dsig`.
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

/// Step 2 backward from dS' (`w.dsp`): adds its gradients and dL/dX_t into `w.dxt`.
#[allow(clippy::too_many_arguments)]
fn spatial_backward(
    n: usize,
    ci: usize,
    t: usize,
    p: &[Vec<f32>],
    ix: [usize; 5],
    bt: &BlockTape,
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
    // lhs = xw1·W2, xw1 = X_t·W1, rhs[m] = W3ᵀ·X_t[m].
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
    let xt = &bt.xt;
    let dxt = &mut w.dxt[..n * ci * t];
    gemm(
        1,
        n * ci,
        t,
        rows(dxw1, n * ci),
        rows(xt, t),
        1.0,
        &mut grads[w1],
        t,
    );
    gemm(n * ci, 1, t, rows(dxw1, 1), rows(&p[w1], t), 1.0, dxt, t);
    for m in 0..n {
        let dr = &drhs[m * t..][..t];
        let xm = &xt[m * ci * t..][..ci * t];
        gemm(
            1,
            t,
            ci,
            rows(dr, t),
            transposed(xm, t),
            1.0,
            &mut grads[w3],
            ci,
        );
        gemm(
            ci,
            1,
            t,
            rows(&p[w3], 1),
            rows(dr, t),
            1.0,
            &mut dxt[m * ci * t..][..ci * t],
            t,
        );
    }
}

/// Step 1 backward from dX_t (`w.dxt`): adds its gradients, and dL/dX into `w.dx` when
/// `need_dx`.
#[allow(clippy::too_many_arguments)]
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
    // X_t = X·(E' + I): dE' = Xᵀ·dX_t (dX gets dX_t + dX_t·E'ᵀ below).
    let de = &mut w.de[..t * t];
    gemm(
        t,
        n * ci,
        t,
        transposed(x, t),
        rows(&w.dxt[..n * ci * t], t),
        0.0,
        de,
        t,
    );
    // Softmax over each column: dE = E' ⊙ (dE' − Σ_u E'·dE').
    let ds = &mut w.dscore[..t * t];
    for col in 0..t {
        let dot: f32 = (0..t).map(|u| bt.e[u * t + col] * de[u * t + col]).sum();
        for u in 0..t {
            ds[u * t + col] = bt.e[u * t + col] * (de[u * t + col] - dot);
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
    let dxt = &w.dxt[..n * ci * t];
    let dx = &mut w.dx[..n * ci * t];
    for (a, b) in dx.iter_mut().zip(dxt) {
        *a += b;
    }
    gemm(n * ci, t, t, rows(dxt, t), transposed(&bt.e, t), 1.0, dx, t);
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
