//! `st-gat`'s step 3 on the device, its graph attention in place of the graph
//! convolution: Q = Wᵀ·X over channels, α from Q, Z = ReLU(Σ_j α_ij Q_j), forward and
//! backward (from dG, the gradient past Z's ReLU, which step 4's backward applies).

use crate::gpu::{Gpu, GpuError, Tensor};
use crate::model::block::wgsl::Block;
use crate::model::schedule::{ParamTable, Scratch, Steps};
use crate::ops::elementwise::{unary_forward, Unary};
use crate::ops::Accumulate::{Add, Overwrite};

impl Block {
    /// Z from the block input X, on all T steps. Nothing but in `st-gat`.
    pub(crate) fn graph_attention_forward(
        &self,
        gpu: &Gpu,
        p: &dyn ParamTable,
        steps: &mut Steps,
    ) -> Result<(), GpuError> {
        let Some(gat) = &self.gat else {
            return Ok(());
        };
        let w = |s: &str| p.param(&self.name(s));
        let x = &self.input;
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
        Ok(())
    }

    /// From dG (`[B, N, C, T]`) through the attention into dQ, d a_src and d a_dst, then
    /// the channel mix Q = Wᵀ·X: d gat.W, and dX *added* to `d_in` (onto the residual's
    /// contribution). Nothing but in `st-gat`.
    pub(crate) fn graph_attention_backward(
        &self,
        gpu: &Gpu,
        p: &dyn ParamTable,
        scratch: &mut Scratch,
        steps: &mut Steps,
        dg: &Tensor,
        d_in: &Tensor,
    ) -> Result<(), GpuError> {
        let Some(gat) = &self.gat else {
            return Ok(());
        };
        let d = self.d;
        let w = |s: &str| p.param(&self.name(s));
        let dw = |s: &str| p.grad(&self.name(s));
        let x = &self.input;
        let hidden = [d.b, d.n, d.c, d.t];
        let op = self.graph_attention(gat.heads);
        let dq = scratch.get("gat.dQ", &hidden)?;
        let d_score = scratch.get("gat.d score", &[d.b, d.t, gat.heads, d.n, d.n])?;
        let da = scratch.get("gat.da", &[2 * d.c])?;
        let inputs = [
            &gat.q,
            w("gat.a_src"),
            w("gat.a_dst"),
            p.param("graph.basis"),
        ];
        for dispatch in op.backward(gpu, inputs, &gat.alpha, dg, &d_score, &dq, &da, Overwrite)? {
            steps.run(Ok(dispatch))?;
        }
        steps.copy_range((&da, 0), (dw("gat.a_src"), 0), d.c);
        steps.copy_range((&da, d.c), (dw("gat.a_dst"), 0), d.c);
        let mw = self.mm_w();
        steps.run(mw.backward_a(gpu, x, &dq, dw("gat.W"), Overwrite))?;
        steps.run(mw.backward_b(gpu, w("gat.W"), &dq, d_in, Add))?;
        Ok(())
    }
}
