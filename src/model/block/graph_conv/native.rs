//! Step 3, the graph wavelet convolution (docs/model.md eq. 29), forward and backward:
//! Ψ = Σ_k θ_k basis_k, Q = Ψ·(I + S') with the spatial attention (Ψ without), M = Q·X_t
//! and Z[i] = ReLU(Wᵀ·M[i]); at the taps of the last block (`tape::Cols`), in their
//! layout, M = Q·X_t and Z = ReLU(M·W) for all nodes at once. X_t is step 1's, or X
//! without attention. (`st-gat`'s graph attention takes its place: `graph_attention/`.)

use crate::model::block::native::{for_each_node, Block};
use crate::model::block::tape::{BlockTape, Work};
use crate::model::cpu::{gemm, lanes_dot, rows, transposed};
use multiversion::multiversion;

impl Block<'_> {
    /// Step 3's forward on this block (the step's `forward` below).
    pub(crate) fn graph_conv_forward(&self, p: &[Vec<f32>], x: &[f32], bt: &mut BlockTape) {
        forward(self, p, x, bt);
    }

    /// Step 3's backward on this block (the step's `backward` below).
    pub(crate) fn graph_conv_backward(
        &self,
        p: &[Vec<f32>],
        x: &[f32],
        bt: &BlockTape,
        need_dx: bool,
        grads: &mut [Vec<f32>],
        w: &mut Work,
    ) {
        backward(self, p, x, bt, need_dx, grads, w);
    }
}

/// Z `[N, C, cols.len]` (at the taps `[N, cols.len, C]`), keeping Ψ, Q and M.
#[multiversion(targets("x86_64+avx512f", "x86_64+avx2+fma"))]
pub(super) fn forward(b: &Block, p: &[Vec<f32>], x: &[f32], bt: &mut BlockTape) {
    let s = b.s;
    let (n, ci, t, c) = (b.n, b.ci, b.t, b.c);
    let split = b.node_tasks(c * ci * t);
    // invariant: every block but st-gat's has gwc.theta (slots::Slots::new).
    let theta = s.theta.expect("a graph convolution has gwc.theta");
    bt.psi.fill(0.0);
    for (theta, basis) in p[theta].iter().zip(b.basis.chunks(n * n)) {
        for (v, basis) in bt.psi.iter_mut().zip(basis) {
            *v += theta * basis;
        }
    }
    let kept = bt.cols.len;
    if s.temporal.is_some() && s.spatial.is_some() {
        bt.q.copy_from_slice(&bt.psi);
        gemm(n, n, n, rows(&bt.psi, n), rows(&bt.s, n), 1.0, &mut bt.q, n);
    } else {
        // Without attention, X_t = X (at the taps, gathered).
        bt.q.copy_from_slice(&bt.psi);
        if bt.cols.taps {
            bt.cols.gather(x, t, &mut bt.xt);
        }
    }
    let width = ci * kept;
    let w = &p[s.w];
    if bt.cols.taps {
        // At the taps, in their layout: M = Q·X_t, Z = ReLU(M·W), `[N·taps, ·]`.
        bt.cols.transpose(n, ci, &bt.xt, &mut bt.xtt, false);
        gemm(
            n,
            n,
            width,
            rows(&bt.q, n),
            rows(&bt.xtt, width),
            0.0,
            &mut bt.m,
            width,
        );
        gemm(
            n * kept,
            ci,
            c,
            rows(&bt.m, ci),
            rows(w, c),
            0.0,
            &mut bt.z,
            c,
        );
        for v in bt.z.iter_mut() {
            *v = v.max(0.0);
        }
        return;
    }
    let xt: &[f32] = if s.temporal.is_some() { &bt.xt } else { x };
    // M = Q·X_t, Z[i] = ReLU(Wᵀ·M[i]).
    gemm(
        n,
        n,
        width,
        rows(&bt.q, n),
        rows(xt, width),
        0.0,
        &mut bt.m,
        width,
    );
    let mix = &bt.m;
    for_each_node(split, &mut bt.z, c * kept, |i, zi| {
        let mi = &mix[i * width..][..width];
        gemm(c, ci, kept, transposed(w, c), rows(mi, kept), 0.0, zi, kept);
        for v in zi.iter_mut() {
            *v = v.max(0.0);
        }
    });
}

/// From dG (`w.dz`, left by `gated_dcc::backward` past Z's ReLU): dW and dθ; dS'
/// (`w.dsp`) and dX_t (`w.dxt`, at the kept steps) for the attentions' backward, or
/// without attention dX_t added into `w.dx` when `need_dx` (`st-gat`: its graph
/// attention's gradients and dX).
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
    let (n, ci, t, c) = (b.n, b.ci, b.t, b.c);
    let s = b.s;
    let (cols, kept) = (bt.cols, bt.cols.len);
    // dG: dZ through Z's ReLU, which step 4's backward applied.
    let dz = &w.dz[..n * c * kept];
    // Z[i] = ReLU(Wᵀ·M[i]), M = Q·X_t; at the taps (in their layout) Z = ReLU(M·W):
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
    for (g, basis) in grads[theta].iter_mut().zip(b.basis.chunks(n * n)) {
        *g += lanes_dot(dpsi, basis);
    }
    if !(s.temporal.is_some() && s.spatial.is_some()) && need_dx {
        // Without attention X_t = X: dX += dX_t.
        cols.scatter_add(&w.dxt[..n * width], t, &mut w.dx[..n * ci * t]);
    }
}
