//! Gated dilated causal convolution (docs/model.md step 4): the causal unfolding that turns
//! the convolution into one GEMM per row, and the tanh ⊙ σ gate, forward and backward,
//! with the f64 CPU reference of the whole gated convolution.

use crate::gpu::{grid_1d, Binding, Dispatch, Gpu, GpuError, Kernel, Shader, Tensor};
use crate::ops::Accumulate;

/// The WGSL module of this family (`shaders/gated_dcc.wgsl`: the unfolding and the gate,
/// forward and backward).
pub static SHADER: Shader = Shader {
    name: "gated_dcc",
    source: include_str!("../../../../shaders/gated_dcc.wgsl"),
    base: None,
};

static UNFOLD_FWD: Kernel = Kernel {
    shader: &SHADER,
    entry: "unfold_forward",
    bindings: &[Binding::read(1), Binding::read_write(2)],
};
/// dcol, x (read only with `relu_input`), dx.
static UNFOLD_BWD: Kernel = Kernel {
    shader: &SHADER,
    entry: "unfold_backward",
    bindings: &[Binding::read(1), Binding::read(3), Binding::read_write(2)],
};
static UNFOLD_FWD4: Kernel = Kernel {
    shader: &SHADER,
    entry: "unfold_forward4",
    bindings: &[Binding::read(1), Binding::read_write(2)],
};
static UNFOLD_BWD4: Kernel = Kernel {
    shader: &SHADER,
    entry: "unfold_backward4",
    bindings: &[Binding::read(1), Binding::read(3), Binding::read_write(2)],
};
static GATE_FWD: Kernel = Kernel {
    shader: &SHADER,
    entry: "gate_forward",
    bindings: &[Binding::read(1), Binding::read(2), Binding::read_write(3)],
};
static GATE_BWD_STACKED: Kernel = Kernel {
    shader: &SHADER,
    entry: "gate_backward_stacked",
    bindings: &[
        Binding::read(1),
        Binding::read(2),
        Binding::read(3),
        Binding::read_write(4),
    ],
};

/// Causal unfolding of `x [rows, channels, steps]` into `col [rows, channels, kernel, steps]`
/// with `col[r, c, k, t] = x[r, c, t − dilation·k]` (zero before the start).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Unfold {
    /// Independent rows convolved separately (B·N in a block, row r = b·N + n).
    pub rows: usize,
    /// Input channels per row (C: the convolution's input is Z).
    pub channels: usize,
    /// Temporal kernel size K: lags k = 0..K, k = 0 being the current step.
    pub kernel: usize,
    /// Input time steps per row and channel (T).
    pub steps: usize,
    /// Steps between consecutive lags, d_l = 2^l in block l (1 in every block of
    /// `iastgcn-t`); docs/model.md step 4.
    pub dilation: usize,
    /// Output steps kept, the last ones (`steps` for the whole unfolding): col is
    /// `[rows, channels, kernel, outputs]` and holds steps `steps − outputs ..`.
    pub outputs: usize,
}

/// What [`Unfold::backward_through_relu`] masks by: the unfolded input, a ReLU's output.
pub struct ReluOutput<'t>(pub &'t Tensor);

crate::gpu::uniform! {
    pub(crate) struct UnfoldParams = UnfoldParams in SHADER {
        rows: u32,
        channels: u32,
        kernel: u32,
        steps: u32,
        dilation: u32,
        accumulate: u32,
        outputs: u32,
        relu_input: u32,
    }
}

crate::gpu::uniform! {
    pub(crate) struct GateParams = GateParams in SHADER {
        n: u32,
        block: u32,
        _pad1: u32,
        _pad2: u32,
    }
}

impl Unfold {
    /// Number of elements of the input x, `rows · channels · steps`.
    pub fn input_len(&self) -> usize {
        self.rows * self.channels * self.steps
    }

    /// Number of elements of the unfolded col, `rows · channels · kernel · outputs`.
    pub fn col_len(&self) -> usize {
        self.rows * self.channels * self.kernel * self.outputs
    }

    /// The first step col holds.
    pub fn first_output(&self) -> usize {
        self.steps - self.outputs
    }

    /// Four steps per invocation (vector stores) when both step counts allow it.
    pub fn quads(&self) -> bool {
        self.steps.is_multiple_of(4) && self.outputs.is_multiple_of(4)
    }

    fn check(&self) -> Result<(), GpuError> {
        if self.outputs == 0 || self.outputs > self.steps {
            return Err(GpuError::Shape {
                tensor: "unfold outputs".into(),
                expected: format!("1..={} steps", self.steps),
                got: self.outputs.to_string(),
            });
        }
        Ok(())
    }

    fn params(&self, accumulate: Accumulate) -> UnfoldParams {
        UnfoldParams {
            rows: self.rows as u32,
            channels: self.channels as u32,
            kernel: self.kernel as u32,
            steps: self.steps as u32,
            dilation: self.dilation as u32,
            accumulate: accumulate.flag(),
            outputs: self.outputs as u32,
            relu_input: 0,
        }
    }

