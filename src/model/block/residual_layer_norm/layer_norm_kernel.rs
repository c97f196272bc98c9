//! LayerNorm over the channel axis of `[B, N, C, T]` (docs/model.md step 6): forward, input and
//! parameter gradients, and the f64 CPU reference. The dropout that follows it in a
//! training step (step 7) can be fused in ([`LayerNorm::dropout`]).

use super::dropout_kernel::Dropout;
use crate::gpu::{grid_1d, Binding, DType, Dispatch, Gpu, GpuError, Kernel, Shader, Tensor};
use crate::ops::{outer_slices, Accumulate};

/// The WGSL module of this family (`shaders/layer_norm.wgsl`: forward, input gradient,
/// parameter gradients).
pub static SHADER: Shader = Shader {
    name: "layer_norm",
    source: include_str!("../../../../shaders/layer_norm.wgsl"),
    base: None,
};

const R1: Binding = Binding::read(1);
const R2: Binding = Binding::read(2);
const R3: Binding = Binding::read(3);
const R4: Binding = Binding::read(4);
const R5: Binding = Binding::read(5);
const W4: Binding = Binding::read_write(4);
const W5: Binding = Binding::read_write(5);
const W6: Binding = Binding::read_write(6);

static FORWARD: Kernel = Kernel {
    shader: &SHADER,
    entry: "layer_norm_forward",
    bindings: &[R1, R2, R3, W4, W5, W6],
};
static FORWARD4: Kernel = Kernel {
    shader: &SHADER,
    entry: "layer_norm_forward4",
    bindings: &[R1, R2, R3, W4, W5, W6],
};
static BACKWARD_INPUT: Kernel = Kernel {
    shader: &SHADER,
    entry: "layer_norm_backward_input",
    bindings: &[R1, R2, R3, R4, R5, W6],
};
static BACKWARD_INPUT4: Kernel = Kernel {
    shader: &SHADER,
    entry: "layer_norm_backward_input4",
    bindings: &[R1, R2, R3, R4, R5, W6],
};
static BACKWARD_PARAMS: Kernel = Kernel {
    shader: &SHADER,
    entry: "layer_norm_backward_params",
    bindings: &[R1, R2, R3, R4, W5, W6],
};
static PARAMS_SUM: Kernel = Kernel {
    shader: &SHADER,
    entry: "layer_norm_params_sum",
    bindings: &[R1, R2, W5, W6],
};

const WORKGROUP: u32 = 256;

/// Shape of a LayerNorm over C for each of `outer` (= B·N) blocks and `steps` (= T).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LayerNorm {
    /// Number of leading blocks, B·N for `[B, N, C, T]`.
    pub outer: usize,
    /// Length C of the normalised (middle) axis, and of γ and β.
    pub channels: usize,
    /// Length of the trailing axis (T, or the time steps a trimmed block computes); each
    /// (outer, step) pair is normalised on its own.
    pub steps: usize,
    /// ε added to the biased variance under the square root (`[model] eps`, docs/model.md
    /// step 6).
    pub eps: f32,
    /// x is the output of a ReLU: [`LayerNorm::backward_input`] returns the gradient with
    /// respect to the ReLU's input, `(x > 0) · ∂L/∂x` (one elementwise pass fewer).
    pub relu_input: bool,
    /// The dropout that follows, fused in (over all [`LayerNorm::len`] elements): the
    /// forward writes `dropout(y)` and both backward kernels take the gradient of the
    /// dropped output, reading it through the same mask. Its training step is that of
    /// [`LayerNorm::set_step`] (0 when built).
    pub dropout: Option<Dropout>,
}

crate::gpu::uniform! {
    pub(crate) struct Params = LnParams in SHADER {
        outer: u32,
        channels: u32,
        steps: u32,
        accumulate: u32,
        eps: f32,
        relu_input: u32,
        drop: u32,
        drop_key: u32,
        drop_threshold: u32,
        drop_scale: f32,
        drop_stride: u32,
        drop_offset: u32,
        slice: u32,
        slices: u32,
        pad0: u32,
        pad1: u32,
    }
}

impl LayerNorm {
    /// docs/model.md: ε = 1e-5.
    pub fn new(outer: usize, channels: usize, steps: usize) -> LayerNorm {
        LayerNorm {
            outer,
            channels,
            steps,
            eps: 1e-5,
            relu_input: false,
            dropout: None,
        }
    }

    /// Number of elements of x and y, `outer · channels · steps`.
    pub fn len(&self) -> usize {
        self.outer * self.channels * self.steps
    }

    /// Whether x and y have no elements.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Rows normalised: one mean and one 1/σ each.
    pub fn rows(&self) -> usize {
        self.outer * self.steps
    }

