//! A recurrent baseline on the device: its tensors and its time loop's launches for one
//! batch size, part of a [`crate::model::Network`], and the time loop the network's
//! schedules drive ([`TimeLoop`], ConvLSTM's too).

use super::{attends_over_time, supports, weight_name};
use crate::gpu::{DType, Gpu, GpuError, Tensor};
use crate::graph::Graph;
use crate::model::config::ModelConfig;
use crate::model::schedule::ParamTable;
use crate::model::schedule::Steps;
use crate::ops::bias::Bias;
use crate::ops::elementwise::{
    binary_backward, binary_forward, unary_backward, unary_forward, Binary, Unary,
};
use crate::ops::gru;
use crate::ops::matmul::Matmul;
use crate::ops::softmax::Softmax;
use crate::ops::time_step::TimeStep;
use crate::ops::Accumulate;

/// What the network's schedules need of a model that runs a cell over the window's steps
/// (the GRU baselines here, ConvLSTM in `model::conv_lstm`): the time loop forward, the
/// head's input it leaves, and backpropagation through time.
pub(crate) trait TimeLoop {
    /// Appends the time loop from x (`input` `[B, N, F, T]`) to the head's input.
    fn forward(
        &self,
        gpu: &Gpu,
        table: &dyn ParamTable,
        input: &Tensor,
        steps: &mut Steps,
    ) -> Result<(), GpuError>;

    /// Appends backpropagation through time from ∂ℒ/∂(head input) (`d_output`, which may
    /// be overwritten as scratch) to the cell's parameter gradients and ∂ℒ/∂x
    /// (`input_grad`, overwritten).
    fn backward(
        &self,
        gpu: &Gpu,
        table: &dyn ParamTable,
        d_output: &Tensor,
        input_grad: &Tensor,
        steps: &mut Steps,
    ) -> Result<(), GpuError>;

    /// What the head reads, `[B, width]`.
    fn output(&self) -> &Tensor;
}

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

/// The attention over time of EAT-GCN: its saved and scratch tensors.
struct TimeAttention {
    /// tanh(h_t·Wa + ba) `[B, A]` of every step.
    score_hidden: Vec<Tensor>,
    /// Scratch `[B, A]`: the pre-activation, then its gradient.
    hidden_scratch: Tensor,
    /// Scratch `[B, A]`: ∂ℒ/∂ tanh(·).
    d_hidden: Tensor,
    /// Scratch `[B]`: one step's e_t or α_t (or their gradients).
    column: Tensor,
    /// e `[B, T]`, then ∂ℒ/∂e in the backward pass.
    scores: Tensor,
    /// α = softmax_t(e) `[B, T]`.
    weights: Tensor,
    /// ∂ℒ/∂α `[B, T]`.
    d_weights: Tensor,
    /// Σ_t α_t h_t `[B, N·H]`: the head's input.
    context: Tensor,
    /// Its width A (= H).
    width: usize,
}

/// A recurrent baseline's tensors and ops for one batch size (part of a
/// [`crate::model::Network`]).
pub(crate) struct RecurrentBody {
    /// S_k `[N, N]`; `None` where S_k = I (T_0), whose product is skipped.
    supports: Vec<Option<Tensor>>,
    /// The state before step 0 (zeros).
    h0: Tensor,
    steps: Vec<Step>,
    /// Forward scratch shared by the steps: one support's product before its graph mix,
    /// and the gate's sum over the supports.
    pre: Tensor,
    mixed: Tensor,
    attention: Option<TimeAttention>,
    batch: usize,
    nodes: usize,
    features: usize,
    hidden: usize,
    window: usize,
}

