//! `iastgcn.Predictor`: a checkpoint or an ensemble file loaded for a control loop or
//! for batches of windows (docs/embedding.md "Python").

use std::path::PathBuf;
use std::sync::Mutex;

use numpy::{
    AllowTypeChange, PyArray1, PyArrayLike1, PyArrayLikeDyn, PyArrayMethods, PyUntypedArrayMethods,
};
use pyo3::prelude::*;

use super::convert::{guarded, raise, residual_array};
use crate::embed::Loaded;
use crate::model::{Backend, Features};

/// A predictor loaded from a checkpoint, for a control loop or for batches of windows.
///
/// Predictor(checkpoint, *, dt=None, backend="native", threads=1)
///
/// checkpoint: a `.safetensors` file written by iastgcn (train, refine, init).
/// dt: the control period in seconds of the recordings the model was trained on (the
///     twin's is 0.02). With it, `push` takes one tick of raw sensor values; without
///     it, only `push_features`, `predict` and `predict_batch` work.
/// backend: "native" (the CPU forward on the calling thread; needs no GPU driver) or
///     "auto" (the default adapter; native on a CPU adapter).
/// threads: tasks the native forward splits one window into (1: the calling thread).
///
/// Residuals are dx, dy, dz in µm and rx, ry, rz in mdeg (base frame): the error to
/// subtract from the next commanded pose. One thread at a time per predictor (a lock
/// makes concurrent calls wait); the lock is released around the forward pass.
#[pyclass(name = "Predictor", module = "iastgcn")]
pub(super) struct PyPredictor {
    inner: Mutex<Loaded>,
    /// (N, F, T), fixed at load.
    shape: (usize, usize, usize),
    /// Sensor values of the last frame when the input was not a contiguous float64
    /// array, reused.
    frame: Mutex<Vec<f64>>,
}

impl PyPredictor {
    fn with<T>(&self, f: impl FnOnce(&mut Loaded) -> PyResult<T>) -> PyResult<T> {
        let mut loaded = self
            .inner
            .lock()
            .map_err(|_| raise("the predictor was poisoned by an earlier internal error"))?;
        guarded(|| f(&mut loaded))
    }
}

/// `got` shape against `expected`, as the error message names them.
fn check_shape(what: &str, got: &[usize], expected: &[&[usize]]) -> PyResult<()> {
    if expected.contains(&got) {
        return Ok(());
    }
    let list: Vec<String> = expected.iter().map(|e| format!("{e:?}")).collect();
    Err(raise(format!(
        "{what}: expected shape {}, got {got:?}",
        list.join(" or ")
    )))
}

#[pymethods]
impl PyPredictor {
    #[new]
    #[pyo3(signature = (checkpoint, *, dt=None, backend="native", threads=1))]
    fn new(
        py: Python<'_>,
        checkpoint: PathBuf,
        dt: Option<f64>,
        backend: &str,
        threads: usize,
    ) -> PyResult<PyPredictor> {
        let native = match backend {
            "native" => true,
            "auto" => false,
            other => {
                return Err(raise(format!(
                    "backend: \"native\" or \"auto\", got {other:?}"
                )))
            }
        };
        if threads == 0 {
            return Err(raise("threads: 1 or more"));
        }
        let mut loaded =
            py.detach(|| guarded(|| Loaded::load(&checkpoint, dt, native).map_err(raise)))?;
        loaded.set_threads(threads);
        let c = loaded.predictor().config();
        let shape = (c.nodes, c.features, c.window);
        Ok(PyPredictor {
            inner: Mutex::new(loaded),
            shape,
            frame: Mutex::new(vec![0.0; shape.0]),
        })
    }

    /// The graph's node names: the order of a sensor frame's values.
    #[getter]
    fn nodes(&self) -> PyResult<Vec<String>> {
        self.with(|l| Ok(l.nodes().to_vec()))
    }

