//! One ST block of docs/model.md ("One ST block"), step by step: each step is a folder
//! that holds all of it, its contract in `mod.rs`, its f64 reference (`reference.rs`,
//! forward and backward), its WGSL schedule (`wgsl.rs`: the launches of its kernels, whose
//! shaders sit in `shaders/` under the step's name or the shared kernel's), its native
//! f32 implementation (`native.rs`) and its test (`tests.rs`), which puts one random case
//! through the three and names the step and the backend that broke (`every_step.rs`
//! drives the steps' `testing::StepTest`s, and checks each reference against finite
//! differences). A kernel that only one step launches is that step's too: its launcher
//! and the kernel's own f64 reference in `kernel.rs` (`layer_norm_kernel.rs` and
//! `dropout_kernel.rs` for steps 5–7), its tests on the device in `kernel_tests.rs`;
//! [`shaders`] and [`uniforms`] list them.
//!
//! | step | docs/model.md |
//! |---|---|
//! | `temporal_attention` | 1: E' and X_t = X·(E' + I) |
//! | `spatial_attention` | 2: S' |
//! | `graph_conv` | 3: Ψ, Q = Ψ·(I + S'), M = Q·X_t, Z = ReLU(Wᵀ·M) |
//! | `graph_attention` | 3 of `st-gat`: Q = Wᵀ·X, α, Z = ReLU(Σ_j α_ij Q_j) |
//! | `gated_dcc` | 4: the unfolding, G_f and G_g with their biases, H = tanh(G_f) ⊙ σ(G_g) |
//! | `residual_layer_norm` | 5–7: A = ReLU(H + R), the LayerNorm, the dropout |
//!
//! Each backend composes the steps in its own file, forward in order and backward in
//! reverse (as llm.c's `gpt2_backward` reads `gpt2_forward` backwards), calling each
//! step as a method of its block named `<step>_forward` / `<step>_backward`:
//! `wgsl.rs` (the device buffers of one block and its schedule), `native.rs` (one window
//! on the CPU, with `tape.rs`, what its forward keeps, and `slots.rs`, where each tensor
//! sits in the parameter list) and `reference.rs` (the f64 block, with `exact.rs`, its
//! shapes and parameters). `testing.rs` holds what the step tests share.
//!
//! To add a step: a folder with the five files (and `kernel.rs` for a kernel of its own) (its `StepTest` listed in
//! `every_step.rs`), its methods called from the three
//! compositions, its saved tensors in `wgsl.rs`'s `Block`, `tape.rs`'s `BlockTape` and
//! `reference.rs`'s `BlockTape`, and its row in the table above and in
//! docs/architecture.md.

#[cfg(test)]
mod every_step;
pub(crate) mod exact;
pub(crate) mod native;
pub(crate) mod reference;
pub(crate) mod slots;
pub(crate) mod tape;
#[cfg(test)]
mod testing;
pub(crate) mod wgsl;

pub mod gated_dcc;
pub mod graph_attention;
pub(crate) mod graph_conv;
pub mod residual_layer_norm;
pub(crate) mod spatial_attention;
pub(crate) mod temporal_attention;

use crate::gpu::{Shader, Uniform, UniformLayout};

/// The shaders of the steps' own kernels, for validation (the shared ops':
/// [`crate::ops::shaders`]).
pub fn shaders() -> [&'static Shader; 4] {
    [
        &gated_dcc::kernel::SHADER,
        &graph_attention::kernel::SHADER,
        &residual_layer_norm::dropout_kernel::SHADER,
        &residual_layer_norm::layer_norm_kernel::SHADER,
    ]
}

/// The uniform blocks of the steps' own kernels on the Rust side (the shared ops':
/// [`crate::ops::uniforms`]), for the test that compares each with its WGSL struct.
pub fn uniforms() -> Vec<UniformLayout> {
    vec![
        gated_dcc::kernel::UnfoldParams::layout(),
        gated_dcc::kernel::GateParams::layout(),
        graph_attention::kernel::Params::layout(),
        residual_layer_norm::dropout_kernel::Params::layout(),
        residual_layer_norm::layer_norm_kernel::Params::layout(),
    ]
}
