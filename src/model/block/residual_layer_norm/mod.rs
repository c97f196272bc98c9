//! Steps 5–7 of docs/model.md: the residual R = W_r·X + b_r and A = ReLU(H + R) (step
//! 5), the LayerNorm over channels Y = γ·(A − μ)/σ + β (step 6), and in training the
//! inverted dropout (step 7), whose mask is drawn by the device's hash
//! (`dropout_kernel::keep`) on every backend. In the last block it runs at the last step
//! only, and its output is the head's input.
//!
//! The contract, per window, on every backend:
//!
//! - reads H `[N, C, steps]` (step 4's), the block input X `[N, C_in, T]`, `res.weight`
//!   `[C, C_in]`, `res.bias`, `ln.gamma`, `ln.beta` `[C]`, and in training the block's
//!   dropout and the optimiser step;
//! - hands on the block output Y `[N, C, steps]`;
//! - keeps for its backward A `[N, C, steps]`, its mean and 1/σ `[N, steps]` (and the
//!   native path the dropout's mask);
//! - backward: from dY into the four parameters' gradients, dH (the gradient past A's
//!   ReLU, step 4's input) and dX, which it starts (the earlier steps add to it).
//!
//! Both backends fuse: the device's LayerNorm kernels apply the dropout; the native path
//! runs two passes, R, A and the statistics per node, then the affine map with the
//! dropout.

pub mod dropout_kernel;
#[cfg(test)]
mod kernel_tests;
pub mod layer_norm_kernel;
pub(crate) mod native;
pub(crate) mod reference;
#[cfg(test)]
pub(super) mod tests;
pub(crate) mod wgsl;
