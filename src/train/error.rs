//! What stops a training stage: the device, the network, the data, or a diverging run
//! (with the last good weights).

use crate::gpu::GpuError;
use crate::model::{ModelError, Parameters};

/// What stops a training run.
#[derive(Debug, thiserror::Error)]
pub enum TrainError {
    /// The device failed.
    #[error(transparent)]
    Gpu(#[from] GpuError),
    /// The network could not be built or run.
    #[error(transparent)]
    Model(#[from] ModelError),
    /// The data does not fit the model or the stage (shapes, too few windows, a state of
    /// another stage).
    #[error("{0}")]
    Data(String),
    /// A non-finite loss or parameter, or a loss that exploded
    /// ([`crate::train::EXPLOSION_FACTOR`]). `last_good` holds the parameters just before
    /// the step that went bad (non-finite), or those at the start of its epoch
    /// (explosion).
    #[error("training diverged at step {step} (epoch {epoch}, batch {batch}): {what}")]
    Diverged {
        /// The optimiser step that went bad, counted from 0 within the stage.
        step: u64,
        /// Its epoch, from 1.
        epoch: usize,
        /// Its mini-batch within the epoch, from 1.
        batch: usize,
        /// What went bad: the loss, or the first non-finite tensor.
        what: String,
        /// The last parameters known good.
        last_good: Box<Parameters>,
    },
}

impl crate::error::StageError for TrainError {}
