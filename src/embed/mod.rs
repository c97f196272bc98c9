//! The engine where robot software lives (docs/embedding.md): a C ABI over the
//! [`crate::compensate::SensorPredictor`] (`c_api`, header `include/iastgcn.h`) and,
//! with the `python` feature, the `iastgcn` Python module (`python`). Both only
//! translate: they load through [`Loaded`] and every number comes from the same library
//! calls the Rust API and the CLI make.

pub mod c_api;
#[cfg(feature = "python")]
pub mod python;

use std::path::Path;

use crate::compensate::{Ensemble, Interval, IntervalCalibration, SensorPredictor};
use crate::error::{Error, Result};
use crate::gpu::Device;
use crate::model::{Checkpoint, ModelError, Predictor, Residual};

/// A checkpoint loaded for another language: with a control period it takes raw sensor
/// values, without one feature steps and windows only. An ensemble file (`.toml`,
/// [`crate::compensate::EnsembleFile`]) loads its members, takes sensor values only, and
/// gives each prediction its calibrated interval.
pub struct Loaded {
    inner: Inner,
    /// The graph's node names, in the frame's order.
    nodes: Vec<String>,
}

enum Inner {
    Sensors(SensorPredictor),
    Features(Predictor),
    Ensemble(Ensemble),
}

/// What an ensemble refuses: the calls on windows of features.
fn ensemble_windows() -> ModelError {
    ModelError::Config(
        "an ensemble predicts from sensor values (push, predict_latest); windows and \
         feature steps go to one of its members' checkpoints"
            .into(),
    )
}

impl Loaded {
    /// Loads the checkpoint at `path` on the native CPU forward (`native`), or on the
    /// default adapter (native on a CPU adapter, and on a machine with no adapter at
    /// all). `dt`: the control period, s, or `None` for features only. A `.toml` path is
    /// an ensemble file, which needs `dt`.
    pub fn load(path: &Path, dt: Option<f64>, native: bool) -> Result<Loaded> {
        let device = if native {
            None
        } else {
            Some(Device::open(None).map_err(|e| Error::from(e).context("opening the adapter"))?)
        };
        if path.extension().is_some_and(|e| e == "toml") {
            let dt = dt.ok_or_else(|| {
                Error::Invalid(format!(
                    "{}: an ensemble file takes sensor values: load it with the control \
                     period dt",
                    path.display()
                ))
            })?;
            let (ensemble, checkpoint) = Ensemble::load(path, dt, device.as_ref())?;
            return Ok(Loaded {
                inner: Inner::Ensemble(ensemble),
                nodes: checkpoint.graph.nodes.clone(),
            });
        }
        let checkpoint = Checkpoint::load(path)?;
        let predictor = match &device {
            None => Predictor::native(&checkpoint)?,
            Some(device) => Predictor::on(device, &checkpoint, 8)?,
        };
        let inner = match dt {
            Some(dt) => Inner::Sensors(SensorPredictor::new(predictor, dt)?),
            None => Inner::Features(predictor),
        };
        Ok(Loaded {
            inner,
            nodes: checkpoint.graph.nodes.clone(),
        })
    }

    /// The predictor underneath (an ensemble's first member: every member has its shapes
    /// and variant).
    pub fn predictor(&self) -> &Predictor {
        match &self.inner {
            Inner::Sensors(s) => s.predictor(),
            Inner::Features(p) => p,
            Inner::Ensemble(e) => e.first(),
        }
    }

    /// The predictor underneath, for windows and feature steps; an ensemble refuses.
    pub fn windows(&mut self) -> std::result::Result<&mut Predictor, ModelError> {
        match &mut self.inner {
            Inner::Sensors(s) => Ok(s.predictor_mut()),
            Inner::Features(p) => Ok(p),
            Inner::Ensemble(_) => Err(ensemble_windows()),
        }
    }

    /// Sets the native forward's tasks per window ([`Predictor::set_threads`]) of every
    /// predictor underneath.
    pub fn set_threads(&mut self, threads: usize) {
        match &mut self.inner {
            Inner::Sensors(s) => s.predictor_mut().set_threads(threads),
            Inner::Features(p) => p.set_threads(threads),
            Inner::Ensemble(e) => {
                for m in e.members_mut() {
                    m.predictor_mut().set_threads(threads);
                }
            }
        }
    }

    /// The members of an ensemble; 1 for one checkpoint.
    pub fn members(&self) -> usize {
        match &self.inner {
            Inner::Ensemble(e) => e.members().len(),
            _ => 1,
        }
    }

    /// The calibrated interval: an ensemble file's, when it has one.
    pub fn interval_calibration(&self) -> Option<IntervalCalibration> {
        match &self.inner {
            Inner::Ensemble(e) => e.interval_calibration(),
            _ => None,
        }
    }

    /// The calibrated interval of the last prediction: an ensemble file's with an
    /// interval, after a prediction; `None` otherwise.
    pub fn interval(&self) -> Option<Interval> {
        match &self.inner {
            Inner::Ensemble(e) => e.interval(),
            _ => None,
        }
    }

    /// The graph's node names, in the frame's order.
    pub fn nodes(&self) -> &[String] {
        &self.nodes
    }

    /// The control period, s, when the handle takes sensor values.
    pub fn dt(&self) -> Option<f64> {
        match &self.inner {
            Inner::Sensors(s) => Some(s.dt()),
            Inner::Features(_) => None,
            Inner::Ensemble(e) => Some(e.dt()),
        }
    }

    /// Pushes one tick of raw sensor values (NaN: no sample).
    pub fn push(&mut self, frame: &[f64]) -> std::result::Result<bool, ModelError> {
        match &mut self.inner {
            Inner::Sensors(s) => s.push(frame),
            Inner::Ensemble(e) => e.push(frame),
            Inner::Features(_) => Err(ModelError::Config(
                "this predictor was loaded without a control period (dt): it takes features, \
                 not sensor values; load it with dt to push sensor values"
                    .into(),
            )),
        }
    }

    /// The residual of the window ending at the last pushed tick, once T are in.
    pub fn predict_latest(&mut self) -> std::result::Result<Option<Residual>, ModelError> {
        match &mut self.inner {
            Inner::Sensors(s) => s.predict_latest(),
            Inner::Features(p) => p.predict_latest(),
            Inner::Ensemble(e) => e.predict_latest(),
        }
    }

    /// Forgets the pushed ticks and the features' state.
    pub fn reset(&mut self) {
        match &mut self.inner {
            Inner::Sensors(s) => s.reset(),
            Inner::Features(p) => p.reset(),
            Inner::Ensemble(e) => e.reset(),
        }
    }
}

/// The message of a caught panic.
pub fn panic_message(panic: &(dyn std::any::Any + Send)) -> String {
    let what = panic
        .downcast_ref::<&str>()
        .map(|s| s.to_string())
        .or_else(|| panic.downcast_ref::<String>().cloned())
        .unwrap_or_else(|| "unknown panic".into());
    format!("internal error (a bug in iastgcn): {what}")
}