impl RecurrentBody {
    /// Allocates the per-step state for `batch` windows on `graph`.
    pub(crate) fn new(
        gpu: &Gpu,
        config: &ModelConfig,
        graph: &Graph,
        batch: usize,
    ) -> Result<RecurrentBody, GpuError> {
        let (n, f, h, t) = (config.nodes, config.features, config.hidden, config.window);
        let all = supports(graph, config);
        let supports = all
            .chunks(n * n)
            .enumerate()
            .map(|(k, s)| {
                let identity = (0..n * n).all(|i| s[i] == if i % (n + 1) == 0 { 1.0 } else { 0.0 });
                if identity {
                    return Ok(None);
                }
                let data: Vec<f32> = s.iter().map(|&v| v as f32).collect();
                gpu.upload(&format!("cell.support{k}"), &[n, n], &data)
                    .map(Some)
            })
            .collect::<Result<Vec<_>, GpuError>>()?;
        let state = |name: String| gpu.zeros(&name, &[batch * n, h], DType::F32);
        let steps = (0..t)
            .map(|t| {
                Ok(Step {
                    x: gpu.zeros(&format!("cell.x{t}"), &[batch * n, f], DType::F32)?,
                    r: state(format!("cell.r{t}"))?,
                    u: state(format!("cell.u{t}"))?,
                    rh: state(format!("cell.rh{t}"))?,
                    c: state(format!("cell.c{t}"))?,
                    h: state(format!("cell.h{t}"))?,
                })
            })
            .collect::<Result<_, GpuError>>()?;
        let attention = if attends_over_time(config.variant) {
            let width = h;
            let wide = |name: &str| gpu.zeros(name, &[batch, width], DType::F32);
            let per_step = |name: &str| gpu.zeros(name, &[batch, t], DType::F32);
            Some(TimeAttention {
                score_hidden: (0..t)
                    .map(|t| wide(&format!("attn.hidden{t}")))
                    .collect::<Result<_, GpuError>>()?,
                hidden_scratch: wide("attn.hidden scratch")?,
                d_hidden: wide("attn.d hidden")?,
                column: gpu.zeros("attn.column", &[batch], DType::F32)?,
                scores: per_step("attn.e")?,
                weights: per_step("attn.alpha")?,
                d_weights: per_step("attn.d alpha")?,
                context: gpu.zeros("attn.context", &[batch, n * h], DType::F32)?,
                width,
            })
        } else {
            None
        };
        Ok(RecurrentBody {
            supports,
            h0: state("cell.h0".into())?,
            steps,
            pre: state("cell.pre".into())?,
            mixed: state("cell.mixed".into())?,
            attention,
            batch,
            nodes: n,
            features: f,
            hidden: h,
            window: t,
        })
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

    /// Appends `act(Σ_k S_k (x·Wx_k + h·Wh_k) + b)` of gate `g` into `out`.
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
        let terms = self.supports.len();
        for (k, support) in self.supports.iter().enumerate() {
            // With S_k = I the products go straight into the sum.
            let (target, first) = match support {
                Some(_) => (&self.pre, Accumulate::Overwrite),
                None if k == 0 => (&self.mixed, Accumulate::Overwrite),
                None => (&self.mixed, Accumulate::Add),
            };
            let wx = table.param(&weight_name(g, "wx", k, terms));
            let wh = table.param(&weight_name(g, "wh", k, terms));
            steps.run(self.input_product().forward(gpu, x, wx, target, first))?;
            steps.run(
                self.state_product()
                    .forward(gpu, h, wh, target, Accumulate::Add),
            )?;
            if let Some(s) = support {
                let acc = if k == 0 {
                    Accumulate::Overwrite
                } else {
                    Accumulate::Add
                };
                steps.run(
                    self.graph_mix()
                        .forward(gpu, s, &self.pre, &self.mixed, acc),
                )?;
            }
        }
        steps.run(
            self.bias()
                .forward(gpu, table.param(&format!("cell.{g}.bias")), &self.mixed),
        )?;
        steps.run(unary_forward(
            gpu,
            act,
            &self.mixed,
            out,
            Accumulate::Overwrite,
        ))?;
        Ok(())
    }

    /// The products of the attention over time: `h_t·Wa` `[B, N·H]·[N·H, A]`, `·v`
    /// `[B, A]·[A, 1]`, and α_t·h_t per window `[1, 1]·[1, N·H]`.
    fn attention_products(&self, a: &TimeAttention) -> (Matmul, Matmul, Matmul) {
        let nh = self.nodes * self.hidden;
        (
            Matmul::new(self.batch, a.width, nh),
            Matmul::new(self.batch, 1, a.width),
            Matmul::new(1, nh, 1).batched(self.batch),
        )
    }

    fn attention_bias(&self, a: &TimeAttention) -> Bias {
        Bias {
            outer: self.batch,
            channels: a.width,
            inner: 1,
        }
    }

    /// Step t's column of a `[B, T]` tensor.
    fn column(&self, t: usize) -> TimeStep {
        TimeStep {
            rows: self.batch,
            steps: self.window,
            step: t,
        }
    }

    fn time_softmax(&self) -> Softmax {
        Softmax {
            outer: self.batch,
            len: self.window,
            inner: 1,
        }
    }

