//! ConvLSTM on the device: its tensors and its time loop's launches for one batch size,
//! part of a [`crate::model::Network`].

use crate::gpu::{DType, Gpu, GpuError, Tensor};
use crate::model::config::ModelConfig;
use crate::model::recurrent::wgsl::TimeLoop;
use crate::model::schedule::ParamTable;
use crate::model::schedule::Steps;
use crate::ops::bias::Bias;
use crate::ops::lstm::Lstm;
use crate::ops::matmul::Matmul;
use crate::ops::time_step::TimeStep;
use crate::ops::unfold2d::Unfold2d;
use crate::ops::Accumulate;

/// One step's saved tensors.
struct Step {
    /// x_t `[B, 1, N, F]`.
    x: Tensor,
    /// The gates' pre-activations `[B, 4C, N·F]`.
    z: Tensor,
    /// The cell c_t `[B, C, N, F]`.
    c: Tensor,
    /// The hidden state h_t `[B, C, N, F]`.
    h: Tensor,
}

/// ConvLSTM's tensors and ops for one batch size (part of a [`crate::model::Network`]).
pub(crate) struct ConvLstmBody {
    /// h and c before step 0, and ∂ℒ/∂c after the last step: zeros, never written.
    zeros: Tensor,
    steps: Vec<Step>,
    /// Scratch: the unfolded x_t `[B, k², N·F]` and h `[B, C·k², N·F]`.
    col_x: Tensor,
    col_h: Tensor,
    batch: usize,
    nodes: usize,
    features: usize,
    channels: usize,
    kernel: usize,
    window: usize,
}

impl ConvLstmBody {
    /// Allocates the per-step state for `batch` windows.
    pub(crate) fn new(
        gpu: &Gpu,
        config: &ModelConfig,
        batch: usize,
    ) -> Result<ConvLstmBody, GpuError> {
        let (n, f, c, k) = (
            config.nodes,
            config.features,
            config.channels,
            config.kernel,
        );
        let state = |name: String| gpu.zeros(&name, &[batch, c, n, f], DType::F32);
        let steps = (0..config.window)
            .map(|t| {
                Ok(Step {
                    x: gpu.zeros(&format!("convlstm.x{t}"), &[batch, 1, n, f], DType::F32)?,
                    z: gpu.zeros(
                        &format!("convlstm.z{t}"),
                        &[batch, 4 * c, n * f],
                        DType::F32,
                    )?,
                    c: state(format!("convlstm.c{t}"))?,
                    h: state(format!("convlstm.h{t}"))?,
                })
            })
            .collect::<Result<_, GpuError>>()?;
        Ok(ConvLstmBody {
            zeros: state("convlstm.zeros".into())?,
            steps,
            col_x: gpu.zeros("convlstm.col x", &[batch, k * k, n * f], DType::F32)?,
            col_h: gpu.zeros("convlstm.col h", &[batch, c * k * k, n * f], DType::F32)?,
            batch,
            nodes: n,
            features: f,
            channels: c,
            kernel: k,
            window: config.window,
        })
    }

    fn unfold(&self, channels: usize) -> Unfold2d {
        Unfold2d {
            batch: self.batch,
            channels,
            height: self.nodes,
            width: self.features,
            kernel: self.kernel,
        }
    }

    /// `z[b] (+)= W [4C, channels·k²] · col[b] [channels·k², N·F]`.
    fn conv(&self, channels: usize) -> Matmul {
        let kk = self.kernel * self.kernel;
        Matmul::new(4 * self.channels, self.nodes * self.features, channels * kk)
            .batched(self.batch)
            .share_a(true)
    }

    fn bias(&self) -> Bias {
        Bias {
            outer: self.batch,
            channels: 4 * self.channels,
            inner: self.nodes * self.features,
        }
    }

    fn cell(&self) -> Lstm {
        Lstm {
            batch: self.batch,
            state: self.channels * self.nodes * self.features,
        }
    }

    fn gather(&self, t: usize) -> TimeStep {
        TimeStep {
            rows: self.batch * self.nodes * self.features,
            steps: self.window,
            step: t,
        }
    }

    /// (h, c) before step t.
    fn previous(&self, t: usize) -> (&Tensor, &Tensor) {
        match t {
            0 => (&self.zeros, &self.zeros),
            _ => (&self.steps[t - 1].h, &self.steps[t - 1].c),
        }
    }
}

