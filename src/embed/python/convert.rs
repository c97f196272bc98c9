//! Where Rust meets Python: the `iastgcn.Error` exception, panics caught and raised as
//! it, and the library's values handed over (through JSON, or as float64 arrays).

use std::panic::{catch_unwind, AssertUnwindSafe};

use numpy::PyArray1;
use pyo3::exceptions::PyException;
use pyo3::prelude::*;
use serde::Serialize;

use crate::embed::panic_message;
use crate::model::Residual;

pyo3::create_exception!(
    iastgcn,
    Error,
    PyException,
    "Every failure of the engine: a file it cannot read, a shape that does not fit the \
     model, a config it refuses, a device error. The message is the library's, naming \
     the file, field or tensor."
);

/// Runs `body` with panics caught and the library's errors raised as `iastgcn.Error`.
pub(super) fn guarded<T>(body: impl FnOnce() -> PyResult<T>) -> PyResult<T> {
    match catch_unwind(AssertUnwindSafe(body)) {
        Ok(result) => result,
        Err(panic) => Err(Error::new_err(panic_message(panic.as_ref()))),
    }
}

/// The library's error as `iastgcn.Error`.
pub(super) fn raise(e: impl std::fmt::Display) -> PyErr {
    Error::new_err(e.to_string())
}

/// A Rust value as Python objects (through JSON: numbers, strings, lists, dicts; NaN
/// becomes None).
pub(super) fn to_python<'py>(
    py: Python<'py>,
    value: &impl Serialize,
) -> PyResult<Bound<'py, PyAny>> {
    let text = serde_json::to_string(value).map_err(raise)?;
    py.import("json")?.call_method1("loads", (text,))
}

/// The residual as a float64 array of 6.
pub(super) fn residual_array<'py>(py: Python<'py>, r: &Residual) -> Bound<'py, PyArray1<f64>> {
    PyArray1::from_slice(py, r)
}
