//! The T-GCN baseline of Table III (Zhao et al. [23]; docs/model.md "Baselines"): a GRU
//! whose gates are graph convolutions, run over the window's T steps, then the head on
//! the last state. Per step t, with Â the renormalised adjacency and x_t `[B, N, F]`:
//!
//! ```text
//! r = σ(Â (x_t·Wx_r + h·Wh_r) + b_r)        u = σ(Â (x_t·Wx_u + h·Wh_u) + b_u)
//! c = tanh(Â (x_t·Wx_c + (r ⊙ h)·Wh_c) + b_c)
//! h' = u ⊙ h + (1 − u) ⊙ c                   (h = 0 before step 0)
//! ```
//!
//! The time loop is one dispatch chain per step, recorded into the same schedule, with
//! every step's state on the device. The backward pass runs through time in reverse:
//! weight gradients accumulate over the steps, and ∂ℒ/∂h ping-pongs between two tensors.
//! The f64 reference is `model::reference::recurrent`.

use super::block::ParamTable;
use super::config::ModelConfig;
use super::schedule::Steps;
use crate::gpu::{DType, Gpu, GpuError, Tensor};
use crate::graph::Graph;
use crate::ops::bias::Bias;
use crate::ops::elementwise::{
    binary_backward, binary_forward, unary_backward, unary_forward, Binary, Unary,
};
use crate::ops::gru;
use crate::ops::matmul::Matmul;
use crate::ops::time_step::TimeStep;
use crate::ops::Accumulate;

/// The gates, in parameter order: reset, update, candidate.
pub const GATES: [&str; 3] = ["r", "u", "c"];

/// One step's saved tensors, `[B·N, ·]` row-major.
struct Step {
    /// x_t `[B, N, F]`.
    x: Tensor,
    r: Tensor,
    u: Tensor,
    /// r ⊙ h_prev.
    rh: Tensor,
    c: Tensor,
    /// The new state h_t.
    h: Tensor,
}

/// T-GCN's tensors and ops for one batch size (part of a [`super::Network`]).
pub(super) struct RecurrentBody {
    adjacency: Tensor,
    /// The state before step 0 (zeros).
    h0: Tensor,
    steps: Vec<Step>,
    /// Forward scratch shared by the steps: the product before the graph mix and after.
    pre: Tensor,
    mixed: Tensor,
    batch: usize,
    nodes: usize,
    features: usize,
    hidden: usize,
    window: usize,
}

impl RecurrentBody {
    /// Allocates the per-step state for `batch` windows on `graph`.
    pub(super) fn new(
        gpu: &Gpu,
        config: &ModelConfig,
        graph: &Graph,
        batch: usize,
    ) -> Result<RecurrentBody, GpuError> {
        let (n, f, h) = (config.nodes, config.features, config.hidden);
        let a: Vec<f32> = {
            let m = graph.renormalized_adjacency();
            (0..n)
                .flat_map(|i| (0..n).map(move |j| (i, j)))
                .map(|(i, j)| m[(i, j)] as f32)
                .collect()
        };
        let adjacency = gpu.upload("tgcn.adjacency", &[n, n], &a)?;
        let state = |name: String| gpu.zeros(&name, &[batch * n, h], DType::F32);
        let steps = (0..config.window)
            .map(|t| Step {
                x: gpu.zeros(&format!("tgcn.x{t}"), &[batch * n, f], DType::F32),
                r: state(format!("tgcn.r{t}")),
                u: state(format!("tgcn.u{t}")),
                rh: state(format!("tgcn.rh{t}")),
                c: state(format!("tgcn.c{t}")),
                h: state(format!("tgcn.h{t}")),
            })
            .collect();
        Ok(RecurrentBody {
            adjacency,
            h0: state("tgcn.h0".into()),
            steps,
            pre: state("tgcn.pre".into()),
            mixed: state("tgcn.mixed".into()),
            batch,
            nodes: n,
            features: f,
            hidden: h,
            window: config.window,
        })
    }

    /// The last state h_{T−1} `[B, N·H]`: the head's input.
    pub(super) fn last_state(&self) -> &Tensor {
        &self.steps[self.window - 1].h
    }

    fn rows(&self) -> usize {
        self.batch * self.nodes
    }

