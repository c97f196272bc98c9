//! The `iastgcn` Python module (feature `python`; built by maturin, `make python`;
//! docs/embedding.md "Python"). `Predictor` for controllers, and the demo's steps as
//! functions for notebooks: `record_data`, `calibrate`, `calibrate_arm`, `train`,
//! `refine`, `adapt`, `evaluate`, each with an optional progress callback. Results come back as
//! dictionaries (the library's own structures through JSON), errors as `iastgcn.Error`
//! with the library's message; a panic is caught and raised as `iastgcn.Error` too.

mod convert;
mod pipeline;
mod predictor;
mod progress;

use pyo3::prelude::*;

use convert::Error;
use pipeline::{
    adapt_model, calibrate, calibrate_arm, evaluate_models, record_data, refine_model, train_model,
};
use predictor::PyPredictor;

#[pymodule]
fn _native(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add("__version__", env!("CARGO_PKG_VERSION"))?;
    m.add("Error", m.py().get_type::<Error>())?;
    m.add_class::<PyPredictor>()?;
    m.add_function(wrap_pyfunction!(record_data, m)?)?;
    m.add_function(wrap_pyfunction!(calibrate, m)?)?;
    m.add_function(wrap_pyfunction!(calibrate_arm, m)?)?;
    m.add_function(wrap_pyfunction!(train_model, m)?)?;
    m.add_function(wrap_pyfunction!(refine_model, m)?)?;
    m.add_function(wrap_pyfunction!(adapt_model, m)?)?;
    m.add_function(wrap_pyfunction!(evaluate_models, m)?)?;
    Ok(())
}
