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
//! Adam), `cores.rs` (how many threads a pass may use when jobs share the machine).
//! Each baseline's forward and backward
//! side by side are in its folder (`model::dense::native`: the dense layers,
//! `model::recurrent::native`: T-GCN and EAT-GCN's time loop, `model::conv_lstm::native`:
//! ConvLSTM's). Tested against the WGSL path and the f64 reference in
//! tests/native_forward.rs and tests/native_train.rs.

pub mod cores;
mod forward;
mod step;

pub use forward::NativeForward;
pub use step::{NativeAdam, NativeStepShape, NativeTraining};
