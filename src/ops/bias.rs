//! Per-channel bias: broadcast add (in place) and the gradient reduction, with the f64
//! CPU reference.

use crate::gpu::{grid_1d, Binding, DType, Dispatch, Gpu, GpuError, Kernel, Shader, Tensor};
use crate::ops::{outer_slices, Accumulate};

/// The WGSL module of this family (`shaders/bias.wgsl`: `bias_add`, `bias_grad`,
/// `bias_grad_columns`).
pub static SHADER: Shader = Shader {
    name: "bias",
    source: include_str!("../../shaders/bias.wgsl"),
    base: None,
};

static ADD: Kernel = Kernel {
    shader: &SHADER,
    entry: "bias_add",
    bindings: &[Binding::read(1), Binding::read_write(2)],
};
static GRAD: Kernel = Kernel {
    shader: &SHADER,
    entry: "bias_grad",
    bindings: &[Binding::read(1), Binding::read_write(2)],
};
static GRAD_COLUMNS: Kernel = Kernel {
    shader: &SHADER,
    entry: "bias_grad_columns",
    bindings: &[Binding::read(1), Binding::read_write(2)],
};

/// A bias of `channels` values added along the middle axis of `[outer, channels, inner]`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Bias {
    /// Length of the leading axis the bias is broadcast over (B·N for a convolution bias on
    /// `[B, N, C, T]`, B for the attention score biases and the head bias).
    pub outer: usize,
    /// Number of bias values: the length of the middle axis (C for a convolution bias,
    /// T·T for `be`, N·N for `bs`, O for the head).
    pub channels: usize,
    /// Length of the trailing axis the bias is broadcast over (the time steps computed,
    /// for a convolution bias; 1 for the others).
    pub inner: usize,
}

crate::gpu::uniform! {
    pub(crate) struct Params = BiasParams in SHADER {
        outer: u32,
        channels: u32,
        inner: u32,
        accumulate: u32,
        slice: u32,
        slices: u32,
        pad0: u32,
        pad1: u32,
    }
}

impl Bias {
    /// Number of elements of the biased tensor, `outer · channels · inner`.
    pub fn numel(&self) -> usize {
        self.outer * self.channels * self.inner
    }

    fn params(&self, accumulate: Accumulate) -> Params {
        Params {
            outer: self.outer as u32,
            channels: self.channels as u32,
            inner: self.inner as u32,
            accumulate: accumulate.flag(),
            slice: self.outer as u32,
            slices: 1,
            pad0: 0,
            pad1: 0,
        }
    }

    /// Slices of the outer axis the workgroup-per-channel gradient is split into, each
    /// summed by its own workgroup per channel (at least 8 192 terms each, 128 per
    /// invocation: `ops::outer_slices`), and the rows per slice. A convolution bias has
    /// few channels with many terms each (the gated convolution's at the paper's shape:
    /// 128 channels of 89 600 terms over a batch of 64), which left a GPU 128
    /// workgroups; split, 1 408.
    pub fn grad_slices(&self) -> (usize, usize) {
        outer_slices(self.outer, self.inner)
    }

    /// `y += bias` (broadcast), in place.
    pub fn forward(&self, gpu: &Gpu, bias: &Tensor, y: &Tensor) -> Result<Dispatch, GpuError> {
        bias.expect_len(self.channels)?;
        y.expect_len(self.numel())?;
        let max = gpu.limits().max_compute_workgroups_per_dimension;
        gpu.dispatch(
            &ADD,
            &[],
            &self.params(Accumulate::Overwrite),
            &[bias, y],
            grid_1d(self.numel(), 256, max),
        )
    }

    /// Whether the gradient sums each channel in one invocation (many channels with few
    /// terms each) rather than in one workgroup (few channels, many terms).
    pub fn per_channel_invocations(&self) -> bool {
        self.channels >= 64 && self.outer * self.inner <= 1024
    }

    /// `dbias (+)= Σ_{outer, inner} dy`.
    pub fn backward(
        &self,
        gpu: &Gpu,
        dy: &Tensor,
        dbias: &Tensor,
        accumulate: Accumulate,
    ) -> Result<Dispatch, GpuError> {
        dy.expect_len(self.numel())?;
        dbias.expect_len(self.channels)?;
        let max = gpu.limits().max_compute_workgroups_per_dimension;
        if self.per_channel_invocations() {
            gpu.dispatch(
                &GRAD_COLUMNS,
                &[],
                &self.params(accumulate),
                &[dy, dbias],
                grid_1d(self.channels, 64, max),
            )
        } else {
            let (slices, rows) = self.grad_slices();
            if slices == 1 {
                return gpu.dispatch(
                    &GRAD,
                    &[],
                    &self.params(accumulate),
                    &[dy, dbias],
                    grid_1d(self.channels, 1, max),
                );
            }
            let split = Params {
                slice: rows as u32,
                slices: slices as u32,
                ..self.params(Accumulate::Overwrite)
            };
            let partials = gpu.zeros(
                &format!("{} partials", dbias.name()),
                &[slices, self.channels],
                DType::F32,
            )?;
            let first = gpu.dispatch(
                &GRAD,
                &[],
                &split,
                &[dy, &partials],
                grid_1d(slices * self.channels, 1, max),
            )?;
            // The slices' sums in order: the per-channel kernel on [slices, channels, 1].
            let slices_sum = Bias {
                outer: slices,
                channels: self.channels,
                inner: 1,
            };
            let second = gpu.dispatch(
                &GRAD_COLUMNS,
                &[],
                &slices_sum.params(accumulate),
                &[&partials, dbias],
                grid_1d(self.channels, 64, max),
            )?;
            Ok(first.then(second))
        }
    }
}

/// f64 reference, for tests.
pub mod cpu {
    use super::Bias;

    /// `y + bias` broadcast over `[outer, channels, inner]`, as a new vector.
    pub fn forward(b: &Bias, bias: &[f64], y: &[f64]) -> Vec<f64> {
        y.iter()
            .enumerate()
            .map(|(i, v)| v + bias[(i / b.inner) % b.channels])
            .collect()
    }

    /// `dbias[c] = Σ_{outer, inner} dy[o, c, i]`, a vector of `channels` values.
    pub fn backward(b: &Bias, dy: &[f64]) -> Vec<f64> {
        let mut out = vec![0.0; b.channels];
        for (i, v) in dy.iter().enumerate() {
            out[(i / b.inner) % b.channels] += v;
        }
        out
    }
}