    /// Writes (overwrites) `col [rows, channels, kernel, outputs]` from
    /// `x [rows, channels, steps]`; an error if `outputs` is 0 or exceeds `steps`, or a
    /// tensor's length differs.
    pub fn forward(&self, gpu: &Gpu, x: &Tensor, col: &Tensor) -> Result<Dispatch, GpuError> {
        self.check()?;
        x.expect_len(self.input_len())?;
        col.expect_len(self.col_len())?;
        let max = gpu.limits().max_compute_workgroups_per_dimension;
        let (kernel, threads) = if self.quads() {
            (&UNFOLD_FWD4, self.col_len() / 4)
        } else {
            (&UNFOLD_FWD, self.col_len())
        };
        gpu.dispatch(
            kernel,
            &[],
            &self.params(Accumulate::Overwrite),
            &[x, col],
            grid_1d(threads, 256, max),
        )
    }

    /// `dx (+)= Σ_k dcol[.., k, t + dilation·k]`.
    pub fn backward(
        &self,
        gpu: &Gpu,
        dcol: &Tensor,
        dx: &Tensor,
        accumulate: Accumulate,
    ) -> Result<Dispatch, GpuError> {
        self.backward_masked(gpu, dcol, dx, None, accumulate)
    }

    /// The gradient before the ReLU whose output `x` was unfolded: `(x > 0) ·` what
    /// [`Unfold::backward`] gives (overwrites `dx`; one elementwise pass fewer).
    pub fn backward_through_relu(
        &self,
        gpu: &Gpu,
        dcol: &Tensor,
        x: ReluOutput,
        dx: &Tensor,
    ) -> Result<Dispatch, GpuError> {
        x.0.expect_len(self.input_len())?;
        self.backward_masked(gpu, dcol, dx, Some(x.0), Accumulate::Overwrite)
    }

    fn backward_masked(
        &self,
        gpu: &Gpu,
        dcol: &Tensor,
        dx: &Tensor,
        mask: Option<&Tensor>,
        accumulate: Accumulate,
    ) -> Result<Dispatch, GpuError> {
        self.check()?;
        dcol.expect_len(self.col_len())?;
        dx.expect_len(self.input_len())?;
        let max = gpu.limits().max_compute_workgroups_per_dimension;
        let (kernel, threads) = if self.quads() {
            (&UNFOLD_BWD4, self.input_len() / 4)
        } else {
            (&UNFOLD_BWD, self.input_len())
        };
        let params = UnfoldParams {
            relu_input: u32::from(mask.is_some()),
            ..self.params(accumulate)
        };
        gpu.dispatch(
            kernel,
            &[],
            &params,
            &[dcol, mask.unwrap_or(dcol), dx],
            grid_1d(threads, 256, max),
        )
    }
}

fn gate_params(n: usize) -> GateParams {
    GateParams {
        n: n as u32,
        block: 0,
        _pad1: 0,
        _pad2: 0,
    }
}

/// `h = tanh(f) ⊙ σ(g)`.
pub fn gate_forward(gpu: &Gpu, f: &Tensor, g: &Tensor, h: &Tensor) -> Result<Dispatch, GpuError> {
    let n = h.numel();
    f.expect_len(n)?;
    g.expect_len(n)?;
    let max = gpu.limits().max_compute_workgroups_per_dimension;
    gpu.dispatch(
        &GATE_FWD,
        &[],
        &gate_params(n),
        &[f, g, h],
        grid_1d(n, 256, max),
    )
}

/// The gate's backward: `df, dg` from `dh`, written stacked per item into `dfg`: item r (of `block` = C·T
/// elements each) holds `[df_r; dg_r]`, `[2C, T]` (overwritten).
pub fn gate_backward_stacked(
    gpu: &Gpu,
    f: &Tensor,
    g: &Tensor,
    dh: &Tensor,
    dfg: &Tensor,
    block: usize,
) -> Result<Dispatch, GpuError> {
    let n = dh.numel();
    for t in [f, g] {
        t.expect_len(n)?;
    }
    dfg.expect_len(2 * n)?;
    if block == 0 || !n.is_multiple_of(block) {
        return Err(GpuError::Shape {
            tensor: dh.name().to_string(),
            expected: format!("a whole number of items of {block} elements"),
            got: format!("{n} elements"),
        });
    }
    let max = gpu.limits().max_compute_workgroups_per_dimension;
    let params = GateParams {
        block: block as u32,
        ..gate_params(n)
    };
    gpu.dispatch(
        &GATE_BWD_STACKED,
        &[],
        &params,
        &[f, g, dh, dfg],
        grid_1d(n, 256, max),
    )
}

/// The f64 reference of step 4, forward and backward side by side: what the WGSL kernels
/// and the native path are tested against, and what the network reference
/// (`model::reference`) composes.
pub mod cpu {
    use super::Unfold;