    fn params(&self, accumulate: Accumulate, step: u32) -> Params {
        let d = self.dropout;
        let (slices, per) = self.grad_slices();
        Params {
            outer: self.outer as u32,
            channels: self.channels as u32,
            steps: self.steps as u32,
            accumulate: accumulate.flag(),
            eps: self.eps,
            relu_input: self.relu_input as u32,
            drop: d.is_some() as u32,
            drop_key: d.map_or(0, |d| d.key(step)),
            drop_threshold: d.map_or(0, |d| d.threshold()),
            drop_scale: d.map_or(1.0, |d| d.scale()),
            drop_stride: d.map_or(1, |d| d.stride as u32),
            drop_offset: d.map_or(0, |d| d.offset as u32),
            slice: per as u32,
            slices: slices as u32,
            pad0: 0,
            pad1: 0,
        }
    }

    /// Slices of the outer axis the parameter gradients are split into, each summed by
    /// its own workgroup per channel (at least 8 192 terms each, 32 per invocation:
    /// `ops::outer_slices`), and the blocks of the outer axis per slice. Each channel's
    /// sum runs over all B·N·T rows (89 600 at the paper's shape, batch 64), so unsplit a
    /// GPU had 64 workgroups, each thread adding 350 terms in a row; split, 640
    /// workgroups of 35 (the bias gradient's split, `Bias::grad_slices`, took a GPU's
    /// step from 31.8 to 29.4 ms).
    pub fn grad_slices(&self) -> (usize, usize) {
        outer_slices(self.outer, self.steps)
    }

    /// Points a dispatch built by this LayerNorm (with its dropout) at the mask of
    /// training step `step` (no allocation: rewrites its uniform block). `accumulate`
    /// is the one it was built with.
    pub fn set_step(
        &self,
        gpu: &Gpu,
        dispatch: &Dispatch,
        step: u32,
        accumulate: Accumulate,
    ) -> Result<(), GpuError> {
        dispatch.write_params(gpu, &self.params(accumulate, step))
    }

    fn check(
        &self,
        full: &[&Tensor],
        per_channel: &[&Tensor],
        per_row: &[&Tensor],
    ) -> Result<(), GpuError> {
        if let Some(d) = self.dropout.filter(|d| d.n != self.len()) {
            return Err(GpuError::Shape {
                tensor: format!("dropout fused into the LayerNorm of {}", full[0].name()),
                expected: format!("{} elements", self.len()),
                got: format!("{}", d.n),
            });
        }
        full.iter().try_for_each(|t| t.expect_len(self.len()))?;
        per_channel
            .iter()
            .try_for_each(|t| t.expect_len(self.channels))?;
        per_row.iter().try_for_each(|t| t.expect_len(self.rows()))
    }

    /// Four rows per invocation (vector loads along t) when T allows it.
    pub fn quads(&self) -> bool {
        self.steps.is_multiple_of(4)
    }

    /// The grid of a per-row kernel: one invocation per row, or per four rows.
    fn row_grid(&self, gpu: &Gpu) -> [u32; 3] {
        let per = if self.quads() { 4 } else { 1 };
        grid_1d(
            self.rows() / per,
            WORKGROUP,
            gpu.limits().max_compute_workgroups_per_dimension,
        )
    }

    /// `y = γ ⊙ (x − μ)/σ + β` (then the dropout, when fused); saves `mean` and `rstd`
    /// (`[rows]`) for the backward pass.
    // A kernel's dispatch takes each of its bindings by name; grouping them would hide
    // which tensor goes where.
    #[allow(clippy::too_many_arguments)]
    pub fn forward(
        &self,
        gpu: &Gpu,
        x: &Tensor,
        gamma: &Tensor,
        beta: &Tensor,
        y: &Tensor,
        mean: &Tensor,
        rstd: &Tensor,
    ) -> Result<Dispatch, GpuError> {
        self.check(&[x, y], &[gamma, beta], &[mean, rstd])?;
        gpu.dispatch(
            if self.quads() { &FORWARD4 } else { &FORWARD },
            &[],
            &self.params(Accumulate::Overwrite, 0),
            &[x, gamma, beta, y, mean, rstd],
            self.row_grid(gpu),
        )
    }

    /// `dx (+)= ∂L/∂x` from `dy` (the dropped output's gradient, when the dropout is fused).
    #[allow(clippy::too_many_arguments)]
    pub fn backward_input(
        &self,
        gpu: &Gpu,
        x: &Tensor,
        gamma: &Tensor,
        dy: &Tensor,
        mean: &Tensor,
        rstd: &Tensor,
        dx: &Tensor,
        accumulate: Accumulate,
    ) -> Result<Dispatch, GpuError> {
        self.check(&[x, dy, dx], &[gamma], &[mean, rstd])?;
        gpu.dispatch(
            if self.quads() {
                &BACKWARD_INPUT4
            } else {
                &BACKWARD_INPUT
            },
            &[],
            &self.params(accumulate, 0),
            &[x, gamma, dy, mean, rstd, dx],
            self.row_grid(gpu),
        )
    }

