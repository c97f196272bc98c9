//! Softmax along one axis (the attention normalisations of docs/model.md), forward and
//! backward, with the f64 CPU reference.

use crate::gpu::{grid_1d, Binding, Dispatch, Gpu, GpuError, Kernel, Shader, Tensor};
use crate::ops::Accumulate;

/// The WGSL module of this family (`shaders/softmax.wgsl`: `softmax_forward`,
/// `softmax_backward`).
pub static SHADER: Shader = Shader {
    name: "softmax",
    source: include_str!("../../shaders/softmax.wgsl"),
    base: None,
};

static FORWARD: Kernel = Kernel {
    shader: &SHADER,
    entry: "softmax_forward",
    bindings: &[Binding::read(1), Binding::read_write(2)],
};
static BACKWARD: Kernel = Kernel {
    shader: &SHADER,
    entry: "softmax_backward",
    bindings: &[Binding::read(1), Binding::read(2), Binding::read_write(3)],
};

const WORKGROUP: u32 = 256;

/// Softmax along the middle axis of a tensor viewed as `[outer, len, inner]`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Softmax {
    /// Length of the leading axis: B for the temporal attention's E `[B, T, T]`, B·N for
    /// the spatial attention's S `[B, N, N]` (docs/model.md "One ST block", steps 1–2).
    pub outer: usize,
    /// Length of the normalised axis: T (the first index t of E), or N (the last index j
    /// of S).
    pub len: usize,
    /// Length of the trailing axis, each position normalised on its own: T for E (one
    /// softmax per t'), 1 for S.
    pub inner: usize,
}

crate::gpu::uniform! {
    pub(crate) struct Params = SmParams in SHADER {
        outer: u32,
        len: u32,
        inner: u32,
        accumulate: u32,
    }
}

impl Softmax {
    /// Number of elements of x and y, `outer · len · inner`.
    pub fn numel(&self) -> usize {
        self.outer * self.len * self.inner
    }

    fn params(&self, accumulate: Accumulate) -> Params {
        Params {
            outer: self.outer as u32,
            len: self.len as u32,
            inner: self.inner as u32,
            accumulate: accumulate.flag(),
        }
    }

    fn grid(&self, gpu: &Gpu) -> [u32; 3] {
        grid_1d(
            self.outer * self.inner,
            WORKGROUP,
            gpu.limits().max_compute_workgroups_per_dimension,
        )
    }

    /// `y = softmax(x)` along the axis.
    pub fn forward(&self, gpu: &Gpu, x: &Tensor, y: &Tensor) -> Result<Dispatch, GpuError> {
        x.expect_len(self.numel())?;
        y.expect_len(self.numel())?;
        gpu.dispatch(
            &FORWARD,
            &[],
            &self.params(Accumulate::Overwrite),
            &[x, y],
            self.grid(gpu),
        )
    }

    /// `dx (+)= y ⊙ (dy − Σ dy·y)` from the forward output `y`.
    pub fn backward(
        &self,
        gpu: &Gpu,
        y: &Tensor,
        dy: &Tensor,
        dx: &Tensor,
        accumulate: Accumulate,
    ) -> Result<Dispatch, GpuError> {
        for t in [y, dy, dx] {
            t.expect_len(self.numel())?;
        }
        gpu.dispatch(
            &BACKWARD,
            &[],
            &self.params(accumulate),
            &[y, dy, dx],
            self.grid(gpu),
        )
    }
}

/// f64 reference, for tests.
pub mod cpu {
    use super::Softmax;

    fn lines(s: &Softmax) -> impl Iterator<Item = Vec<usize>> + '_ {
        (0..s.outer).flat_map(move |o| {
            (0..s.inner).map(move |i| (0..s.len).map(|l| (o * s.len + l) * s.inner + i).collect())
        })
    }

    /// `y = softmax(x)` along the middle axis, the maximum subtracted before
    /// exponentiating.
    pub fn forward(s: &Softmax, x: &[f64]) -> Vec<f64> {
        let mut y = vec![0.0; s.numel()];
        for idx in lines(s) {
            let m = idx.iter().map(|&k| x[k]).fold(f64::NEG_INFINITY, f64::max);
            let z: f64 = idx.iter().map(|&k| (x[k] - m).exp()).sum();
            for &k in &idx {
                y[k] = (x[k] - m).exp() / z;
            }
        }
        y
    }

    /// `dx` from the input `x` and upstream `dy`.
    pub fn backward(s: &Softmax, x: &[f64], dy: &[f64]) -> Vec<f64> {
        let y = forward(s, x);
        let mut dx = vec![0.0; s.numel()];
        for idx in lines(s) {
            let dot: f64 = idx.iter().map(|&k| dy[k] * y[k]).sum();
            for &k in &idx {
                dx[k] = y[k] * (dy[k] - dot);
            }
        }
        dx
    }
}
