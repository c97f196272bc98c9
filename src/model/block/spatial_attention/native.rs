//! Step 2, the spatial attention (docs/model.md eq. 32–34): S' from X_t, forward and
//! backward; step 3 folds it into Q = Ψ·(I + S'). Where X_t is kept at fewer
//! steps than T (the last block, `tape::Cols`), the attention reads X and E' instead:
//! X_t·W1 = X·v with v = (I + E')·W1, and W3ᵀ·X_t[m] = r[m]·(I + E') with
//! r[m] = W3ᵀ·X[m]. Both do nothing in the variants without attention.

use crate::model::block::native::{score_gate_backward, Block};
use crate::model::block::tape::{BlockTape, Work};
use crate::model::cpu::{gemm, rows, sigmoid, softmax_rows, transposed};
use multiversion::multiversion;

impl Block<'_> {
    /// Step 2's forward on this block (the step's `forward` below).
    pub(crate) fn spatial_attention_forward(&self, p: &[Vec<f32>], x: &[f32], bt: &mut BlockTape) {
        forward(self, p, x, bt);
    }

    /// Step 2's backward on this block (the step's `backward` below).
    pub(crate) fn spatial_attention_backward(
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

/// S' from X_t = X·(I + E') (`bt.xt`, or `x` and `bt.e` when X_t is kept at fewer steps
/// than T), keeping lhs, rhs, σ and S'.
#[multiversion(targets("x86_64+avx512f", "x86_64+avx2+fma"))]
pub(super) fn forward(b: &Block, p: &[Vec<f32>], x: &[f32], bt: &mut BlockTape) {
    let Some(ix) = b.s.spatial else {
        return;
    };
    let (n, ci, t) = (b.n, b.ci, b.t);
    let [w1, w2, w3, bs, vs] = ix.map(|i| &p[i][..]);
    // With X_t at every step, from X_t; else from X and E'.
    let every = !bt.cols.taps;
    let (src, w1v): (&[f32], &[f32]) = if every {
        (&bt.xt, w1)
    } else {
        bt.sv.copy_from_slice(w1);
        gemm(t, t, 1, rows(&bt.e, t), rows(w1, 1), 1.0, &mut bt.sv, 1);
        (x, &bt.sv)
    };
    gemm(
        n * ci,
        t,
        1,
        rows(src, t),
        rows(w1v, 1),
        0.0,
        &mut bt.xw1,
        1,
    );
    gemm(
        n,
        ci,
        t,
        rows(&bt.xw1, ci),
        rows(w2, t),
        0.0,
        &mut bt.s_lhs,
        t,
    );
    let r = if every { &mut bt.s_rhs } else { &mut bt.sr };
    for m in 0..n {
        let sm = &src[m * ci * t..][..ci * t];
        gemm(
            1,
            ci,
            t,
            rows(w3, ci),
            rows(sm, t),
            0.0,
            &mut r[m * t..][..t],
            t,
        );
    }
    if !every {
        bt.s_rhs.copy_from_slice(&bt.sr);
        gemm(
            n,
            t,
            t,
            rows(&bt.sr, t),
            rows(&bt.e, t),
            1.0,
            &mut bt.s_rhs,
            t,
        );
    }
    bt.s_sig.copy_from_slice(bs);
    gemm(
        n,
        t,
        n,
        rows(&bt.s_lhs, t),
        transposed(&bt.s_rhs, t),
        1.0,
        &mut bt.s_sig,
        n,
    );
    for v in bt.s_sig.iter_mut() {
        *v = sigmoid(*v);
    }
    gemm(n, n, n, rows(vs, n), rows(&bt.s_sig, n), 0.0, &mut bt.s, n);
    softmax_rows(&mut bt.s, n);
}

/// From dS' (`w.dsp`, left by `graph_conv::backward`): adds the attention's gradients
/// and writes `w.de`: its part of dL/dE' and dL/dX (into `w.dx` when `need_dx`) where
/// it read X and E', zero and dL/dX_t (into `w.dxt`) where it read X_t.
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
    let Some([w1, w2, w3, bs, vs]) = b.s.spatial else {
        return;
    };
    let (n, ci, t) = (b.n, b.ci, b.t);
    // Softmax over each row: dS = S' ⊙ (dS' − Σ_j S'·dS').
    for ((dr, sr), gr) in w.dscore[..n * n]
        .chunks_mut(n)
        .zip(bt.s.chunks(n))
        .zip(w.dsp.chunks(n))
    {
        let dot: f32 = sr.iter().zip(gr).map(|(s, g)| s * g).sum();
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
    // The attention read X_t (kept at every step), or X and E' through v and r;
    // d(what it read) goes to dX_t, for step 1's backward, or to dX.
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