    /// `dγ, dβ (+)=` their gradients from `dy` (`dy` as in [`LayerNorm::backward_input`]):
    /// one workgroup per channel and slice of the rows ([`LayerNorm::grad_slices`]), then,
    /// when split, a second launch adding the slices in order. [`LayerNorm::set_step`]
    /// rewrites the first launch, the one that reads `dy`.
    #[allow(clippy::too_many_arguments)]
    pub fn backward_params(
        &self,
        gpu: &Gpu,
        x: &Tensor,
        dy: &Tensor,
        mean: &Tensor,
        rstd: &Tensor,
        dgamma: &Tensor,
        dbeta: &Tensor,
        accumulate: Accumulate,
    ) -> Result<Dispatch, GpuError> {
        self.check(&[x, dy], &[dgamma, dbeta], &[mean, rstd])?;
        let params = self.params(accumulate, 0);
        let (slices, _) = self.grad_slices();
        let grid = [self.channels as u32, slices as u32, 1];
        if slices == 1 {
            let tensors = [x, dy, mean, rstd, dgamma, dbeta];
            return gpu.dispatch(&BACKWARD_PARAMS, &[], &params, &tensors, grid);
        }
        let partial = |t: &Tensor| {
            gpu.zeros(
                &format!("{} partials", t.name()),
                &[slices, self.channels],
                DType::F32,
            )
        };
        let (pg, pb) = (partial(dgamma)?, partial(dbeta)?);
        let tensors = [x, dy, mean, rstd, &pg, &pb];
        let first = gpu.dispatch(&BACKWARD_PARAMS, &[], &params, &tensors, grid)?;
        let max = gpu.limits().max_compute_workgroups_per_dimension;
        let groups = grid_1d(self.channels, 64, max);
        let sum = gpu.dispatch(
            &PARAMS_SUM,
            &[],
            &params,
            &[&pg, &pb, dgamma, dbeta],
            groups,
        )?;
        Ok(first.then(sum))
    }
}

/// f64 reference, for tests.
pub mod cpu {
    use super::LayerNorm;

    fn at(ln: &LayerNorm, o: usize, c: usize, t: usize) -> usize {
        (o * ln.channels + c) * ln.steps + t
    }

    /// `y = γ ⊙ (x − μ)/√(v + ε) + β` over `[outer, channels, steps]`, with μ and the biased
    /// variance v taken over the channels of each (outer, step).
    pub fn forward(ln: &LayerNorm, x: &[f64], gamma: &[f64], beta: &[f64]) -> Vec<f64> {
        let mut y = vec![0.0; ln.len()];
        let c = ln.channels as f64;
        for o in 0..ln.outer {
            for t in 0..ln.steps {
                let mu = (0..ln.channels).map(|k| x[at(ln, o, k, t)]).sum::<f64>() / c;
                let var = (0..ln.channels)
                    .map(|k| (x[at(ln, o, k, t)] - mu).powi(2))
                    .sum::<f64>()
                    / c;
                let r = 1.0 / (var + ln.eps as f64).sqrt();
                for k in 0..ln.channels {
                    let i = at(ln, o, k, t);
                    y[i] = gamma[k] * (x[i] - mu) * r + beta[k];
                }
            }
        }
        y
    }

    /// `(dx, dγ, dβ)` for upstream `dy`.
    pub fn backward(
        ln: &LayerNorm,
        x: &[f64],
        gamma: &[f64],
        dy: &[f64],
    ) -> (Vec<f64>, Vec<f64>, Vec<f64>) {
        let mut dx = vec![0.0; ln.len()];
        let mut dg = vec![0.0; ln.channels];
        let mut db = vec![0.0; ln.channels];
        let c = ln.channels as f64;
        for o in 0..ln.outer {
            for t in 0..ln.steps {
                let idx: Vec<usize> = (0..ln.channels).map(|k| at(ln, o, k, t)).collect();
                let mu = idx.iter().map(|&i| x[i]).sum::<f64>() / c;
                let var = idx.iter().map(|&i| (x[i] - mu).powi(2)).sum::<f64>() / c;
                let r = 1.0 / (var + ln.eps as f64).sqrt();
                let xh: Vec<f64> = idx.iter().map(|&i| (x[i] - mu) * r).collect();
                let g: Vec<f64> = idx
                    .iter()
                    .enumerate()
                    .map(|(k, &i)| dy[i] * gamma[k])
                    .collect();
                let sg: f64 = g.iter().sum();
                let sgx: f64 = g.iter().zip(&xh).map(|(a, b)| a * b).sum();
                for (k, &i) in idx.iter().enumerate() {
                    dx[i] = r / c * (c * g[k] - sg - xh[k] * sgx);
                    dg[k] += dy[i] * xh[k];
                    db[k] += dy[i];
                }
            }
        }
        (dx, dg, db)
    }
}
