//! The ConvLSTM baseline of Table III (Shi et al. [25]; docs/model.md "Baselines"): an LSTM
//! whose gates are 2-D convolutions over the node × feature grid of every step, run over
//! the window's T steps, then the head on the last hidden state. With x_t the grid
//! `[B, 1, N, F]` and the state h, c `[B, C, N, F]` (C = `channels`, zero before step 0):
//!
//! ```text
//! z = Wx ∗ x_t + Wh ∗ h + b          (k×k "same" convolutions, 4C output channels: i f o g)
//! c' = σ(z_f) ⊙ c + σ(z_i) ⊙ tanh(z_g)        h' = σ(z_o) ⊙ tanh(c')
//! ```
//!
//! Each convolution is `ops::unfold2d` then one batched product; the cell is `ops::lstm`.
//! The time loop is one dispatch chain per step, every step's state on the device; the
//! backward pass runs through time in reverse, recomputing each step's unfoldings.
//!
//! This folder holds all of it: the device schedule in `wgsl.rs`, the f64 reference in
//! `reference.rs`, the native f32 forward and backward in `native.rs` (tested in
//! tests/model_conv_lstm.rs and tests/native_*.rs).

pub(crate) mod native;
pub mod reference;
pub(crate) mod wgsl;

use super::config::ModelConfig;

/// Forward FLOPs of ConvLSTM for `batch` windows: per step the two convolution products
/// (the input's from step 0, the state's from step 1), then the head.
pub fn forward_flops(config: &ModelConfig, batch: usize) -> f64 {
    let f = |x: usize| x as f64;
    let (b, c, kk) = (
        f(batch),
        f(config.channels),
        f(config.kernel * config.kernel),
    );
    let grid = f(config.nodes * config.features);
    let per_input = 2.0 * b * 4.0 * c * grid * kk;
    let t = f(config.window);
    t * per_input + (t - 1.0) * per_input * c + 2.0 * b * f(config.outputs) * c * grid
}