impl TimeLoop for ConvLstmBody {
    fn forward(
        &self,
        gpu: &Gpu,
        table: &dyn ParamTable,
        input: &Tensor,
        steps: &mut Steps,
    ) -> Result<(), GpuError> {
        let (ux, uh) = (self.unfold(1), self.unfold(self.channels));
        let (cx, ch) = (self.conv(1), self.conv(self.channels));
        for (t, s) in self.steps.iter().enumerate() {
            let (h, c) = self.previous(t);
            steps.run(self.gather(t).forward(gpu, input, &s.x))?;
            steps.run(ux.forward(gpu, &s.x, &self.col_x))?;
            steps.run(cx.forward(
                gpu,
                table.param("cell.wx"),
                &self.col_x,
                &s.z,
                Accumulate::Overwrite,
            ))?;
            if t > 0 {
                steps.run(uh.forward(gpu, h, &self.col_h))?;
                steps.run(ch.forward(
                    gpu,
                    table.param("cell.wh"),
                    &self.col_h,
                    &s.z,
                    Accumulate::Add,
                ))?;
            }
            steps.run(self.bias().forward(gpu, table.param("cell.bias"), &s.z))?;
            steps.run(self.cell().forward(gpu, &s.z, c, &s.c, &s.h))?;
        }
        Ok(())
    }

    fn backward(
        &self,
        gpu: &Gpu,
        table: &dyn ParamTable,
        d_output: &Tensor,
        input_grad: &Tensor,
        steps: &mut Steps,
    ) -> Result<(), GpuError> {
        let shape = [self.batch, self.channels, self.nodes, self.features];
        let state = |name: &str| gpu.zeros(name, &shape, DType::F32);
        // ∂ℒ/∂h and ∂ℒ/∂c of the current step and of the one before.
        let dh = [d_output.clone(), state("convlstm.dh (other)")?];
        let dc = [state("convlstm.dc")?, state("convlstm.dc (other)")?];
        let dz = gpu.zeros("convlstm.dz", self.steps[0].z.shape(), DType::F32)?;
        let dcol_x = gpu.zeros("convlstm.dcol x", self.col_x.shape(), DType::F32)?;
        let dcol_h = gpu.zeros("convlstm.dcol h", self.col_h.shape(), DType::F32)?;
        let dx = gpu.zeros("convlstm.dx", self.steps[0].x.shape(), DType::F32)?;
        let (ux, uh) = (self.unfold(1), self.unfold(self.channels));
        let (cx, ch) = (self.conv(1), self.conv(self.channels));
        let last = self.window - 1;
        for (t, s) in self.steps.iter().enumerate().rev() {
            let (h, c) = self.previous(t);
            let i = last - t;
            let (dh_cur, dh_prev) = (&dh[i % 2], &dh[(i + 1) % 2]);
            // After the last step nothing depends on c.
            let dc_cur = if t == last { &self.zeros } else { &dc[i % 2] };
            let dc_prev = &dc[(i + 1) % 2];
            // The first step processed writes the weight gradients; later ones add.
            let acc = if t == last {
                Accumulate::Overwrite
            } else {
                Accumulate::Add
            };
            steps.run(
                self.cell()
                    .backward(gpu, [&s.z, c, &s.c], dh_cur, dc_cur, &dz, dc_prev),
            )?;
            steps.run(self.bias().backward(gpu, &dz, table.grad("cell.bias"), acc))?;
            steps.run(ux.forward(gpu, &s.x, &self.col_x))?;
            steps.run(cx.backward_a(gpu, &self.col_x, &dz, table.grad("cell.wx"), acc))?;
            steps.run(cx.backward_b(
                gpu,
                table.param("cell.wx"),
                &dz,
                &dcol_x,
                Accumulate::Overwrite,
            ))?;
            steps.run(ux.backward(gpu, &dcol_x, &dx, Accumulate::Overwrite))?;
            steps.run(self.gather(t).backward(gpu, &dx, input_grad, acc))?;
            if t > 0 {
                // h_{t−1} fed the state convolution (h before step 0 is a constant).
                steps.run(uh.forward(gpu, h, &self.col_h))?;
                // Steps run from the last: the first of them writes ∂ℒ/∂Wh.
                steps.run(ch.backward_a(gpu, &self.col_h, &dz, table.grad("cell.wh"), acc))?;
                steps.run(ch.backward_b(
                    gpu,
                    table.param("cell.wh"),
                    &dz,
                    &dcol_h,
                    Accumulate::Overwrite,
                ))?;
                steps.run(uh.backward(gpu, &dcol_h, dh_prev, Accumulate::Overwrite))?;
            }
        }
        Ok(())
    }

    fn output(&self) -> &Tensor {
        &self.steps[self.window - 1].h
    }
}
