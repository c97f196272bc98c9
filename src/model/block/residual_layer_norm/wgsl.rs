//! Steps 5–7 on the device, the residual 1×1 convolution, LayerNorm and the dropout
//! (docs/model.md), forward and backward: the residual product accumulates onto H (step
//! 4's output) with its bias and the ReLU in the epilogue, and LayerNorm is whole, affine
//! map included, with the dropout of a training step fused into its kernels (the forward
//! writes the dropped output; the backward reads ∂ℒ/∂output through the same mask).

use crate::gpu::{Gpu, GpuError, Tensor};
use crate::model::block::residual_layer_norm::layer_norm_kernel::LayerNorm;
use crate::model::block::wgsl::{Block, MaskedStep};
use crate::model::schedule::{ParamTable, Pass, Scratch, Steps};
use crate::ops::matmul::Epilogue;
use crate::ops::Accumulate::{Add, Overwrite};

impl Block {
    /// A = ReLU(H + R + res.bias) in place of H (`s`), then the block output
    /// LayerNorm(A), through the dropout for [`Pass::Train`] (whose LayerNorm dispatch is
    /// returned, for its mask to follow the training step).
    pub(crate) fn residual_layer_norm_forward(
        &self,
        gpu: &Gpu,
        p: &dyn ParamTable,
        steps: &mut Steps,
        pass: Pass,
    ) -> Result<Option<MaskedStep>, GpuError> {
        let w = |s: &str| p.param(&self.name(s));
        let x = &self.input;
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
        let ln = match pass {
            Pass::Train => self.layer_norm_dropout(),
            Pass::Inference => self.layer_norm(),
        };
        let index = steps.run(ln.forward(
            gpu,
            &self.s,
            w("ln.gamma"),
            w("ln.beta"),
            &self.output,
            &self.mean,
            &self.rstd,
        ))?;
        Ok((pass == Pass::Train).then_some(MaskedStep {
            layer_norm: ln,
            index,
        }))
    }

    /// From ∂ℒ/∂output (`d_out`, `[B, N, C, to]`, read through the dropout's mask) into
    /// dγ, dβ, d res.weight and d res.bias; dA masked by A's ReLU (returned: it is dH,
    /// and dR) and dX = res.weightᵀ·dA, which *overwrites* `d_in` (all of it; zero off
    /// the last step in a trimmed block) for the later steps' backward to add to. Also
    /// returns the two LayerNorm dispatches that read the mask.
    pub(crate) fn residual_layer_norm_backward(
        &self,
        gpu: &Gpu,
        p: &dyn ParamTable,
        scratch: &mut Scratch,
        steps: &mut Steps,
        d_out: &Tensor,
        d_in: &Tensor,
    ) -> Result<(Tensor, [MaskedStep; 2]), GpuError> {
        let d = self.d;
        let w = |s: &str| p.param(&self.name(s));
        let dw = |s: &str| p.grad(&self.name(s));
        let x = &self.input;
        // LayerNorm and the ReLU before it (its input was the ReLU's output; the mask is
        // applied by the LayerNorm backward), from the dropped output's gradient.
        let ln = self.layer_norm_dropout();
        let ln_relu = LayerNorm {
            relu_input: true,
            ..ln
        };
        let ds = scratch.get("dS", &[d.b, d.n, d.c, d.to])?;
        let input = steps.run(ln_relu.backward_input(
            gpu,
            &self.s,
            w("ln.gamma"),
            d_out,
            &self.mean,
            &self.rstd,
            &ds,
            Overwrite,
        ))?;
        let params = steps.run(ln.backward_params(
            gpu,
            &self.s,
            d_out,
            &self.mean,
            &self.rstd,
            dw("ln.gamma"),
            dw("ln.beta"),
            Overwrite,
        ))?;
        let masked = [
            MaskedStep {
                layer_norm: ln_relu,
                index: input,
            },
            MaskedStep {
                layer_norm: ln,
                index: params,
            },
        ];
        // Residual: ∂/∂H = ∂/∂R = dS.
        let bias = self.channel_bias();
        let res = self.mm_res();
        steps.run(bias.backward(gpu, &ds, dw("res.bias"), Overwrite))?;
        match &self.x_last {
            Some(x_last) => {
                // Only the last step of the input reached the residual: its gradient
                // there, zero elsewhere (this writes all of d_in).
                let dx_last = scratch.get("dx_last", &[d.b, d.n, d.ci])?;
                steps.run(res.backward_a(gpu, x_last, &ds, dw("res.weight"), Overwrite))?;
                steps.run(res.backward_b(gpu, w("res.weight"), &ds, &dx_last, Overwrite))?;
                steps.run(self.input_last_step().backward(gpu, &dx_last, d_in))?;
            }
            None => {
                steps.run(res.backward_a(gpu, x, &ds, dw("res.weight"), Overwrite))?;
                steps.run(res.backward_b(gpu, w("res.weight"), &ds, d_in, Overwrite))?;
            }
        }
        Ok((ds, masked))
    }
}