    /// The unfolding `col [rows, channels, kernel, outputs]` of `x [rows, channels, steps]`,
    /// zero where `t − dilation·k < 0`.
    pub fn unfold(u: &Unfold, x: &[f64]) -> Vec<f64> {
        let mut col = vec![0.0; u.col_len()];
        let first = u.first_output();
        for rc in 0..u.rows * u.channels {
            for k in 0..u.kernel {
                let lag = u.dilation * k;
                for t in lag.max(first)..u.steps {
                    col[(rc * u.kernel + k) * u.outputs + t - first] = x[rc * u.steps + t - lag];
                }
            }
        }
        col
    }

    /// `dx [rows, channels, steps]` from `dcol [rows, channels, kernel, outputs]`: each col
    /// element's gradient added back to the input step it was copied from.
    pub fn unfold_backward(u: &Unfold, dcol: &[f64]) -> Vec<f64> {
        let mut dx = vec![0.0; u.input_len()];
        let first = u.first_output();
        for rc in 0..u.rows * u.channels {
            for k in 0..u.kernel {
                let lag = u.dilation * k;
                for t in lag.max(first)..u.steps {
                    dx[rc * u.steps + t - lag] += dcol[(rc * u.kernel + k) * u.outputs + t - first];
                }
            }
        }
        dx
    }

    /// `G[r, o, t] = bias[o] + Σ_c Σ_k weight[o, c, k] · x[r, c, t − d·k]` (docs/model.md step 4)
    /// over the kept steps: `[rows, out_channels, u.outputs]`.
    pub fn conv(
        u: &Unfold,
        out_channels: usize,
        weight: &[f64],
        bias: &[f64],
        x: &[f64],
    ) -> Vec<f64> {
        let col = unfold(u, x);
        let (ck, steps) = (u.channels * u.kernel, u.outputs);
        let mut out = vec![0.0; u.rows * out_channels * steps];
        for r in 0..u.rows {
            for o in 0..out_channels {
                let dst = &mut out[(r * out_channels + o) * steps..][..steps];
                dst.iter_mut().for_each(|v| *v = bias[o]);
                for j in 0..ck {
                    let w = weight[o * ck + j];
                    let src = &col[(r * ck + j) * steps..][..steps];
                    for (d, s) in dst.iter_mut().zip(src) {
                        *d += w * s;
                    }
                }
            }
        }
        out
    }

    /// The backward of [`conv`] from `dg` `[rows, out_channels, u.outputs]`: `(dx, dweight,
    /// dbias)`, dx `[rows, channels, steps]` through the unfolding's adjoint.
    pub fn conv_backward(
        u: &Unfold,
        out_channels: usize,
        weight: &[f64],
        x: &[f64],
        dg: &[f64],
    ) -> (Vec<f64>, Vec<f64>, Vec<f64>) {
        let col = unfold(u, x);
        let (ck, steps) = (u.channels * u.kernel, u.outputs);
        let mut dw = vec![0.0; out_channels * ck];
        let mut db = vec![0.0; out_channels];
        let mut dcol = vec![0.0; col.len()];
        for r in 0..u.rows {
            for o in 0..out_channels {
                let g = &dg[(r * out_channels + o) * steps..][..steps];
                db[o] += g.iter().sum::<f64>();
                for j in 0..ck {
                    let at = (r * ck + j) * steps;
                    let w = weight[o * ck + j];
                    let (c, d) = (&col[at..at + steps], &mut dcol[at..at + steps]);
                    dw[o * ck + j] += g.iter().zip(c).map(|(g, c)| g * c).sum::<f64>();
                    for (d, g) in d.iter_mut().zip(g) {
                        *d += w * g;
                    }
                }
            }
        }
        (unfold_backward(u, &dcol), dw, db)
    }

    /// `H = tanh(f) ⊙ σ(g)` element by element (docs/model.md step 4).
    pub fn gate(f: &[f64], g: &[f64]) -> Vec<f64> {
        f.iter()
            .zip(g)
            .map(|(f, g)| f.tanh() / (1.0 + (-g).exp()))
            .collect()
    }

    /// `[a_r; b_r]` for each item r of `block` elements: the stacked layout.
    pub fn stack(a: &[f64], b: &[f64], block: usize) -> Vec<f64> {
        a.chunks(block)
            .zip(b.chunks(block))
            .flat_map(|(x, y)| x.iter().chain(y).copied())
            .collect()
    }

    /// `(df, dg)` of the gate from the pre-activations `f`, `g` and upstream `dh`:
    /// `df = dh·σ(g)·(1 − tanh²f)`, `dg = dh·tanh(f)·σ(g)·(1 − σ(g))` (not stacked).
    pub fn gate_backward(f: &[f64], g: &[f64], dh: &[f64]) -> (Vec<f64>, Vec<f64>) {
        let mut df = Vec::with_capacity(f.len());
        let mut dg = Vec::with_capacity(f.len());
        for ((f, g), d) in f.iter().zip(g).zip(dh) {
            let th = f.tanh();
            let sg = 1.0 / (1.0 + (-g).exp());
            df.push(d * sg * (1.0 - th * th));
            dg.push(d * th * sg * (1.0 - sg));
        }
        (df, dg)
    }
}
