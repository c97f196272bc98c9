//! The weighted squared error of docs/model.md eq. 39 (without weight decay, which the
//! optimiser applies), optionally over ensembles of consecutive windows (docs/model.md
//! "Refinement"): forward into a one-element tensor and backward, with the f64 CPU
//! reference.

use crate::gpu::{grid_1d, Binding, Dispatch, Gpu, GpuError, Kernel, Shader, Tensor};

/// The WGSL module of this family (`shaders/loss.wgsl`: `loss_forward`, `loss_backward`).
pub static SHADER: Shader = Shader {
    name: "loss",
    source: include_str!("../../shaders/loss.wgsl"),
    base: None,
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

/// `ℒ = (1/B) Σ_b ℓ(ŷ_b, y_b)` with `ℓ(a, b) = Σ_m w_m (a_m − b_m)²`, `w_m = 1` for the
/// first three outputs (position) and `penalty` (P) for the rest (attitude).
///
/// With `group` = M > 1 the batch holds G = B/M ensembles of M consecutive windows
/// (rows g·M .. g·M + M − 1) and the loss is the ensemble loss of docs/model.md
/// "Refinement": `ℒ = (1/G) Σ_g [ (1/M) Σ_k ℓ(ŷ_gk, y_gk) + ℓ(mean_k ŷ_gk, mean_k y_gk) ]`.
/// `group` = 1 is the plain loss (no ensemble term: the formula with M = 1 would count
/// every window twice).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PoseLoss {
    /// Windows B in the batch: ŷ and y are `[batch, outputs]`, in standardised label space.
    pub batch: usize,
    /// Outputs O per window (6: dx, dy, dz, rx, ry, rz); the first three are weighted 1,
    /// the rest `penalty`.
    pub outputs: usize,
    /// The attitude penalty P of docs/model.md "Loss" (`[train] attitude_penalty`).
    pub penalty: f64,
    /// Ensemble size M (the refinement magnification m); 1 for the plain per-window loss.
    /// Must divide `batch`.
    pub group: usize,
}

crate::gpu::uniform! {
    pub(crate) struct Params = LossParams in SHADER {
        batch: u32,
        outputs: u32,
        penalty: f32,
        group: u32,
    }
}

impl PoseLoss {
    fn params(&self) -> Params {
        Params {
            batch: self.batch as u32,
            outputs: self.outputs as u32,
            penalty: self.penalty as f32,
            group: self.group as u32,
        }
    }

    fn check(&self, pred: &Tensor, target: &Tensor) -> Result<(), GpuError> {
        if self.group == 0 || !self.batch.is_multiple_of(self.group) {
            return Err(GpuError::Shape {
                tensor: "pose loss batch".into(),
                expected: format!("a positive multiple of the ensemble size {}", self.group),
                got: format!("{} windows", self.batch),
            });
        }
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
    /// (e.g. a new `penalty`, same batch, outputs and group).
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

/// The loss on the host in f64: what the native CPU training path trains with
/// (`model::native::step`), and the reference the WGSL kernels above are tested against
/// (`tests/head_loss.rs`). One implementation of the maths, not a test-only copy.
impl PoseLoss {
    fn weight(&self, m: usize) -> f64 {
        if m < 3 {
            1.0
        } else {
            self.penalty
        }
    }

    /// `mean_k (ŷ_gk − y_gk)` per ensemble g, `[G, outputs]` (empty for group 1).
    fn group_mean_errors(&self, pred: &[f64], target: &[f64]) -> Vec<f64> {
        assert!(
            self.group > 0 && self.batch.is_multiple_of(self.group),
            "pose loss: batch {} is not a multiple of group {}",
            self.batch,
            self.group
        );
        if self.group == 1 {
            return Vec::new();
        }
        let (m, o) = (self.group, self.outputs);
        let mut mean = vec![0.0; self.batch / m * o];
        for (i, (p, t)) in pred.iter().zip(target).enumerate() {
            mean[i / o / m * o + i % o] += (p - t) / m as f64;
        }
        mean
    }

    /// ℒ for `pred` and `target` `[batch, outputs]`, as [`PoseLoss`] defines it; panics if
    /// `group` does not divide `batch`.
    pub fn value(&self, pred: &[f64], target: &[f64]) -> f64 {
        let windows: f64 = pred
            .iter()
            .zip(target)
            .enumerate()
            .map(|(i, (p, t))| self.weight(i % self.outputs) * (p - t) * (p - t))
            .sum();
        let ensembles: f64 = self
            .group_mean_errors(pred, target)
            .iter()
            .enumerate()
            .map(|(i, e)| self.weight(i % self.outputs) * e * e)
            .sum();
        // (1/G)(1/M) = 1/B for the per-window terms.
        windows / self.batch as f64 + ensembles / (self.batch / self.group) as f64
    }

    /// `∂ℒ/∂ŷ`, `[batch, outputs]`: `(2/B)·w_m·(ŷ − y)`, plus `(2/B)·w_m·mean_k(ŷ_gk − y_gk)`
    /// of the window's ensemble when `group` > 1.
    pub fn gradient(&self, pred: &[f64], target: &[f64]) -> Vec<f64> {
        let mean = self.group_mean_errors(pred, target);
        let o = self.outputs;
        pred.iter()
            .zip(target)
            .enumerate()
            .map(|(i, (p, t))| {
                let ensemble = if self.group > 1 {
                    mean[i / o / self.group * o + i % o]
                } else {
                    0.0
                };
                2.0 / self.batch as f64 * self.weight(i % o) * (p - t + ensemble)
            })
            .collect()
    }
}
