//! Step 1, the temporal attention (docs/model.md eq. 35–37): E' from the block input X,
//! and X_t = X·(E' + I) at the steps the block keeps; forward and backward. Both do
//! nothing in the variants without attention (step 3 reads X there).

use crate::model::block::native::{score_gate_backward, Block};
use crate::model::block::tape::{BlockTape, Work};
use crate::model::cpu::{gemm, par_gemm, rows, sigmoid, softmax_columns, transposed};
use multiversion::multiversion;

impl Block<'_> {
    /// Step 1's forward on this block (the step's `forward` below).
    pub(crate) fn temporal_attention_forward(&self, p: &[Vec<f32>], x: &[f32], bt: &mut BlockTape) {
        forward(self, p, x, bt);
    }

    /// Step 1's backward on this block (the step's `backward` below).
    pub(crate) fn temporal_attention_backward(
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

/// E', and X_t = X·(E' + I) at the kept steps (`bt.cols`), keeping lhs, rhs, σ and E'.
#[multiversion(targets("x86_64+avx512f", "x86_64+avx2+fma"))]
pub(super) fn forward(b: &Block, p: &[Vec<f32>], x: &[f32], bt: &mut BlockTape) {
    let Some(ix) = b.s.temporal else {
        return;
    };
    let (n, ci, t) = (b.n, b.ci, b.t);
    let [u1, u2, u3, be, ve] = ix.map(|i| &p[i][..]);
    gemm(
        1,
        n,
        ci * t,
        rows(u1, n),
        rows(x, ci * t),
        0.0,
        &mut bt.xu1,
        ci * t,
    );
    gemm(
        t,
        ci,
        n,
        transposed(&bt.xu1, t),
        rows(u2, n),
        0.0,
        &mut bt.t_lhs,
        n,
    );
    for i in 0..n {
        let xi = &x[i * ci * t..][..ci * t];
        gemm(
            1,
            ci,
            t,
            rows(u3, ci),
            rows(xi, t),
            0.0,
            &mut bt.t_rhs[i * t..][..t],
            t,
        );
    }
    bt.t_sig.copy_from_slice(be);
    gemm(
        t,
        n,
        t,
        rows(&bt.t_lhs, n),
        rows(&bt.t_rhs, t),
        1.0,
        &mut bt.t_sig,
        t,
    );
    for v in bt.t_sig.iter_mut() {
        *v = sigmoid(*v);
    }
    gemm(t, t, t, rows(ve, t), rows(&bt.t_sig, t), 0.0, &mut bt.e, t);
    let (max, sum) = bt.e_cols.split_at_mut(t);
    softmax_columns(&mut bt.e, t, max, sum);
    let cols = bt.cols;
    cols.gather(x, t, &mut bt.xt);
    par_gemm(
        b.threads,
        n * ci,
        t,
        cols.len,
        rows(x, t),
        cols.of(&bt.e, t, false),
        1.0,
        &mut bt.xt,
        cols.len,
    );
}

/// From dX_t at the kept steps (`w.dxt`) and the spatial attention's part of dE'
/// (`w.de`): adds the attention's gradients, and dL/dX into `w.dx` when `need_dx`.
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
    let Some([u1, u2, u3, be, ve]) = b.s.temporal else {
        return;
    };
    let (n, ci, t) = (b.n, b.ci, b.t);
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
