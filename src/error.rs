//! The library's error: every module's typed error in one enum, so that a pipeline call
//! (train, refine, evaluate, the demo) returns one type that still says which stage,
//! file or tensor failed. The binary turns it into a message; nothing here panics on
//! input.

use std::fmt::Display;
use std::path::{Path, PathBuf};

use crate::calibrate::arm::ArmCalibrationError;
use crate::calibrate::file::CalibrationFileError;
use crate::calibrate::CalibrationError;
use crate::data::{DataError, DatasetError};
use crate::gpu::GpuError;
use crate::graph::GraphError;
use crate::interop::TensorFileError;
use crate::model::{CheckpointError, ModelError};
use crate::plot::PlotError;
use crate::robot::RobotError;
use crate::train::{ConfigError, StateError, TrainError};

/// What stops a library call.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// The GPU: no adapter, a device or shader failure, a buffer too large.
    #[error(transparent)]
    Gpu(#[from] GpuError),
    /// The robot model: a bad geometry asset, a pose outside the workspace, kinematics that fail.
    #[error(transparent)]
    Robot(#[from] RobotError),
    /// The identification of the geometric errors.
    #[error(transparent)]
    Calibration(#[from] CalibrationError),
    /// A serial arm's calibration could not run.
    #[error(transparent)]
    ArmCalibration(#[from] ArmCalibrationError),
    /// A calibration file that cannot be written or read.
    #[error(transparent)]
    CalibrationFile(#[from] CalibrationFileError),
    /// A recording or calibration set that cannot be written or read.
    #[error(transparent)]
    Data(#[from] DataError),
    /// Recordings that cannot be turned into a dataset.
    #[error(transparent)]
    Dataset(#[from] DatasetError),
    /// A sensor graph asset that cannot be read or is invalid.
    #[error(transparent)]
    Graph(#[from] GraphError),
    /// A model config or network that cannot be built or run.
    #[error(transparent)]
    Model(#[from] ModelError),
    /// A checkpoint that cannot be written, read or trusted.
    #[error(transparent)]
    Checkpoint(#[from] CheckpointError),
    /// A run config that cannot be read or is invalid.
    #[error(transparent)]
    Config(#[from] ConfigError),
    /// A training state that cannot be written, read or resumed.
    #[error(transparent)]
    State(#[from] StateError),
    /// Training, refinement or prediction that cannot go on.
    #[error(transparent)]
    Train(#[from] TrainError),
    /// A plot that cannot be drawn or written.
    #[error(transparent)]
    Plot(#[from] PlotError),
    /// A tensor file (`iastgcn forward`'s input or output) that cannot be read or written.
    #[error(transparent)]
    TensorFile(#[from] TensorFileError),
    /// A file that could not be written or read.
    // The I/O error is part of the message, not a source: a chain printer (the CLI's
    // `{:#}`) would print it twice.
    #[error("{}: {error}", path.display())]
    Io {
        /// The file.
        path: PathBuf,
        /// What the operating system said.
        error: std::io::Error,
    },
    /// An argument or setting that cannot be used; the text names it and says why.
    #[error("{0}")]
    Invalid(String),
    /// An error and where it happened (a run, a stage, a file).
    #[error("{context}: {inner}")]
    Context {
        /// Where it happened.
        context: String,
        /// What happened.
        inner: Box<Error>,
    },
}

/// The library's result.
pub type Result<T, E = Error> = std::result::Result<T, E>;

impl Error {
    /// An I/O error on `path`.
    pub fn io(path: &Path, source: std::io::Error) -> Error {
        Error::Io {
            path: path.to_path_buf(),
            error: source,
        }
    }

    /// `self`, said to have happened in `context`.
    ///
    /// ```
    /// use iastgcn::error::Error;
    ///
    /// let e = Error::Invalid("batch must be positive".into()).context("run config");
    /// assert_eq!(e.to_string(), "run config: batch must be positive");
    /// assert!(matches!(e.root(), Error::Invalid(_)));
    /// ```
    pub fn context(self, context: impl Display) -> Error {
        Error::Context {
            context: context.to_string(),
            inner: Box::new(self),
        }
    }

    /// The innermost error under every [`Error::Context`].
    pub fn root(&self) -> &Error {
        match self {
            Error::Context { inner, .. } => inner.root(),
            e => e,
        }
    }
}

/// `error` from building work of `batch` windows, with the fix where the batch is too
/// large for the adapter: "`--batch 4096`: tensor x needs 9.1 GiB; this adapter allows
/// 2.0 GiB per buffer (…); try --batch 512".
pub fn batch_error(error: impl Into<Error>, batch: usize) -> Error {
    let error = error.into();
    let gpu = match &error {
        Error::Gpu(e) => Some(e),
        Error::Model(ModelError::Gpu(e)) => Some(e),
        _ => None,
    };
    match gpu.and_then(|e| e.fitting_count(batch).map(|n| (e, n))) {
        Some((e, n)) => Error::Invalid(format!("--batch {batch}: {e}; try --batch {n}")),
        None => error,
    }
}

/// Returns [`Error::Invalid`] with `message` unless `ok`.
pub fn ensure(ok: bool, message: impl FnOnce() -> String) -> Result<()> {
    if ok {
        Ok(())
    } else {
        Err(Error::Invalid(message()))
    }
}

/// Writes `bytes` to `path` atomically ([`crate::atomic::write`]), naming the path on error.
pub fn write_file(path: &Path, bytes: &[u8]) -> Result<()> {
    crate::atomic::write(path, bytes).map_err(|e| Error::io(path, e))
}
