//! Step 4 on the device, the gated dilated causal convolution (docs/model.md eq. 30–31;
//! the plain one of `iastgcn-t`), forward and backward: the unfolding, the filter and gate
//! products with their biases in the epilogue, and H; back to dG, Z's ReLU mask applied as
//! the unfolding's backward folds dcol back.

use crate::gpu::{Gpu, GpuError, Tensor};
use crate::model::block::gated_dcc::kernel::{gate_backward_stacked, gate_forward, ReluOutput};
use crate::model::block::wgsl::Block;
use crate::model::schedule::{ParamTable, Pass, Scratch, Steps};
use crate::ops::bias::Bias;
use crate::ops::elementwise::{unary_backward, unary_forward, Unary};
use crate::ops::matmul::Epilogue;
use crate::ops::Accumulate::Overwrite;

impl Block {
    /// H (into `s`, `[B, N, C, to]`) from Z: the unfolding, the filter and gate products
    /// with their biases in the epilogue, and the gate. [`Pass::Train`] keeps G_f and G_g
    /// for the backward; inference keeps no G_g (the gate product applies
    /// tanh(G_f) ⊙ σ(·) itself).
    pub(crate) fn gated_dcc_forward(
        &self,
        gpu: &Gpu,
        p: &dyn ParamTable,
        steps: &mut Steps,
        pass: Pass,
    ) -> Result<(), GpuError> {
        let train = pass == Pass::Train;
        let w = |s: &str| p.param(&self.name(s));
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
        Ok(())
    }

    /// From dH (`[B, N, C, to]`) into the filter's and the gate's parameter gradients, and
    /// dG (returned, `[B, N, C, T]`): dZ masked by Z > 0, step 3's ReLU.
    pub(crate) fn gated_dcc_backward(
        &self,
        gpu: &Gpu,
        p: &dyn ParamTable,
        scratch: &mut Scratch,
        steps: &mut Steps,
        dh: &Tensor,
    ) -> Result<Tensor, GpuError> {
        let d = self.d;
        let w = |s: &str| p.param(&self.name(s));
        let dw = |s: &str| p.grad(&self.name(s));
        let out = [d.b, d.n, d.c, d.to];
        let conv = self.mm_conv();
        let dcol = scratch.get("dcol", &[d.b, d.n, d.c, d.k, d.to])?;
        if let Some(w_fg) = &self.w_fg {
            // Filter and gate stacked: one product each for the weights' gradient and
            // dcol, with twice the rows (K = 2C for dcol).
            let (c, ck) = (d.c, d.c * d.k);
            steps.copy_range((w("tcn.filter.weight"), 0), (w_fg, 0), c * ck);
            steps.copy_range((w("tcn.gate.weight"), 0), (w_fg, c * ck), c * ck);
            let dfg = scratch.get("dG_fg", &[d.b, d.n, 2 * c, d.to])?;
            let block = c * d.to;
            steps.run(gate_backward_stacked(
                gpu, &self.f, &self.gg, dh, &dfg, block,
            ))?;
            let stacked_bias = Bias {
                channels: 2 * c,
                ..self.channel_bias()
            };
            let dbias = scratch.get("dbias_fg", &[2 * c])?;
            steps.run(stacked_bias.backward(gpu, &dfg, &dbias, Overwrite))?;
            steps.copy_range((&dbias, 0), (dw("tcn.filter.bias"), 0), c);
            steps.copy_range((&dbias, c), (dw("tcn.gate.bias"), 0), c);
            let fg = self.mm_conv_fg();
            let dw_fg = scratch.get("dW_fg", &[2 * c, ck])?;
            steps.run(fg.backward_a(gpu, &self.col, &dfg, &dw_fg, Overwrite))?;
            steps.copy_range((&dw_fg, 0), (dw("tcn.filter.weight"), 0), c * ck);
            steps.copy_range((&dw_fg, c * ck), (dw("tcn.gate.weight"), 0), c * ck);
            steps.run(fg.backward_b(gpu, w_fg, &dfg, &dcol, Overwrite))?;
        } else {
            let df = scratch.get("dG_f", &out)?;
            steps.run(unary_backward(
                gpu,
                Unary::Relu,
                &self.f,
                dh,
                &df,
                Overwrite,
            ))?;
            let bias = self.channel_bias();
            steps.run(bias.backward(gpu, &df, dw("tcn.filter.bias"), Overwrite))?;
            let weight = dw("tcn.filter.weight");
            steps.run(conv.backward_a(gpu, &self.col, &df, weight, Overwrite))?;
            steps.run(conv.backward_b(gpu, w("tcn.filter.weight"), &df, &dcol, Overwrite))?;
        }
        // Z = ReLU(G), masked by the unfolding's backward.
        let dg = scratch.get("dG", &[d.b, d.n, d.c, d.t])?;
        let z = ReluOutput(&self.z);
        steps.run(self.unfold().backward_through_relu(gpu, &dcol, z, &dg))?;
        Ok(dg)
    }
}
