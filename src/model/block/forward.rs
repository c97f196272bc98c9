//! The forward schedule of one block: steps 1–7 as device ops, for training or inference.

use super::Pass;
use super::{Block, ParamTable};
use crate::gpu::{Gpu, GpuError};
use crate::model::schedule::Steps;
use crate::ops::elementwise::{unary_forward, Unary};
use crate::ops::gated_dcc::gate_forward;
use crate::ops::matmul::Epilogue;
use crate::ops::Accumulate::{Add, Overwrite};

impl Block {
    /// The forward pass. For [`Pass::Train`], dropout (whose step is set later through the
    /// returned slot) writes the output and G_g and Y are kept for the backward pass;
    /// otherwise the gate is fused into the gate product and LayerNorm writes the output.
    pub fn forward(
        &self,
        gpu: &Gpu,
        p: &dyn ParamTable,
        steps: &mut Steps,
        pass: Pass,
    ) -> Result<Option<usize>, GpuError> {
        let train = pass == Pass::Train;
        let w = |s: &str| p.param(&self.name(s));
        let x = &self.input;
        let attention = match (&self.tat, &self.sat) {
            (Some(ta), Some(sa)) => {
                // 1. Temporal attention.
                steps.run(
                    self.mm_u1()
                        .forward(gpu, w("tat.U1"), x, &ta.xu1, Overwrite),
                )?;
                steps.run(
                    self.mm_u2()
                        .forward(gpu, &ta.xu1, w("tat.U2"), &ta.lhs, Overwrite),
                )?;
                steps.run(
                    self.mm_u3()
                        .forward(gpu, w("tat.U3"), x, &ta.rhs, Overwrite),
                )?;
                steps.run(
                    self.mm_tp()
                        .forward(gpu, &ta.lhs, &ta.rhs, &ta.p, Overwrite),
                )?;
                let be = self.temporal_score_bias();
                steps.run(be.forward(gpu, w("tat.be"), &ta.p))?;
                steps.run(unary_forward(
                    gpu,
                    Unary::Sigmoid,
                    &ta.p,
                    &ta.sig,
                    Overwrite,
                ))?;
                steps.run(
                    self.mm_ve()
                        .forward(gpu, w("tat.Ve"), &ta.sig, &ta.e, Overwrite),
                )?;
                steps.run(self.temporal_softmax().forward(gpu, &ta.e, &ta.ep))?;
                steps.run(self.mm_xt().forward(gpu, x, &ta.ep, &sa.xt, Overwrite))?;
                // 2. Spatial attention.
                let xt = &sa.xt;
                steps.run(
                    self.mm_w1()
                        .forward(gpu, xt, w("sat.W1"), &sa.xw1, Overwrite),
                )?;
                steps.run(
                    self.mm_w2()
                        .forward(gpu, &sa.xw1, w("sat.W2"), &sa.lhs, Overwrite),
                )?;
                steps.run(
                    self.mm_w3()
                        .forward(gpu, w("sat.W3"), xt, &sa.rhs, Overwrite),
                )?;
                steps.run(
                    self.mm_sp()
                        .forward(gpu, &sa.lhs, &sa.rhs, &sa.p, Overwrite),
                )?;
                let bs = self.spatial_score_bias();
                steps.run(bs.forward(gpu, w("sat.bs"), &sa.p))?;
                steps.run(unary_forward(
                    gpu,
                    Unary::Sigmoid,
                    &sa.p,
                    &sa.sig,
                    Overwrite,
                ))?;
                steps.run(
                    self.mm_vs()
                        .forward(gpu, w("sat.Vs"), &sa.sig, &sa.s, Overwrite),
                )?;
                steps.run(self.spatial_softmax().forward(gpu, &sa.s, &sa.sp))?;
                Some(sa)
            }
            _ => None,
        };
        if let Some(gat) = &self.gat {
            // 3. st-gat: Q = Wᵀ·X over channels, α from Q, Z = ReLU(Σ_j α_ij Q_j).
            let op = self.graph_attention(gat.heads);
            steps.run(self.mm_w().forward(gpu, w("gat.W"), x, &gat.q, Overwrite))?;
            steps.run(op.attention_weights(
                gpu,
                &gat.q,
                w("gat.a_src"),
                w("gat.a_dst"),
                p.param("graph.basis"),
                &gat.alpha,
            ))?;
            steps.run(op.aggregate(gpu, &gat.q, &gat.alpha, &gat.g, Overwrite))?;
            steps.run(unary_forward(gpu, Unary::Relu, &gat.g, &self.z, Overwrite))?;
        } else {
            self.graph_conv_forward(gpu, p, attention, steps)?;
        }
        // 4. Gated dilated causal convolution (or the plain one of iastgcn-t).
        steps.run(self.unfold().forward(gpu, &self.z, &self.col))?;
        // The channel biases are added by the products themselves.
        let conv = self.mm_conv();
        let (col, f) = (&self.col, &self.f);
        let bias = |name: &str| Epilogue {
            bias: Some(w(name)),
            relu: false,
            ..Epilogue::default()
        };
        let filter = bias("tcn.filter.bias");
        steps.run(conv.forward_with(gpu, w("tcn.filter.weight"), col, f, Overwrite, filter))?;
        if self.gated && !train {
            // Inference keeps no G_g: the gate product applies tanh(G_f) ⊙ σ(·) itself.
            let gated = Epilogue {
                gate: Some(f),
                ..bias("tcn.gate.bias")
            };
            let gate_weight = w("tcn.gate.weight");
            steps.run(conv.forward_with(gpu, gate_weight, col, &self.s, Overwrite, gated))?;
        } else if self.gated {
            let (gg, gate) = (&self.gg, bias("tcn.gate.bias"));
            steps.run(conv.forward_with(gpu, w("tcn.gate.weight"), col, gg, Overwrite, gate))?;
            steps.run(gate_forward(gpu, f, gg, &self.s))?;
        } else {
            steps.run(unary_forward(gpu, Unary::Relu, f, &self.s, Overwrite))?;
        }
        // 5–6. Residual 1×1 convolution (+ bias) accumulated onto H, with the ReLU in the
        // product's epilogue; then LayerNorm.
        let residual = Epilogue {
            bias: Some(w("res.bias")),
            relu: true,
            ..Epilogue::default()
        };
        let x_res = match &self.x_last {
            Some(x_last) => {
                steps.run(self.input_last_step().forward(gpu, x, x_last))?;
                x_last
            }
            None => x,
        };
        steps.run(self.mm_res().forward_with(
            gpu,
            w("res.weight"),
            x_res,
            &self.s,
            Add,
            residual,
        ))?;
        // Inference has no dropout: LayerNorm writes the block output itself.
        let y = if train { &self.y } else { &self.output };
        steps.run(self.layer_norm().forward(
            gpu,
            &self.s,
            w("ln.gamma"),
            w("ln.beta"),
            y,
            &self.mean,
            &self.rstd,
        ))?;
        // 7. Dropout.
        if train {
            Ok(Some(steps.run(self.dropout.apply(
                gpu,
                0,
                &self.y,
                &self.output,
                Overwrite,
            ))?))
        } else {
            Ok(None)
        }
    }

