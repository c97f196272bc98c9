//! The IASTGCN variants, ST-GAT, the dense and recurrent baselines and ConvLSTM on the CPU
//! in f32, with no device: the inference forward, one window at a time (the controller's
//! latency path where the only adapter is a CPU, or there is none; [`super::Predictor`]
//! picks it on its own, docs/performance.md "The native CPU forward"), and training
//! (`train::Trainer` picks it on a CPU adapter, docs/performance.md "Native CPU
//! training").
//!
//! The ST blocks' steps are `model::block`'s (each step's `native.rs`, composed in
//! `block/native.rs`); the arithmetic is `model::cpu`'s. Files here: `forward.rs`
//! ([`NativeForward`]), `step.rs` ([`NativeTraining`]: a batch over threads, the loss,
//! Adam), and the flat head the baselines share. Each baseline's forward and backward
//! side by side are in its folder (`model::dense::native`: the dense layers,
//! `model::recurrent::native`: T-GCN and EAT-GCN's time loop, `model::conv_lstm::native`:
//! ConvLSTM's). Tested against the WGSL path and the f64 reference in
//! tests/native_forward.rs and tests/native_train.rs.

mod forward;
mod step;

use crate::model::cpu::{gemm, rows};
pub use forward::NativeForward;
pub use step::{NativeAdam, NativeStepShape, NativeTraining};

/// The flat head of the baselines that end in a state vector: ŷ[o] = b[o] + W[o]·h, with
/// `head` the (W `[O, |h|]`, b) slots in `params`.
pub(crate) fn flat_head(params: &[Vec<f32>], head: (usize, usize), h: &[f32], out: &mut [f32]) {
    let (w, b) = (&params[head.0], &params[head.1]);
    for ((o, row), b) in out.iter_mut().zip(w.chunks_exact(h.len())).zip(b) {
        *o = b + row.iter().zip(h).map(|(w, v)| w * v).sum::<f32>();
    }
}

/// The backward of [`flat_head`] from ∂ℒ/∂ŷ `dout`: adds ∂ℒ/∂W and ∂ℒ/∂b to `grads`
/// and writes ∂ℒ/∂h = Wᵀ·dout into `dh`.
pub(crate) fn flat_head_backward(
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
