#![warn(missing_docs)]
//! IASTGCN: predicting the pose residual errors of an optical-polishing hybrid robot with
//! an interpretable adaptive spatio-temporal graph network, trained on any GPU through
//! WGSL compute shaders with hand-written backward passes.
//!
//! The modules read as the pipeline (docs/architecture.md has the picture and the rules
//! on who may import whom):
//!
//! - [`robot`] → [`twin`]: the robot's kinematics, and the digital twin that stands in for
//!   it (hidden error sources, instruments, tracker, polishing paths);
//! - [`calibrate`]: geometric calibration with a graded EKF;
//! - [`data`]: recordings, features, labels, windows and leakage-free splits;
//! - [`model`] on [`ops`] on [`gpu`]: the network as WGSL kernels, its f64 reference,
//!   checkpoints and the embeddable [`model::Predictor`];
//! - [`train`]: training, refinement and prediction on recordings;
//! - [`compensate`]: online compensation in the twin (held-out runs, the error budget);
//! - [`polish`]: the mirror: dwell time, removal at the pad's true pose, interferometer;
//! - [`experiment`]: the protocol's experiments: Tables III, V and VI, the demo,
//!   `reproduce`, twin machines, serial arms;
//! - [`embed`]: the C ABI and the Python module over the same calls.
//!
//! Long calls report through a [`progress::Reporter`] and return [`error::Result`].
//!
//! ```no_run
//! use iastgcn::{data::DataSources, gpu::Device, progress::Silent, train};
//!
//! let sources = DataSources::new(vec!["grid.csv".into()], "calibration.toml".into());
//! let config = train::RunConfig::demo();
//! let (graph, data) = train::build_dataset(&sources, &config, None)?;
//! let out = std::path::Path::new("model.safetensors");
//! // The default adapter, or the native CPU path where there is none.
//! let device = Device::open(None)?;
//! let trained = train::train(&device, &data, &graph, &config, out, None, &mut Silent)?;
//! println!("best validation loss {}", trained.best_val);
//! # Ok::<(), iastgcn::error::Error>(())
//! ```

pub mod atomic;
pub mod calibrate;
pub mod compensate;
pub mod data;
pub mod embed;
pub mod error;
pub mod experiment;
pub mod gpu;
pub mod graph;
pub mod interop;
pub mod model;
pub mod ops;
pub mod plot;
pub mod polish;
pub mod progress;
pub mod robot;
pub mod smoke;
pub mod stats;
pub mod testing;
pub mod train;
pub mod twin;

/// The README's Rust examples, compiled and run as doc tests so they stay true.
#[cfg(doctest)]
#[doc = include_str!("../README.md")]
pub struct ReadmeDoctests;
