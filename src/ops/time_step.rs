//! One time step of a `[rows, steps]` tensor: the gather that feeds a recurrent cell its
//! input at step t (`x_t [B, N, F]` from `x [B, N, F, T]`), and its backward scatter, with
//! the f64 CPU reference.

use crate::gpu::{grid_1d, Binding, Dispatch, Gpu, GpuError, Kernel, Shader, Tensor};
use crate::ops::Accumulate;

/// The WGSL module of this family (`shaders/time_step.wgsl`: `time_step_forward`,
/// `time_step_backward`).
pub static SHADER: Shader = Shader {
    name: "time_step",
    source: include_str!("../../shaders/time_step.wgsl"),
    base: None,
};

static FORWARD: Kernel = Kernel {
    shader: &SHADER,
    entry: "time_step_forward",
    bindings: &[Binding::read(1), Binding::read_write(2)],
};
static BACKWARD: Kernel = Kernel {
    shader: &SHADER,
    entry: "time_step_backward",
    bindings: &[Binding::read(1), Binding::read_write(2)],
};

/// `h[r] = y[r, step]` for `y` viewed as `[rows, steps]`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct TimeStep {
    /// Rows, one output value each (B·N·F for a recurrent cell's input).
    pub rows: usize,
    /// Time steps per row (T).
    pub steps: usize,
    /// The step read or written, `< steps`.
    pub step: usize,
}

crate::gpu::uniform! {
    pub(crate) struct Params = TimeStepParams in SHADER {
        rows: u32,
        steps: u32,
        step: u32,
        accumulate: u32,
    }
}

impl TimeStep {
    fn params(&self, accumulate: Accumulate) -> Result<Params, GpuError> {
        if self.step >= self.steps {
            return Err(GpuError::Shape {
                tensor: "time step".into(),
                expected: format!("a step below {}", self.steps),
                got: self.step.to_string(),
            });
        }
        Ok(Params {
            rows: self.rows as u32,
            steps: self.steps as u32,
            step: self.step as u32,
            accumulate: accumulate.flag(),
        })
    }

    /// Gathers (overwrites) `h [rows]` from `y [rows, steps]`.
    pub fn forward(&self, gpu: &Gpu, y: &Tensor, h: &Tensor) -> Result<Dispatch, GpuError> {
        y.expect_len(self.rows * self.steps)?;
        h.expect_len(self.rows)?;
        let max = gpu.limits().max_compute_workgroups_per_dimension;
        gpu.dispatch(
            &FORWARD,
            &[],
            &self.params(Accumulate::Overwrite)?,
            &[y, h],
            grid_1d(self.rows, 256, max),
        )
    }

    /// `Overwrite`: all of `dy` is written, `dh` at `step` and zero elsewhere. `Add`: `dh`
    /// is added at `step` and the other steps are left alone.
    pub fn backward(
        &self,
        gpu: &Gpu,
        dh: &Tensor,
        dy: &Tensor,
        accumulate: Accumulate,
    ) -> Result<Dispatch, GpuError> {
        dh.expect_len(self.rows)?;
        dy.expect_len(self.rows * self.steps)?;
        let max = gpu.limits().max_compute_workgroups_per_dimension;
        let threads = match accumulate {
            Accumulate::Overwrite => self.rows * self.steps,
            Accumulate::Add => self.rows,
        };
        gpu.dispatch(
            &BACKWARD,
            &[],
            &self.params(accumulate)?,
            &[dh, dy],
            grid_1d(threads, 256, max),
        )
    }
}

/// f64 reference, for tests.
pub mod cpu {
    use super::TimeStep;

    /// `h[r] = y[r, step]`, a vector of `rows` values.
    pub fn forward(s: &TimeStep, y: &[f64]) -> Vec<f64> {
        (0..s.rows).map(|r| y[r * s.steps + s.step]).collect()
    }

    /// `dy [rows, steps]` (+)= `dh` at `step` of each row (`dy` holds what an `Add`
    /// backward adds to; pass zeros for `Overwrite`).
    pub fn backward(s: &TimeStep, dh: &[f64], dy: &mut [f64]) {
        for (r, d) in dh.iter().enumerate() {
            dy[r * s.steps + s.step] += *d;
        }
    }
}
