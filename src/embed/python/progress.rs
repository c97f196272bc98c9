//! Progress from a long library call to a Python callback, the GIL released meanwhile.

use pyo3::prelude::*;

use super::convert::{guarded, raise};
use crate::progress::Reporter;

/// A [`Reporter`] that calls a Python callable `progress(event, text, position, total)`
/// with event "begin", "update", "end" or "note". The first exception it raises stops
/// the calls and is raised when the library call returns.
struct PyReporter {
    callback: Option<Py<PyAny>>,
    error: Option<PyErr>,
}

impl PyReporter {
    fn new(callback: Option<Py<PyAny>>) -> PyReporter {
        PyReporter {
            callback,
            error: None,
        }
    }

    fn call(&mut self, event: &str, text: &str, position: u64, total: u64) {
        let (Some(callback), None) = (&self.callback, &self.error) else {
            return;
        };
        let result = Python::attach(|py| {
            callback
                .call1(py, (event, text, position, total))
                .map(|_| ())
        });
        if let Err(e) = result {
            self.error = Some(e);
        }
    }

    /// The library call's result, or the callback's first exception.
    fn finish<T>(self, result: crate::error::Result<T>) -> PyResult<T> {
        if let Some(e) = self.error {
            return Err(e);
        }
        result.map_err(raise)
    }
}

impl Reporter for PyReporter {
    fn begin(&mut self, what: &str, len: u64) {
        self.call("begin", what, 0, len);
    }
    fn update(&mut self, pos: u64, message: &str) {
        self.call("update", message, pos, 0);
    }
    fn end(&mut self) {
        self.call("end", "", 0, 0);
    }
    fn note(&mut self, line: &str) {
        self.call("note", line, 0, 0);
    }
}

/// Runs a long library call without the GIL, reporting to `progress`.
pub(super) fn long_call<T: Send>(
    py: Python<'_>,
    progress: Option<Py<PyAny>>,
    body: impl FnOnce(&mut dyn Reporter) -> crate::error::Result<T> + Send,
) -> PyResult<T> {
    py.detach(|| {
        guarded(|| {
            let mut reporter = PyReporter::new(progress);
            let result = body(&mut reporter);
            reporter.finish(result)
        })
    })
}
