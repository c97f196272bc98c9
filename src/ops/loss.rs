//! The weighted squared error of MODEL.md eq. 39 (without weight decay, which the
//! optimiser applies): forward into a one-element tensor and backward, with the f64
//! CPU reference.

use crate::gpu::{grid_1d, Binding, Dispatch, Gpu, GpuError, Kernel, Shader, Tensor};

pub static SHADER: Shader = Shader {
    name: "loss",
    source: include_str!("../../shaders/loss.wgsl"),
};

static FORWARD: Kernel = Kernel {
    shader: &SHADER,
    entry: "loss_forward",
    bindings: &[Binding::read(1), Binding::read(2), Binding::read_write(3)],
};
static BACKWARD: Kernel = Kernel {
    shader: &SHADER,
    entry: "loss_backward",
    bindings: &[Binding::read(1), Binding::read(2), Binding::read_write(3)],
};

/// `ℒ = (1/B) Σ_b Σ_m w_m (ŷ − y)²` with `w_m = 1` for the first three outputs
/// (position) and `penalty` (P) for the rest (attitude).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PoseLoss {
    pub batch: usize,
    pub outputs: usize,
    pub penalty: f64,
}

#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct Params {
    batch: u32,
    outputs: u32,
    penalty: f32,
    _pad: u32,
}

impl PoseLoss {
    fn params(&self) -> Params {
        Params {
            batch: self.batch as u32,
            outputs: self.outputs as u32,
            penalty: self.penalty as f32,
            _pad: 0,
        }
    }

    fn check(&self, pred: &Tensor, target: &Tensor) -> Result<(), GpuError> {
        pred.expect_len(self.batch * self.outputs)?;
        target.expect_len(self.batch * self.outputs)
    }

    /// `loss[0] = ℒ` (one workgroup).
    pub fn forward(
        &self,
        gpu: &Gpu,
        pred: &Tensor,
        target: &Tensor,
        loss: &Tensor,
    ) -> Result<Dispatch, GpuError> {
        self.check(pred, target)?;
        loss.expect_len(1)?;
        gpu.dispatch(
            &FORWARD,
            &[],
            &self.params(),
            &[pred, target, loss],
            [1, 1, 1],
        )
    }

    /// Rewrites the uniforms of a dispatch built by this loss's `forward` or `backward`
    /// (e.g. a new `penalty`, same batch and outputs).
    pub fn set_penalty(&self, gpu: &Gpu, dispatch: &Dispatch) -> Result<(), GpuError> {
        dispatch.write_params(gpu, &self.params())
    }

    /// `dpred = ∂ℒ/∂ŷ` (overwritten).
    pub fn backward(
        &self,
        gpu: &Gpu,
        pred: &Tensor,
        target: &Tensor,
        dpred: &Tensor,
    ) -> Result<Dispatch, GpuError> {
        self.check(pred, target)?;
        dpred.expect_len(self.batch * self.outputs)?;
        let max = gpu.limits().max_compute_workgroups_per_dimension;
        gpu.dispatch(
            &BACKWARD,
            &[],
            &self.params(),
            &[pred, target, dpred],
            grid_1d(self.batch * self.outputs, 256, max),
        )
    }
}

/// f64 reference, for tests.
pub mod cpu {
    use super::PoseLoss;

    fn weight(l: &PoseLoss, m: usize) -> f64 {
        if m < 3 {
            1.0
        } else {
            l.penalty
        }
    }

    pub fn forward(l: &PoseLoss, pred: &[f64], target: &[f64]) -> f64 {
        let s: f64 = pred
            .iter()
            .zip(target)
            .enumerate()
            .map(|(i, (p, t))| weight(l, i % l.outputs) * (p - t) * (p - t))
            .sum();
        s / l.batch as f64
    }

    pub fn backward(l: &PoseLoss, pred: &[f64], target: &[f64]) -> Vec<f64> {
        pred.iter()
            .zip(target)
            .enumerate()
            .map(|(i, (p, t))| 2.0 / l.batch as f64 * weight(l, i % l.outputs) * (p - t))
            .collect()
    }
}
