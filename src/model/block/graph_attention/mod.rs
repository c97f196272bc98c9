//! `st-gat`'s step 3, in place of the graph convolution: Q = Wᵀ·X per node, then on every
//! head and step a graph attention over the graph's edges, e_ij = a_src·q_i + a_dst·q_j,
//! α_i = softmax over j of LeakyReLU(e_ij), Z_i = ReLU(Σ_j α_ij·q_j) (the kernel and its
//! f64 reference: `graph_attention::kernel`).
//!
//! The contract, per window, on every backend:
//!
//! - reads the block input X `[N, C_in, T]`, the graph's edges (its basis, > 0.5),
//!   `gat.W` `[C_in, C]`, `gat.a_src` and `gat.a_dst` `[C]`;
//! - hands step 4 Z `[N, C, T]`;
//! - keeps for its backward Q `[N, C, T]`, α `[T, heads, N, N]` and Z (the native path
//!   also the scores before the LeakyReLU and each node's two score terms);
//! - backward: from dG, the gradient past Z's ReLU (step 4's backward applies it), into
//!   the three parameters' gradients and dX, added.
//!
//! Its test runs in `graph_conv/tests.rs`, with the graph convolution's.

pub mod kernel;
#[cfg(test)]
mod kernel_tests;
pub(crate) mod native;
pub(crate) mod reference;
pub(crate) mod wgsl;
