//! The Adam update of docs/model.md (β1 0.9, β2 0.999, ε 1e-8) with the λ‖W‖² term of eq. 39
//! folded into the gradient (the GPU loss omits it), in place per tensor, with the f64
//! CPU reference.

use crate::gpu::{grid_1d, Binding, Dispatch, Gpu, GpuError, Kernel, Shader, Tensor};

/// The WGSL module of this family (`shaders/adam.wgsl`, entry `adam_step`).
pub static SHADER: Shader = Shader {
    name: "adam",
    source: include_str!("../../shaders/adam.wgsl"),
    base: None,
};

static STEP: Kernel = Kernel {
    shader: &SHADER,
    entry: "adam_step",
    bindings: &[
        Binding::read_write(1),
        Binding::read(2),
        Binding::read_write(3),
        Binding::read_write(4),
        Binding::read(5),
    ],
};

/// Adam with L2 weight decay folded into the gradient (g' = g + 2·decay·w).
///
/// `decay` is λ for the weights of docs/model.md eq. 39 and 0 for biases, be/bs, θ and ln.*.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Adam {
    /// Number of elements in the parameter tensor (and in its gradient and both moments).
    pub numel: usize,
    /// Decay rate β1 of the first moment (docs/model.md "Optimiser and schedule": 0.9).
    pub beta1: f64,
    /// Decay rate β2 of the second moment (docs/model.md "Optimiser and schedule": 0.999).
    pub beta2: f64,
    /// ε added to √v̂ in the update's denominator (docs/model.md "Optimiser and schedule":
    /// 1e-8).
    pub eps: f64,
    /// L2 coefficient λ: the gradient becomes g + 2·decay·w before the moments; 0 for the
    /// tensors outside the weight-decay term of docs/model.md "Loss".
    pub decay: f64,
}

crate::gpu::uniform! {
    pub(crate) struct Params = AdamParams in SHADER {
        numel: u32,
        beta1: f32,
        beta2: f32,
        eps: f32,
        decay: f32,
        one_minus_beta1: f32,
        one_minus_beta2: f32,
        _pad: u32,
    }
}

/// The per-step values shared by every tensor's update, in a small storage tensor of 4 f32
/// written by the host once per step: [lr, 1 − β1^t, 1 − β2^t, 0].
///
/// `t` counts updates from 1 (at `t = 0` the bias corrections are 0 and the update is
/// undefined).
pub fn hyper_values(lr: f64, beta1: f64, beta2: f64, t: u64) -> [f32; 4] {
    let t = t.min(i32::MAX as u64) as i32;
    [
        lr as f32,
        (1.0 - beta1.powi(t)) as f32,
        (1.0 - beta2.powi(t)) as f32,
        0.0,
    ]
}

impl Adam {
    fn params(&self) -> Params {
        Params {
            numel: self.numel as u32,
            beta1: self.beta1 as f32,
            beta2: self.beta2 as f32,
            eps: self.eps as f32,
            decay: self.decay as f32,
            one_minus_beta1: (1.0 - self.beta1) as f32,
            one_minus_beta2: (1.0 - self.beta2) as f32,
            _pad: 0,
        }
    }

    /// One update of `param` in place from `grad`, moments `m`, `v` (updated in place), reading lr and bias corrections from `hyper` (4 floats).
    pub fn step(
        &self,
        gpu: &Gpu,
        param: &Tensor,
        grad: &Tensor,
        m: &Tensor,
        v: &Tensor,
        hyper: &Tensor,
    ) -> Result<Dispatch, GpuError> {
        param.expect_len(self.numel)?;
        grad.expect_len(self.numel)?;
        m.expect_len(self.numel)?;
        v.expect_len(self.numel)?;
        hyper.expect_len(4)?;
        let max = gpu.limits().max_compute_workgroups_per_dimension;
        gpu.dispatch(
            &STEP,
            &[],
            &self.params(),
            &[param, grad, m, v, hyper],
            grid_1d(self.numel, 256, max),
        )
    }
}

/// f64 reference, for tests.
pub mod cpu {
    /// One update in place; `hyper` = [lr, 1 − β1^t, 1 − β2^t, 0] as from
    /// [`super::hyper_values`].
    pub fn step(
        a: &super::Adam,
        hyper: [f64; 4],
        param: &mut [f64],
        grad: &[f64],
        m: &mut [f64],
        v: &mut [f64],
    ) {
        for (name, len) in [
            ("param", param.len()),
            ("grad", grad.len()),
            ("m", m.len()),
            ("v", v.len()),
        ] {
            assert_eq!(len, a.numel, "adam reference: {name} length");
        }
        let [lr, bc1, bc2, _] = hyper;
        for (((w, g), m), v) in param.iter_mut().zip(grad).zip(m).zip(v) {
            let g = g + 2.0 * a.decay * *w;
            *m = a.beta1 * *m + (1.0 - a.beta1) * g;
            *v = a.beta2 * *v + (1.0 - a.beta2) * g * g;
            *w -= lr * (*m / bc1) / ((*v / bc2).sqrt() + a.eps);
        }
    }
}