    /// Appends e_t = v · tanh(h_t·Wa + ba), α = softmax_t(e) and the context Σ_t α_t h_t.
    fn attention_forward(
        &self,
        gpu: &Gpu,
        table: &dyn ParamTable,
        a: &TimeAttention,
        steps: &mut Steps,
    ) -> Result<(), GpuError> {
        let (score_in, score_out, weigh) = self.attention_products(a);
        let first = |t: usize| {
            if t == 0 {
                Accumulate::Overwrite
            } else {
                Accumulate::Add
            }
        };
        for (t, s) in self.steps.iter().enumerate() {
            let hidden = &a.score_hidden[t];
            steps.run(score_in.forward(
                gpu,
                &s.h,
                table.param("attn.W"),
                &a.hidden_scratch,
                Accumulate::Overwrite,
            ))?;
            steps.run(self.attention_bias(a).forward(
                gpu,
                table.param("attn.b"),
                &a.hidden_scratch,
            ))?;
            steps.run(unary_forward(
                gpu,
                Unary::Tanh,
                &a.hidden_scratch,
                hidden,
                Accumulate::Overwrite,
            ))?;
            steps.run(score_out.forward(
                gpu,
                hidden,
                table.param("attn.v"),
                &a.column,
                Accumulate::Overwrite,
            ))?;
            steps.run(self.column(t).backward(gpu, &a.column, &a.scores, first(t)))?;
        }
        steps.run(self.time_softmax().forward(gpu, &a.scores, &a.weights))?;
        for (t, s) in self.steps.iter().enumerate() {
            steps.run(self.column(t).forward(gpu, &a.weights, &a.column))?;
            steps.run(weigh.forward(gpu, &a.column, &s.h, &a.context, first(t)))?;
        }
        Ok(())
    }

    /// Appends ∂ℒ/∂e (into `scores`) from ∂ℒ/∂context: ∂ℒ/∂α_t = h_t · ∂ℒ/∂context, then
    /// the softmax backward.
    fn attention_backward_scores(
        &self,
        gpu: &Gpu,
        a: &TimeAttention,
        d_context: &Tensor,
        steps: &mut Steps,
    ) -> Result<(), GpuError> {
        let (_, _, weigh) = self.attention_products(a);
        for (t, s) in self.steps.iter().enumerate() {
            let acc = if t == 0 {
                Accumulate::Overwrite
            } else {
                Accumulate::Add
            };
            steps.run(weigh.backward_a(gpu, &s.h, d_context, &a.column, Accumulate::Overwrite))?;
            steps.run(self.column(t).backward(gpu, &a.column, &a.d_weights, acc))?;
        }
        steps.run(self.time_softmax().backward(
            gpu,
            &a.weights,
            &a.d_weights,
            &a.scores,
            Accumulate::Overwrite,
        ))?;
        Ok(())
    }

    /// Appends the attention's share of ∂ℒ/∂h_t into `dh` (`dh_acc`: overwrite for the
    /// last step, whose ∂ℒ/∂h comes only from here) and its parameter gradients (`acc`).
    #[allow(clippy::too_many_arguments)]
    fn attention_backward_step(
        &self,
        gpu: &Gpu,
        table: &dyn ParamTable,
        a: &TimeAttention,
        t: usize,
        d_context: &Tensor,
        dh: &Tensor,
        dh_acc: Accumulate,
        acc: Accumulate,
        steps: &mut Steps,
    ) -> Result<(), GpuError> {
        let (score_in, score_out, weigh) = self.attention_products(a);
        let h = &self.steps[t].h;
        // α_t ∂ℒ/∂context.
        steps.run(self.column(t).forward(gpu, &a.weights, &a.column))?;
        steps.run(weigh.backward_b(gpu, &a.column, d_context, dh, dh_acc))?;
        // Through e_t = v · tanh(h_t·Wa + ba).
        steps.run(self.column(t).forward(gpu, &a.scores, &a.column))?;
        let hidden = &a.score_hidden[t];
        steps.run(score_out.backward_b(gpu, hidden, &a.column, table.grad("attn.v"), acc))?;
        steps.run(score_out.backward_a(
            gpu,
            table.param("attn.v"),
            &a.column,
            &a.d_hidden,
            Accumulate::Overwrite,
        ))?;
        steps.run(unary_backward(
            gpu,
            Unary::Tanh,
            hidden,
            &a.d_hidden,
            &a.hidden_scratch,
            Accumulate::Overwrite,
        ))?;
        steps.run(self.attention_bias(a).backward(
            gpu,
            &a.hidden_scratch,
            table.grad("attn.b"),
            acc,
        ))?;
        steps.run(score_in.backward_b(gpu, h, &a.hidden_scratch, table.grad("attn.W"), acc))?;
        steps.run(score_in.backward_a(
            gpu,
            table.param("attn.W"),
            &a.hidden_scratch,
            dh,
            Accumulate::Add,
        ))?;
        Ok(())
    }

