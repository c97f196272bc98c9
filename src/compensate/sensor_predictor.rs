//! What a controller embeds: a [`Predictor`] fed with one control tick of raw sensor
//! values at a time. The values go through the same causal features as training
//! ([`Stream`]: filtered signal, difference, entropy per node, docs/model.md "Features
//! and labels") into the predictor's ring of the last T steps, and the residual of the
//! window ending at the newest tick comes out. The twin's online compensation
//! ([`super::online`]), the C ABI and the Python package all run this one type, so a
//! controller in any language gets the same residuals bit for bit.

use std::borrow::BorrowMut;

use crate::data::features::Stream;
use crate::data::FeatureConfig;
use crate::model::{Checkpoint, ModelError, Predictor, Residual};

/// Features per node that [`Stream`] computes (r, D, H).
const STREAM_FEATURES: usize = 3;

/// A predictor fed with raw sensor values, one control tick at a time. It owns its
/// [`Predictor`] or borrows one (`SensorPredictor<&mut Predictor>`, as the twin's loop
/// does for each run).
pub struct SensorPredictor<P: BorrowMut<Predictor> = Predictor> {
    predictor: P,
    stream: Stream,
    dt: f64,
    /// A NaN-coded frame as [`Stream`] takes it, reused.
    values: Vec<Option<f64>>,
    /// The tick's features, f64 then f32, reused.
    features: Vec<f64>,
    step: Vec<f32>,
}

impl SensorPredictor {
    /// A native (CPU) predictor of `checkpoint` fed with sensor values every `dt` s.
    pub fn native(checkpoint: &Checkpoint, dt: f64) -> Result<SensorPredictor, ModelError> {
        SensorPredictor::new(Predictor::native(checkpoint)?, dt)
    }
}

impl<P: BorrowMut<Predictor>> SensorPredictor<P> {
    /// Wraps `predictor` for sensor values sampled every `dt` seconds (the control period
    /// of the recordings the model was trained on: the features' filter and differences
    /// depend on it). Fails when `dt` is not a positive number or when the model does not
    /// take the F = 3 features per node the stream computes.
    pub fn new(predictor: P, dt: f64) -> Result<SensorPredictor<P>, ModelError> {
        if !(dt.is_finite() && dt > 0.0) {
            return Err(ModelError::Config(format!(
                "dt: the control period must be a positive number of seconds, got {dt}"
            )));
        }
        let config = predictor.borrow().config();
        if config.features != STREAM_FEATURES {
            return Err(ModelError::Config(format!(
                "this model takes {} features per node; raw sensor values give {STREAM_FEATURES} \
                 (filtered signal, difference, entropy): push features instead",
                config.features
            )));
        }
        let nodes = config.nodes;
        Ok(SensorPredictor {
            stream: Stream::new(nodes, dt, &FeatureConfig::default()),
            dt,
            values: vec![None; nodes],
            features: vec![0.0; nodes * STREAM_FEATURES],
            step: vec![0.0; nodes * STREAM_FEATURES],
            predictor,
        })
    }

    /// Pushes one tick of raw sensor values, one per graph node in the checkpoint's order
    /// (`None`: no new sample this tick, the last one is held). True once T ticks are in,
    /// so that [`SensorPredictor::predict_latest`] has a window. Allocation-free.
    pub fn push_values(&mut self, values: &[Option<f64>]) -> Result<bool, ModelError> {
        self.check_frame(values.len())?;
        self.stream.push(values, &mut self.features);
        self.push_features()
    }

    /// As [`SensorPredictor::push_values`], with NaN for "no sample this tick" (how C and
    /// NumPy callers say it).
    pub fn push(&mut self, frame: &[f64]) -> Result<bool, ModelError> {
        self.check_frame(frame.len())?;
        for (v, &x) in self.values.iter_mut().zip(frame) {
            *v = (!x.is_nan()).then_some(x);
        }
        self.stream.push(&self.values, &mut self.features);
        self.push_features()
    }

    fn check_frame(&self, len: usize) -> Result<(), ModelError> {
        if len == self.values.len() {
            return Ok(());
        }
        Err(ModelError::Config(format!(
            "frame: expected one value per graph node ({}), got {len}",
            self.values.len()
        )))
    }

    /// Pushes the tick's features into the predictor's ring.
    fn push_features(&mut self) -> Result<bool, ModelError> {
        for (o, f) in self.step.iter_mut().zip(&self.features) {
            *o = *f as f32;
        }
        self.predictor.borrow_mut().push_step(&self.step)
    }

    /// The residual of the window ending at the last pushed tick; `None` until T ticks
    /// have been pushed.
    pub fn predict_latest(&mut self) -> Result<Option<Residual>, ModelError> {
        self.predictor.borrow_mut().predict_latest()
    }

    /// Forgets the pushed ticks and the features' state (a new run, or after a pause).
    pub fn reset(&mut self) {
        self.predictor.borrow_mut().reset();
        self.stream = Stream::new(self.values.len(), self.dt, &FeatureConfig::default());
    }

    /// The control period, s.
    pub fn dt(&self) -> f64 {
        self.dt
    }

    /// The predictor underneath (shapes, backend, windows of features).
    pub fn predictor(&self) -> &Predictor {
        self.predictor.borrow()
    }

    /// The predictor underneath, to predict windows of features directly.
    pub fn predictor_mut(&mut self) -> &mut Predictor {
        self.predictor.borrow_mut()
    }
}
