//! The head's input: the last time step of the last block (docs/model.md "Head"), gathered
//! forward and scattered backward, with the f64 CPU reference.

use crate::gpu::{grid_1d, Binding, Dispatch, Gpu, GpuError, Kernel, Shader, Tensor};

/// The WGSL module of this family (`shaders/head.wgsl`: `last_step_forward`,
/// `last_step_backward`).
pub static SHADER: Shader = Shader {
    name: "head",
    source: include_str!("../../shaders/head.wgsl"),
    base: None,
};

static FORWARD: Kernel = Kernel {
    shader: &SHADER,
    entry: "last_step_forward",
    bindings: &[Binding::read(1), Binding::read_write(2)],
};
static BACKWARD: Kernel = Kernel {
    shader: &SHADER,
    entry: "last_step_backward",
    bindings: &[Binding::read(1), Binding::read_write(2)],
};

/// `h[r] = y[r, steps − 1]` for `y` viewed as `[rows, steps]` (rows = B·N·C).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct LastStep {
    /// Number of rows, one output value each: B·N·C for the head's input (B·N·C_in when a
    /// trimmed block's residual reads its input's last step).
    pub rows: usize,
    /// Time steps per row (T); the op reads or writes step `steps − 1`.
    pub steps: usize,
}

crate::gpu::uniform! {
    pub(crate) struct Params = HeadParams in SHADER {
        rows: u32,
        steps: u32,
        _pad0: u32,
        _pad1: u32,
    }
}

impl LastStep {
    fn params(&self) -> Params {
        Params {
            rows: self.rows as u32,
            steps: self.steps as u32,
            _pad0: 0,
            _pad1: 0,
        }
    }

    /// Gathers (overwrites) `h [rows]` from `y [rows, steps]`: for `[B, N, C, T]` that is
    /// the head's input `h [B, N·C]`.
    pub fn forward(&self, gpu: &Gpu, y: &Tensor, h: &Tensor) -> Result<Dispatch, GpuError> {
        y.expect_len(self.rows * self.steps)?;
        h.expect_len(self.rows)?;
        let max = gpu.limits().max_compute_workgroups_per_dimension;
        gpu.dispatch(
            &FORWARD,
            &[],
            &self.params(),
            &[y, h],
            grid_1d(self.rows, 256, max),
        )
    }

    /// Writes all of `dy`: `dh` at the last step, zero elsewhere.
    pub fn backward(&self, gpu: &Gpu, dh: &Tensor, dy: &Tensor) -> Result<Dispatch, GpuError> {
        dh.expect_len(self.rows)?;
        dy.expect_len(self.rows * self.steps)?;
        let max = gpu.limits().max_compute_workgroups_per_dimension;
        gpu.dispatch(
            &BACKWARD,
            &[],
            &self.params(),
            &[dh, dy],
            grid_1d(self.rows * self.steps, 256, max),
        )
    }
}

/// f64 reference, for tests.
pub mod cpu {
    use super::LastStep;

    /// `h[r] = y[r, steps − 1]`, a vector of `rows` values.
    pub fn forward(s: &LastStep, y: &[f64]) -> Vec<f64> {
        (0..s.rows).map(|r| y[r * s.steps + s.steps - 1]).collect()
    }

    /// `dy [rows, steps]`: `dh` at the last step of each row, zero elsewhere.
    pub fn backward(s: &LastStep, dh: &[f64]) -> Vec<f64> {
        let mut dy = vec![0.0; s.rows * s.steps];
        for (r, d) in dh.iter().enumerate() {
            dy[r * s.steps + s.steps - 1] = *d;
        }
        dy
    }
}
