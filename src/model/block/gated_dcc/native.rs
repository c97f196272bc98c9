//! Step 4, the gated dilated causal convolution (docs/model.md eq. 30–31) on the block's
//! output steps, forward and backward: the unfolding of Z, [G_f; G_g] = [W_f; W_g]·col +
//! bias in one product, then tanh(G_f) and σ(G_g) and H = tanh(G_f) ⊙ σ(G_g)
//! (`iastgcn-t`: H = ReLU(G_f), no gate).

use crate::model::block::native::Block;
use crate::model::block::tape::{BlockTape, Work};
use crate::model::cpu::{gemm, lanes_sum, par_gemm, rows, sigmoid, tanh, transposed};
use multiversion::multiversion;

impl Block<'_> {
    /// Step 4's forward on this block (the step's `forward` below).
    pub(crate) fn gated_dcc_forward(&self, p: &[Vec<f32>], bt: &mut BlockTape) {
        forward(self, p, bt);
    }

    /// Step 4's backward on this block (the step's `backward` below).
    pub(crate) fn gated_dcc_backward(
        &self,
        p: &[Vec<f32>],
        bt: &BlockTape,
        grads: &mut [Vec<f32>],
        w: &mut Work,
    ) {
        backward(self, p, bt, grads, w);
    }
}

/// `bt.g` = [tanh(G_f); σ(G_g)] `[outs, N·steps]` from Z, keeping the unfolding `bt.col`
/// and the stacked weights `bt.wcat`.
#[multiversion(targets("x86_64+avx512f", "x86_64+avx2+fma"))]
pub(super) fn forward(b: &Block, p: &[Vec<f32>], bt: &mut BlockTape) {
    let (n, t, c, k) = (b.n, b.t, b.c, b.k);
    let s = b.s;
    // Unfold every node, then G = W·col + bias.
    let (t0, steps) = (bt.t0, bt.steps);
    let wide = n * steps;
    let d = s.dilation;
    let kept = bt.cols.len;
    for ch in 0..c {
        for lag in 0..k {
            let row = &mut bt.col[(ch * k + lag) * wide..][..wide];
            if bt.cols.taps {
                // One output step; Z `[N, taps, C]` holds lag's tap at kept − 1 − lag.
                for (i, v) in row.iter_mut().enumerate() {
                    *v = if lag < kept {
                        bt.z[(i * kept + kept - 1 - lag) * c + ch]
                    } else {
                        0.0
                    };
                }
                continue;
            }
            let shift = d * lag;
            let zeros = shift.saturating_sub(t0).min(steps);
            for (i, seg) in row.chunks_mut(steps).enumerate() {
                seg[..zeros].fill(0.0);
                if zeros < steps {
                    let from = t0 + zeros - shift;
                    seg[zeros..].copy_from_slice(&bt.z[(i * c + ch) * t + from..][..steps - zeros]);
                }
            }
        }
    }
    let ck = c * k;
    let biases = std::iter::once(s.filter.1).chain(s.gate.map(|g| g.1));
    let bias_rows = biases.flat_map(|i| p[i].iter());
    for (row, &bias) in bt.g.chunks_mut(wide).zip(bias_rows) {
        row.fill(bias);
    }
    let weights: &[f32] = match s.gate {
        Some((gate, _)) => {
            let (f, g) = bt.wcat.split_at_mut(c * ck);
            f.copy_from_slice(&p[s.filter.0]);
            g.copy_from_slice(&p[gate]);
            &bt.wcat
        }
        None => &p[s.filter.0],
    };
    par_gemm(
        b.threads,
        weights.len() / ck,
        ck,
        wide,
        rows(weights, ck),
        rows(&bt.col, wide),
        1.0,
        &mut bt.g,
        wide,
    );
    // The gate's activations, once over the whole of G (kept for the backward), and H
    // in the gate's pass.
    if s.gate.is_some() {
        let (f, q) = bt.g.split_at_mut(c * wide);
        for v in f.iter_mut() {
            *v = tanh(*v);
        }
        for ((q, h), f) in q.iter_mut().zip(bt.hidden.iter_mut()).zip(&*f) {
            *q = sigmoid(*q);
            *h = f * *q;
        }
    } else {
        for (h, f) in bt.hidden.iter_mut().zip(&bt.g) {
            *h = f.max(0.0);
        }
    }
}

/// From dH = dA (`w.da`, left by `residual_layer_norm::backward`): dG, the convolution
/// weights' and biases' gradients, dcol = [W_f; W_g]ᵀ·dG and its unfolding's adjoint
/// into dZ, then dG = dZ through Z's ReLU (`w.dz`, what step 3's backward starts from).
#[multiversion(targets("x86_64+avx512f", "x86_64+avx2+fma"))]
pub(super) fn backward(
    b: &Block,
    p: &[Vec<f32>],
    bt: &BlockTape,
    grads: &mut [Vec<f32>],
    w: &mut Work,
) {
    let (n, t, c, k) = (b.n, b.t, b.c, b.k);
    let s = b.s;
    let (t0, steps) = (bt.t0, bt.steps);
    let wide = n * steps;
    let da = &w.da[..n * c * steps];
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
    for (half, (wt, bias)) in convs.enumerate() {
        for (g, d) in grads[wt].iter_mut().zip(&dw[half * c * ck..][..c * ck]) {
            *g += d;
        }
        let dgh = &dg[half * c * wide..][..c * wide];
        for (g, row) in grads[bias].iter_mut().zip(dgh.chunks(wide)) {
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
    // (at the taps, Z `[N, taps, C]` holds lag's tap at taps − 1 − lag).
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
                for (a, v) in dst.iter_mut().zip(&seg[zeros..]) {
                    *a += v;
                }
            }
        }
    } // Z = ReLU(G) is step 3's: hand it dG, dZ through that ReLU. A select, not a
      // conditional store: the loop vectorises.
    for (g, &z) in dz.iter_mut().zip(&bt.z) {
        *g = if z > 0.0 { *g } else { 0.0 };
    }
}
