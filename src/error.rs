//! The library's error, at the bottom of the module graph: it names no module. Each stage
//! owns its typed error (`GpuError`, `DataError`, `CheckpointError`, …) and marks it a
//! [`StageError`]; `?` wraps it whole into [`Error::Stage`], so that a pipeline call
//! (train, refine, evaluate, the demo) returns one type that still says which stage, file
//! or tensor failed, and [`Error::find`] gets the typed error back. Errors flow one way:
//! every module may import this one, this one imports none of them (docs/architecture.md
//! "Errors"). The binary turns it into a message; nothing here panics on input.

use std::fmt::Display;
use std::path::{Path, PathBuf};

/// A stage's own error type, carried whole by [`Error::Stage`]. Each module implements it
/// for its error types next to their definitions.
pub trait StageError: std::error::Error + Send + Sync + 'static {}

impl<E: StageError> From<E> for Error {
    fn from(error: E) -> Error {
        Error::Stage(Box::new(error))
    }
}

/// What stops a library call.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// A stage's typed error (the GPU, the robot model, a calibration, a recording or a
    /// dataset, a graph, a model or checkpoint, a run config or training state, training,
    /// a plot, a tensor file), kept whole: [`Error::find`] returns it by type.
    #[error(transparent)]
    Stage(Box<dyn std::error::Error + Send + Sync + 'static>),
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
    /// A setting outside what the call can use: `setting` names it as the library does
    /// (a config field: `held_out.sessions`), `message` says what it may be and what it
    /// was. A front end may name it its own way (the command line: its flag).
    #[error("{setting}: {message}")]
    Setting {
        /// The setting, as the library's configs name it.
        setting: &'static str,
        /// What it may be, and what it was.
        message: String,
    },
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

    /// The stage's typed error of type `E` under every [`Error::Context`], if that is
    /// what failed.
    ///
    /// ```
    /// use iastgcn::error::Error;
    /// use iastgcn::gpu::GpuError;
    ///
    /// let e = Error::from(GpuError::NoAdapter { hint: "install a driver".into() })
    ///     .context("opening the adapter");
    /// assert!(e.find::<GpuError>().is_some());
    /// assert!(Error::Invalid("x".into()).find::<GpuError>().is_none());
    /// ```
    pub fn find<E: StageError>(&self) -> Option<&E> {
        match self.root() {
            Error::Stage(e) => e.downcast_ref::<E>(),
            _ => None,
        }
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

/// Writes each `(name, text)` into the folder `dir`, all replaced together or none
/// ([`crate::atomic::Batch`]), naming the file on error.
pub fn write_files(dir: &Path, files: &[(&str, &str)]) -> Result<()> {
    let mut batch = crate::atomic::Batch::new();
    for (name, text) in files {
        let path = dir.join(name);
        batch
            .add(&path, text.as_bytes())
            .map_err(|e| Error::io(&path, e))?;
    }
    batch.commit().map_err(|e| Error::io(dir, e))
}
