//! The head in f32 on the CPU, one window: ŷ = W·h + b and its backward. The ST networks'
//! runs through the product kernels ([`forward`], [`backward`]); the recurrent baselines'
//! and ConvLSTM's row by row ([`forward_rows`], [`backward_rows`]), as each was written
//! first (the two sum in different orders, and each family's native training keeps its
//! bits).

use crate::model::cpu::{gemm, rows, transposed};

/// ŷ = W·h + b for one window, `head` the (W `[O, |h|]`, b) slots in `params`.
pub(crate) fn forward(params: &[Vec<f32>], head: (usize, usize), h: &[f32], out: &mut [f32]) {
    let (o, width) = (out.len(), h.len());
    out.copy_from_slice(&params[head.1]);
    gemm(
        o,
        width,
        1,
        rows(&params[head.0], width),
        rows(h, 1),
        1.0,
        out,
        1,
    );
}

/// The backward of [`forward`] from ∂ℒ/∂ŷ `dout`: adds ∂ℒ/∂W and ∂ℒ/∂b to `grads` and
/// writes ∂ℒ/∂h = Wᵀ·dout into `dh`.
pub(crate) fn backward(
    params: &[Vec<f32>],
    head: (usize, usize),
    h: &[f32],
    dout: &[f32],
    grads: &mut [Vec<f32>],
    dh: &mut [f32],
) {
    let (o, width) = (dout.len(), h.len());
    gemm(
        o,
        1,
        width,
        rows(dout, 1),
        rows(h, width),
        1.0,
        &mut grads[head.0],
        width,
    );
    for (g, d) in grads[head.1].iter_mut().zip(dout) {
        *g += d;
    }
    gemm(
        width,
        o,
        1,
        transposed(&params[head.0], width),
        rows(dout, 1),
        0.0,
        dh,
        1,
    );
}

/// The flat head of the baselines that end in a state vector: ŷ[o] = b[o] + W[o]·h, with
/// `head` the (W `[O, |h|]`, b) slots in `params`.
pub(crate) fn forward_rows(params: &[Vec<f32>], head: (usize, usize), h: &[f32], out: &mut [f32]) {
    let (w, b) = (&params[head.0], &params[head.1]);
    for ((o, row), b) in out.iter_mut().zip(w.chunks_exact(h.len())).zip(b) {
        *o = b + row.iter().zip(h).map(|(w, v)| w * v).sum::<f32>();
    }
}

/// The backward of [`forward_rows`] from ∂ℒ/∂ŷ `dout`: adds ∂ℒ/∂W and ∂ℒ/∂b to `grads`
/// and writes ∂ℒ/∂h = Wᵀ·dout into `dh`.
pub(crate) fn backward_rows(
    params: &[Vec<f32>],
    head: (usize, usize),
    h: &[f32],
    dout: &[f32],
    grads: &mut [Vec<f32>],
    dh: &mut [f32],
) {
    let (w, b, m) = (head.0, head.1, h.len());
    for (o, &g) in dout.iter().enumerate() {
        grads[b][o] += g;
        for (dw, v) in grads[w][o * m..][..m].iter_mut().zip(h) {
            *dw += g * v;
        }
    }
    let outputs = dout.len();
    gemm(
        1,
        outputs,
        m,
        rows(dout, outputs),
        rows(&params[w], m),
        0.0,
        dh,
        m,
    );
}