    /// (N, F, T): nodes, features per node, window length in ticks.
    #[getter]
    fn window_shape(&self) -> (usize, usize, usize) {
        self.shape
    }

    /// The tick the residual is for: 0 for the last pushed tick, 1 for the next (a
    /// look-ahead model, whose frame carries the planned motion to that tick).
    #[getter]
    fn look_ahead(&self) -> PyResult<usize> {
        self.with(|l| Ok(l.predictor().config().look_ahead))
    }

    /// The model's variant ("iastgcn", "tgcn", …).
    #[getter]
    fn variant(&self) -> PyResult<String> {
        self.with(|l| Ok(l.predictor().config().variant.name().to_string()))
    }

    /// "native" or "device": where windows run.
    #[getter]
    fn backend(&self) -> PyResult<&'static str> {
        self.with(|l| {
            Ok(match l.predictor().backend() {
                Backend::Native => "native",
                Backend::Device => "device",
            })
        })
    }

    /// The control period in seconds, or None when the predictor takes features only.
    #[getter]
    fn dt(&self) -> PyResult<Option<f64>> {
        self.with(|l| Ok(l.dt()))
    }

    /// Tasks the native forward splits one window into.
    #[getter]
    fn get_threads(&self) -> PyResult<usize> {
        self.with(|l| Ok(l.predictor().threads()))
    }

    #[setter]
    fn set_threads(&self, threads: usize) -> PyResult<()> {
        if threads == 0 {
            return Err(raise("threads: 1 or more"));
        }
        self.with(|l| {
            l.set_threads(threads);
            Ok(())
        })
    }

    /// push(frame) -> bool
    ///
    /// Pushes one control tick of raw sensor values: N numbers in the order of `nodes`
    /// (float32 or float64; NaN: no new sample this tick, the last one is held).
    /// Returns True once T ticks are in, so that `predict_latest` has a window.
    fn push(&self, frame: PyArrayLike1<'_, f64, AllowTypeChange>) -> PyResult<bool> {
        let (n, _, _) = self.shape;
        check_shape("frame", frame.shape(), &[&[n]])?;
        match frame.as_slice() {
            Ok(values) => self.with(|l| l.push(values).map_err(raise)),
            Err(_) => {
                let mut buffer = self.frame.lock().map_err(raise)?;
                for (b, v) in buffer.iter_mut().zip(frame.as_array().iter()) {
                    *b = *v;
                }
                self.with(|l| l.push(&buffer).map_err(raise))
            }
        }
    }

    /// push_features(step) -> bool
    ///
    /// Pushes one step of per-node features, shape (N, F) or (N·F,), before
    /// standardisation, for callers that compute the features themselves. True once
    /// T steps are in.
    fn push_features(&self, step: PyArrayLikeDyn<'_, f32, AllowTypeChange>) -> PyResult<bool> {
        let (n, f, _) = self.shape;
        check_shape("step", step.shape(), &[&[n, f], &[n * f]])?;
        let values: Vec<f32>;
        let step = match step.as_slice() {
            Ok(s) => s,
            Err(_) => {
                values = step.as_array().iter().copied().collect();
                &values
            }
        };
        self.with(|l| l.windows().and_then(|p| p.push_step(step)).map_err(raise))
    }

    /// predict_latest() -> numpy.ndarray | None
    ///
    /// The residual (6 float64) of the window ending at the last pushed tick, or None
    /// until T ticks have been pushed.
    fn predict_latest<'py>(&self, py: Python<'py>) -> PyResult<Option<Bound<'py, PyArray1<f64>>>> {
        let latest = py.detach(|| self.with(|l| l.predict_latest().map_err(raise)))?;
        Ok(latest.map(|r| residual_array(py, &r)))
    }

    /// interval() -> tuple[float, float] | None
    ///
    /// The calibrated interval of the last prediction, (position µm, attitude mdeg): the
    /// true residual lies within these radii of it with the share `interval_level` (on
    /// the session it was calibrated on). Only an ensemble file with an interval has one
    /// (docs/embedding.md "Ensembles and intervals"); None otherwise and before the first
    /// prediction.
    fn interval(&self) -> PyResult<Option<(f64, f64)>> {
        self.with(|l| Ok(l.interval().map(|i| (i.position_um, i.attitude_mdeg))))
    }

    /// The share of predictions the interval covered where it was calibrated (0.9 for
    /// a 90 % interval), or None without one.
    #[getter]
    fn interval_level(&self) -> PyResult<Option<f64>> {
        self.with(|l| Ok(l.interval_calibration().map(|s| s.level)))
    }

    /// The checkpoints averaged: an ensemble file's members, 1 for one checkpoint.
    #[getter]
    fn members(&self) -> PyResult<usize> {
        self.with(|l| Ok(l.members()))
    }

    /// predict(window) -> numpy.ndarray
    ///
    /// The residual (6 float64) of one window of features, shape (N, F, T), oldest step
    /// first, before standardisation. Leaves the pushed ticks alone.
    fn predict<'py>(
        &self,
        py: Python<'py>,
        window: PyArrayLikeDyn<'py, f32, AllowTypeChange>,
    ) -> PyResult<Bound<'py, PyArray1<f64>>> {
        let (n, f, t) = self.shape;
        check_shape("window", window.shape(), &[&[n, f, t]])?;
        let copied: Vec<f32>;
        let data = match window.as_slice() {
            Ok(s) => s,
            Err(_) => {
                copied = window.as_array().iter().copied().collect();
                &copied
            }
        };
        let r =
            py.detach(|| self.with(|l| l.windows().and_then(|p| p.predict(data)).map_err(raise)))?;
        Ok(residual_array(py, &r))
    }

    /// predict_batch(windows, standardised=False) -> numpy.ndarray
    ///
    /// The residuals, shape (W, 6), of W windows of features, shape (W, N, F, T).
    /// `standardised`: the windows are already standardised with the checkpoint's
    /// statistics (as a dataset built with them is).
    #[pyo3(signature = (windows, standardised=false))]
    fn predict_batch<'py>(
        &self,
        py: Python<'py>,
        windows: PyArrayLikeDyn<'py, f32, AllowTypeChange>,
        standardised: bool,
    ) -> PyResult<Bound<'py, PyAny>> {
        let (n, f, t) = self.shape;
        let shape = windows.shape().to_vec();
        if shape.len() != 4 || shape[1..] != [n, f, t] {
            return Err(raise(format!(
                "windows: expected shape (W, {n}, {f}, {t}), got {shape:?}"
            )));
        }
        let copied: Vec<f32>;
        let data = match windows.as_slice() {
            Ok(s) => s,
            Err(_) => {
                copied = windows.as_array().iter().copied().collect();
                &copied
            }
        };
        let features = if standardised {
            Features::Standardised
        } else {
            Features::Raw
        };
        let out = py.detach(|| {
            self.with(|l| {
                let mut out = Vec::new();
                l.windows()
                    .and_then(|p| p.predict_batch(data, features, &mut out))
                    .map_err(raise)?;
                Ok(out)
            })
        })?;
        let flat: Vec<f64> = out.iter().flatten().copied().collect();
        PyArray1::from_vec(py, flat)
            .reshape([shape[0], 6])
            .map(Bound::into_any)
    }

    /// Forgets the pushed ticks and the features' filter state (a new run, or after a
    /// pause in the trajectory).
    fn reset(&self) -> PyResult<()> {
        self.with(|l| {
            l.reset();
            Ok(())
        })
    }

    fn __repr__(&self) -> PyResult<String> {
        let (n, f, t) = self.shape;
        let dt = self.dt()?;
        Ok(format!(
            "Predictor(variant={:?}, nodes={n}, features={f}, window={t}, dt={}, backend={:?})",
            self.variant()?,
            dt.map_or("None".into(), |d| d.to_string()),
            self.backend()?
        ))
    }
}
