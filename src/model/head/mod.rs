//! The head of docs/model.md ("Head"): ŷ = h·Wᵀ + b, one linear map from the network's
//! last features to the six pose errors, shared by the ST networks and the recurrent
//! baselines (the dense baselines end in a layer of their own).
//!
//! The contract, per batch, on every backend:
//!
//! - reads h `[B, width]` (the ST networks: the last block's output at the last step,
//!   width N·C; T-GCN and EAT-GCN: the last state or the attention's context, N·H;
//!   ConvLSTM: the last hidden state), `head.weight` `[O, width]` and `head.bias` `[O]`;
//! - hands the loss ŷ `[B, O]`;
//! - keeps nothing for its backward but h, which its caller holds;
//! - backward: from dŷ into the two parameters' gradients, and dh, overwritten.
//!
//! `reference.rs` (f64; the ST networks' head reads the last step of Y_L itself),
//! `wgsl.rs` (a product and a bias, the shared ops), `native.rs` (one window in f32),
//! `tests.rs` (the three on random cases).

pub(crate) mod native;
pub(crate) mod reference;
#[cfg(test)]
mod tests;
pub(crate) mod wgsl;
