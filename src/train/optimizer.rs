//! Adam over every parameter tensor of a [`Network`], on the device (docs/model.md
//! "Optimiser and schedule"), with the inverse-time-decay learning rate. The moments
//! live next to the parameters for the whole run; one step is one dispatch per tensor,
//! recorded after the backward pass into the same submit.

use super::config::TrainConfig;
use crate::gpu::{DType, Dispatch, Gpu, GpuError, Recorder, Tensor};
use crate::model::Network;
use crate::ops::adam::{hyper_values, Adam};

/// lr(step) = lr0 / (1 + r · step / steps_per_epoch).
pub fn learning_rate(lr0: f64, decay: f64, step: u64, steps_per_epoch: usize) -> f64 {
    lr0 / (1.0 + decay * step as f64 / steps_per_epoch.max(1) as f64)
}

/// Host copies of the first and second moments, one vector per parameter tensor.
pub type Moments = (Vec<Vec<f32>>, Vec<Vec<f32>>);

/// Adam moments and the prepared update dispatches of one network.
pub struct Optimizer {
    /// First moments, in [`crate::model::param_specs`] order.
    pub m: Vec<Tensor>,
    /// Second moments, same order.
    pub v: Vec<Tensor>,
    /// [lr, 1 − β1^t, 1 − β2^t, 0], written once per step.
    hyper: Tensor,
    updates: Vec<Dispatch>,
    beta1: f64,
    beta2: f64,
}

impl Optimizer {
    /// Zero moments for every parameter of `net`; λ (`weight_decay`) acts on the tensors
    /// docs/model.md marks as weights only.
    pub fn new(gpu: &Gpu, net: &Network, config: &TrainConfig) -> Result<Optimizer, GpuError> {
        let hyper = gpu.zeros("adam.hyper", &[4], DType::F32)?;
        let (mut m, mut v, mut updates) = (Vec::new(), Vec::new(), Vec::new());
        for ((spec, p), g) in net.specs.iter().zip(&net.params).zip(&net.grads) {
            let mt = gpu.zeros(&format!("adam.m.{}", spec.name), &spec.shape, DType::F32)?;
            let vt = gpu.zeros(&format!("adam.v.{}", spec.name), &spec.shape, DType::F32)?;
            let adam = Adam {
                numel: spec.numel(),
                beta1: config.beta1,
                beta2: config.beta2,
                eps: config.adam_eps,
                decay: if spec.decay { config.weight_decay } else { 0.0 },
            };
            updates.push(adam.step(gpu, p, g, &mt, &vt, &hyper)?);
            m.push(mt);
            v.push(vt);
        }
        Ok(Optimizer {
            m,
            v,
            hyper,
            updates,
            beta1: config.beta1,
            beta2: config.beta2,
        })
    }

    /// Sets the learning rate and the bias corrections of update number `t` (1-based)
    /// for the next recorded step.
    pub fn set_step(&self, gpu: &Gpu, lr: f64, t: u64) -> Result<(), GpuError> {
        gpu.write(&self.hyper, &hyper_values(lr, self.beta1, self.beta2, t))
    }

    /// Records the update of every tensor.
    pub fn record(&self, rec: &mut Recorder) {
        rec.dispatch_all(&self.updates);
    }

    /// Reads the moments back (for a resumable training state).
    pub fn read_state(&self, gpu: &Gpu) -> Result<Moments, GpuError> {
        let read = |ts: &[Tensor]| -> Result<Vec<Vec<f32>>, GpuError> {
            ts.iter()
                .map(|t| {
                    let mut v = gpu.read_f32(t)?;
                    v.truncate(t.numel());
                    Ok(v)
                })
                .collect()
        };
        Ok((read(&self.m)?, read(&self.v)?))
    }

    /// Writes the moments (from [`Optimizer::read_state`] or zeros).
    pub fn load_state(&self, gpu: &Gpu, m: &[Vec<f32>], v: &[Vec<f32>]) -> Result<(), GpuError> {
        for (ts, values) in [(&self.m, m), (&self.v, v)] {
            if values.len() != ts.len() {
                return Err(GpuError::Shape {
                    tensor: "adam moments".into(),
                    expected: format!("{} tensors", ts.len()),
                    got: format!("{}", values.len()),
                });
            }
            for (t, x) in ts.iter().zip(values) {
                t.expect_len(x.len())?;
                gpu.write(t, x)?;
            }
        }
        Ok(())
    }

    /// Zero moments (a new stage starts a fresh Adam).
    pub fn reset(&self, gpu: &Gpu) -> Result<(), GpuError> {
        for t in self.m.iter().chain(&self.v) {
            gpu.write(t, &vec![0f32; t.numel()])?;
        }
        Ok(())
    }
}