    fn input_product(&self) -> Matmul {
        Matmul::new(self.rows(), self.hidden, self.features)
    }

    fn state_product(&self) -> Matmul {
        Matmul::new(self.rows(), self.hidden, self.hidden)
    }

    fn graph_mix(&self) -> Matmul {
        Matmul::new(self.nodes, self.hidden, self.nodes)
            .batched(self.batch)
            .share_a(true)
    }

    fn bias(&self) -> Bias {
        Bias {
            outer: self.rows(),
            channels: self.hidden,
            inner: 1,
        }
    }

    fn gather(&self, t: usize) -> TimeStep {
        TimeStep {
            rows: self.rows() * self.features,
            steps: self.window,
            step: t,
        }
    }

    fn previous(&self, t: usize) -> &Tensor {
        if t == 0 {
            &self.h0
        } else {
            &self.steps[t - 1].h
        }
    }

    /// Appends `act(Â (x·Wx + h·Wh) + b)` of gate `g` into `out`.
    #[allow(clippy::too_many_arguments)]
    fn gate_forward(
        &self,
        gpu: &Gpu,
        table: &dyn ParamTable,
        g: &str,
        x: &Tensor,
        h: &Tensor,
        act: Unary,
        out: &Tensor,
        steps: &mut Steps,
    ) -> Result<(), GpuError> {
        let p = |s: &str| table.param(&format!("cell.{g}.{s}"));
        steps.run(self.input_product().forward(
            gpu,
            x,
            p("wx"),
            &self.pre,
            Accumulate::Overwrite,
        ))?;
        steps.run(
            self.state_product()
                .forward(gpu, h, p("wh"), &self.pre, Accumulate::Add),
        )?;
        steps.run(self.graph_mix().forward(
            gpu,
            &self.adjacency,
            &self.pre,
            &self.mixed,
            Accumulate::Overwrite,
        ))?;
        steps.run(self.bias().forward(gpu, p("bias"), &self.mixed))?;
        steps.run(unary_forward(
            gpu,
            act,
            &self.mixed,
            out,
            Accumulate::Overwrite,
        ))?;
        Ok(())
    }

    /// Appends the time loop from x (`input` `[B, N, F, T]`) to h_{T−1}.
    pub(super) fn forward(
        &self,
        gpu: &Gpu,
        table: &dyn ParamTable,
        input: &Tensor,
        steps: &mut Steps,
    ) -> Result<(), GpuError> {
        for (t, s) in self.steps.iter().enumerate() {
            let h = self.previous(t);
            steps.run(self.gather(t).forward(gpu, input, &s.x))?;
            self.gate_forward(gpu, table, "r", &s.x, h, Unary::Sigmoid, &s.r, steps)?;
            self.gate_forward(gpu, table, "u", &s.x, h, Unary::Sigmoid, &s.u, steps)?;
            steps.run(binary_forward(
                gpu,
                Binary::Mul,
                &s.r,
                h,
                &s.rh,
                Accumulate::Overwrite,
            ))?;
            self.gate_forward(gpu, table, "c", &s.x, &s.rh, Unary::Tanh, &s.c, steps)?;
            steps.run(gru::forward(gpu, &s.u, h, &s.c, &s.h))?;
        }
        Ok(())
    }

