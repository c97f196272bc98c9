//! IASTGCN: predicting the pose residual errors of an optical-polishing hybrid robot with
//! an interpretable adaptive spatio-temporal graph network, trained on any GPU through
//! WGSL compute shaders.
//!
//! The pipeline, module by module: `gpu` (device, tensors, pipelines, recorder) →
//! `ops` (WGSL kernels with forward/backward and f64 CPU references). Later stages
//! (twin, calibrate, data, graph, model, train, compensate) build on these.

pub mod atomic;
pub mod calibrate;
pub mod compensate;
pub mod data;
pub mod error;
pub mod gpu;
pub mod graph;
pub mod model;
pub mod ops;
pub mod plot;
pub mod progress;
pub mod robot;
pub mod stats;
pub mod testing;
pub mod train;
pub mod twin;

/// The README's Rust examples, compiled and run as doc tests so they stay true.
#[cfg(doctest)]
#[doc = include_str!("../README.md")]
pub struct ReadmeDoctests;
