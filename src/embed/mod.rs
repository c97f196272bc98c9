//! The engine where robot software lives (docs/embedding.md): a C ABI over the
//! [`crate::compensate::SensorPredictor`] (`c_api`, header `include/iastgcn.h`) and,
//! with the `python` feature, the `iastgcn` Python module (`python`). Both only
//! translate: they load through [`Loaded`] and every number comes from the same library
//! calls the Rust API and the CLI make.

pub mod c_api;
#[cfg(feature = "python")]
pub mod python;

use std::path::Path;

use crate::compensate::SensorPredictor;
use crate::error::{Error, Result};
use crate::gpu::Device;
use crate::model::{Checkpoint, ModelError, Predictor, Residual};

/// A checkpoint loaded for another language: with a control period it takes raw sensor
/// values, without one feature steps and windows only.
pub struct Loaded {
    inner: Inner,
    /// The graph's node names, in the frame's order.
    nodes: Vec<String>,
}

enum Inner {
    Sensors(SensorPredictor),
    Features(Predictor),
}

impl Loaded {
    /// Loads the checkpoint at `path` on the native CPU forward (`native`), or on the
    /// default adapter (native on a CPU adapter, and on a machine with no adapter at
    /// all). `dt`: the control period, s, or `None` for features only.
    pub fn load(path: &Path, dt: Option<f64>, native: bool) -> Result<Loaded> {
        let checkpoint = Checkpoint::load(path)?;
        let predictor = if native {
            Predictor::native(&checkpoint)?
        } else {
            let device =
                Device::open(None).map_err(|e| Error::from(e).context("opening the adapter"))?;
            Predictor::on(&device, &checkpoint, 8)?
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

    /// The predictor underneath.
    pub fn predictor(&mut self) -> &mut Predictor {
        match &mut self.inner {
            Inner::Sensors(s) => s.predictor_mut(),
            Inner::Features(p) => p,
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
        }
    }

    /// Pushes one tick of raw sensor values (NaN: no sample).
    pub fn push(&mut self, frame: &[f64]) -> std::result::Result<bool, ModelError> {
        match &mut self.inner {
            Inner::Sensors(s) => s.push(frame),
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
        }
    }

    /// Forgets the pushed ticks and the features' state.
    pub fn reset(&mut self) {
        match &mut self.inner {
            Inner::Sensors(s) => s.reset(),
            Inner::Features(p) => p.reset(),
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