    /// Appends backpropagation through time from ∂ℒ/∂h_{T−1} (`d_last`, overwritten as
    /// scratch) to the cell's parameter gradients and ∂ℒ/∂x (`input_grad`).
    pub(super) fn backward(
        &self,
        gpu: &Gpu,
        table: &dyn ParamTable,
        d_last: &Tensor,
        input_grad: &Tensor,
        steps: &mut Steps,
    ) -> Result<(), GpuError> {
        let state = |name: &str| gpu.zeros(name, &[self.rows(), self.hidden], DType::F32);
        // ∂ℒ/∂h of the current step and of the one before.
        let dh = [d_last.clone(), state("tgcn.dh (other)")];
        let (du, dc, dr, drh) = (
            state("tgcn.du"),
            state("tgcn.dc"),
            state("tgcn.dr"),
            state("tgcn.drh"),
        );
        let (dz, dp) = (state("tgcn.dz"), state("tgcn.dp"));
        let dx = gpu.zeros("tgcn.dx", &[self.rows(), self.features], DType::F32);
        let last = self.window - 1;
        for (t, s) in self.steps.iter().enumerate().rev() {
            let h = self.previous(t);
            let (cur, prev) = (&dh[(last - t) % 2], &dh[(last - t + 1) % 2]);
            // The first step processed writes the weight gradients; later ones add.
            let acc = if t == last {
                Accumulate::Overwrite
            } else {
                Accumulate::Add
            };
            steps.run(gru::backward(
                gpu,
                &s.u,
                h,
                &s.c,
                cur,
                &du,
                &dc,
                prev,
                Accumulate::Overwrite,
            ))?;
            // The candidate: its input product reads r ⊙ h.
            self.gate_backward(
                gpu,
                table,
                "c",
                Unary::Tanh,
                (&s.c, &dc),
                (&s.x, &s.rh),
                (&dz, &dp),
                acc,
                &drh,
                Accumulate::Overwrite,
                &dx,
                Accumulate::Overwrite,
                steps,
            )?;
            steps.run(binary_backward(
                gpu,
                Binary::Mul,
                h,
                &drh,
                &dr,
                Accumulate::Overwrite,
            ))?;
            steps.run(binary_backward(
                gpu,
                Binary::Mul,
                &s.r,
                &drh,
                prev,
                Accumulate::Add,
            ))?;
            for (g, out, d_out) in [("r", &s.r, &dr), ("u", &s.u, &du)] {
                self.gate_backward(
                    gpu,
                    table,
                    g,
                    Unary::Sigmoid,
                    (out, d_out),
                    (&s.x, h),
                    (&dz, &dp),
                    acc,
                    prev,
                    Accumulate::Add,
                    &dx,
                    Accumulate::Add,
                    steps,
                )?;
            }
            steps.run(self.gather(t).backward(gpu, &dx, input_grad, acc))?;
        }
        Ok(())
    }

    /// Appends the backward of one gate `out = act(Â (x·Wx + h·Wh) + b)` given
    /// `d_out`: the gate's parameter gradients (`acc`), ∂ℒ/∂h into `dh` (`dh_acc`) and
    /// ∂ℒ/∂x into `dx` (`dx_acc`). `scratch` is (∂ℒ/∂ mixed, ∂ℒ/∂ pre).
    #[allow(clippy::too_many_arguments)]
    fn gate_backward(
        &self,
        gpu: &Gpu,
        table: &dyn ParamTable,
        g: &str,
        act: Unary,
        (out, d_out): (&Tensor, &Tensor),
        (x, h): (&Tensor, &Tensor),
        (dz, dp): (&Tensor, &Tensor),
        acc: Accumulate,
        dh: &Tensor,
        dh_acc: Accumulate,
        dx: &Tensor,
        dx_acc: Accumulate,
        steps: &mut Steps,
    ) -> Result<(), GpuError> {
        let name = |s: &str| format!("cell.{g}.{s}");
        steps.run(unary_backward(
            gpu,
            act,
            out,
            d_out,
            dz,
            Accumulate::Overwrite,
        ))?;
        steps.run(
            self.bias()
                .backward(gpu, dz, table.grad(&name("bias")), acc),
        )?;
        steps.run(self.graph_mix().backward_b(
            gpu,
            &self.adjacency,
            dz,
            dp,
            Accumulate::Overwrite,
        ))?;
        let (mx, mh) = (self.input_product(), self.state_product());
        steps.run(mx.backward_b(gpu, x, dp, table.grad(&name("wx")), acc))?;
        steps.run(mx.backward_a(gpu, table.param(&name("wx")), dp, dx, dx_acc))?;
        steps.run(mh.backward_b(gpu, h, dp, table.grad(&name("wh")), acc))?;
        steps.run(mh.backward_a(gpu, table.param(&name("wh")), dp, dh, dh_acc))?;
        Ok(())
    }
}

/// Forward FLOPs of T-GCN for `batch` windows: per step and gate the two products and
/// the graph mix, then the head.
pub fn forward_flops(config: &ModelConfig, batch: usize) -> f64 {
    let f = |x: usize| x as f64;
    let (b, n, h) = (f(batch), f(config.nodes), f(config.hidden));
    let per_gate = 2.0 * b * n * h * (f(config.features) + h + n);
    f(config.window) * 3.0 * per_gate + 2.0 * b * f(config.outputs) * n * h
}
