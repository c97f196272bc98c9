//! Step 4 of docs/model.md, the gated dilated causal convolution (eq. 30–31): the
//! unfolding of Z over K taps d apart, G_f = W_f·col + b_f and G_g = W_g·col + b_g, and
//! H = tanh(G_f) ⊙ σ(G_g) (`iastgcn-t`: the plain convolution, H = ReLU(G_f)). In the
//! last block it runs at the last step only, the one the head reads.
//!
//! The contract, per window, on every backend:
//!
//! - reads Z `[N, C, T]` (step 3's), `tcn.filter.weight` `[C, C, K]` and its bias `[C]`,
//!   and the gate's (gated variants);
//! - hands step 5 H `[N, C, steps]` (steps = T, or 1 in the last block);
//! - keeps for its backward the unfolding `[C·K, N·steps]` and G_f and G_g (the native
//!   tape holds them after their activations, tanh(G_f) and σ(G_g));
//! - backward: from dH (step 5's) into the four parameters' gradients, and dG = dZ
//!   through Z's ReLU (step 3's activation: the device fuses its mask into the
//!   unfolding's backward, the native path applies it to dZ), which step 3's backward
//!   starts from.

pub mod kernel;
#[cfg(test)]
mod kernel_tests;
pub(crate) mod native;
pub(crate) mod reference;
#[cfg(test)]
pub(super) mod tests;
pub(crate) mod wgsl;