    /// Appends the backward of one gate `out = act(Σ_k S_k (x·Wx_k + h·Wh_k) + b)` given
    /// `d_out`: the gate's parameter gradients (`acc`), ∂ℒ/∂h into `dh` and ∂ℒ/∂x into
    /// `dx` (each with its own mode for the first support; later supports add).
    /// `scratch` is (∂ℒ/∂ mixed, ∂ℒ/∂ pre).
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
        (dh, dh_acc): (&Tensor, Accumulate),
        (dx, dx_acc): (&Tensor, Accumulate),
        steps: &mut Steps,
    ) -> Result<(), GpuError> {
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
                .backward(gpu, dz, table.grad(&format!("cell.{g}.bias")), acc),
        )?;
        let (mx, mh) = (self.input_product(), self.state_product());
        let terms = self.supports.len();
        for (k, support) in self.supports.iter().enumerate() {
            // ∂ℒ/∂(x·Wx_k + h·Wh_k) = S_kᵀ dz (dz itself where S_k = I).
            let d_pre = match support {
                Some(s) => {
                    steps.run(self.graph_mix().backward_b(
                        gpu,
                        s,
                        dz,
                        dp,
                        Accumulate::Overwrite,
                    ))?;
                    dp
                }
                None => dz,
            };
            let (wx, wh) = (
                weight_name(g, "wx", k, terms),
                weight_name(g, "wh", k, terms),
            );
            let later = |first: Accumulate| if k == 0 { first } else { Accumulate::Add };
            steps.run(mx.backward_b(gpu, x, d_pre, table.grad(&wx), acc))?;
            steps.run(mx.backward_a(gpu, table.param(&wx), d_pre, dx, later(dx_acc)))?;
            steps.run(mh.backward_b(gpu, h, d_pre, table.grad(&wh), acc))?;
            steps.run(mh.backward_a(gpu, table.param(&wh), d_pre, dh, later(dh_acc)))?;
        }
        Ok(())
    }
}

impl TimeLoop for RecurrentBody {
    /// What the head reads, `[B, N·H]`: the last state h_{T−1}, or with the attention over
    /// time the context Σ_t α_t h_t.
    fn output(&self) -> &Tensor {
        match &self.attention {
            Some(a) => &a.context,
            None => &self.steps[self.window - 1].h,
        }
    }

    /// Appends the time loop from x (`input` `[B, N, F, T]`) to the head's input.
    fn forward(
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
        if let Some(a) = &self.attention {
            self.attention_forward(gpu, table, a, steps)?;
        }
        Ok(())
    }

    /// Appends backpropagation through time from ∂ℒ/∂(head input) (`d_output`; without
    /// the attention it is ∂ℒ/∂h_{T−1} and is overwritten as scratch) to the cell's
    /// parameter gradients and ∂ℒ/∂x (`input_grad`).
    fn backward(
        &self,
        gpu: &Gpu,
        table: &dyn ParamTable,
        d_output: &Tensor,
        input_grad: &Tensor,
        steps: &mut Steps,
    ) -> Result<(), GpuError> {
        let state = |name: &str| gpu.zeros(name, &[self.rows(), self.hidden], DType::F32);
        // ∂ℒ/∂h of the current step and of the one before.
        let dh = match &self.attention {
            Some(a) => {
                self.attention_backward_scores(gpu, a, d_output, steps)?;
                [state("cell.dh")?, state("cell.dh (other)")?]
            }
            None => [d_output.clone(), state("cell.dh (other)")?],
        };
        let (du, dc, dr, drh) = (
            state("cell.du")?,
            state("cell.dc")?,
            state("cell.dr")?,
            state("cell.drh")?,
        );
        let (dz, dp) = (state("cell.dz")?, state("cell.dp")?);
        let dx = gpu.zeros("cell.dx", &[self.rows(), self.features], DType::F32)?;
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
            if let Some(a) = &self.attention {
                self.attention_backward_step(gpu, table, a, t, d_output, cur, acc, acc, steps)?;
            }
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
                (&drh, Accumulate::Overwrite),
                (&dx, Accumulate::Overwrite),
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
                    (prev, Accumulate::Add),
                    (&dx, Accumulate::Add),
                    steps,
                )?;
            }
            steps.run(self.gather(t).backward(gpu, &dx, input_grad, acc))?;
        }
        Ok(())
    }
}
