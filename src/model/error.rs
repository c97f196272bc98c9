//! What can go wrong building or feeding a network, on any backend.

use crate::gpu::GpuError;

/// What can go wrong building or feeding a network.
#[derive(Debug, thiserror::Error)]
pub enum ModelError {
    /// The device failed: allocation, upload, a kernel's shape check or a dispatch.
    #[error(transparent)]
    Gpu(#[from] GpuError),
    /// A model config, graph, batch size, parameter count or input length the network
    /// cannot use; the message says which and why.
    #[error("{0}")]
    Config(String),
    /// A parameter tensor given to [`Network::load_parameters`](crate::model::Network::load_parameters) whose name, shape or
    /// length differs from the network's own at that position.
    #[error("parameter {name}: {message}")]
    Parameter {
        /// The docs/model.md name of the tensor given (e.g. `blocks.0.gwc.W`).
        name: String,
        /// The expected and the given name, shape and value count.
        message: String,
    },
}

impl crate::error::StageError for ModelError {}