    /// Step 3: the graph wavelet (or Chebyshev) convolution of X_s = X_t + S'·X_t (eq. 28–29
    /// after 32–34): M = Ψ·X_s = Q·X_t with Q = Ψ + Ψ·S', then Z = ReLU(Wᵀ·M).
    fn graph_conv_forward(
        &self,
        gpu: &Gpu,
        p: &dyn ParamTable,
        attention: Option<&super::Spatial>,
        steps: &mut Steps,
    ) -> Result<(), GpuError> {
        let w = |s: &str| p.param(&self.name(s));
        let x = &self.input;
        steps.run(self.mm_psi().forward(
            gpu,
            w("gwc.theta"),
            p.param("graph.basis"),
            &self.psi,
            Overwrite,
        ))?;
        match attention {
            Some(sa) => {
                let plus_psi = Epilogue {
                    matrix: Some(&self.psi),
                    ..Epilogue::default()
                };
                let mq = self.mm_q();
                steps.run(mq.forward_with(gpu, &self.psi, &sa.sp, &sa.q, Overwrite, plus_psi))?;
                steps.run(self.mm_qx().forward(gpu, &sa.q, &sa.xt, &self.m, Overwrite))?;
            }
            None => {
                steps.run(self.mm_mix().forward(gpu, &self.psi, x, &self.m, Overwrite))?;
            }
        }
        let relu = Epilogue {
            bias: None,
            relu: true,
            ..Epilogue::default()
        };
        let mw = self.mm_w();
        steps.run(mw.forward_with(gpu, w("gwc.W"), &self.m, &self.z, Overwrite, relu))?;
        Ok(())
    }
}
