//! Step 1 on the device, the temporal attention (docs/model.md eq. 35–37): E' and
//! X_t = X·(E' + I), forward and backward.

use crate::gpu::{Gpu, GpuError, Tensor};
use crate::model::block::wgsl::Block;
use crate::model::schedule::{ParamTable, Scratch, Steps};
use crate::ops::matmul::Epilogue;
use crate::ops::outer::Second;
use crate::ops::Accumulate::{Add, Overwrite};

impl Block {
    /// E' from the block input X, then X_t = X·(E' + I) (into the spatial attention's
    /// `xt`). Nothing without attention.
    pub(crate) fn temporal_attention_forward(
        &self,
        gpu: &Gpu,
        p: &dyn ParamTable,
        steps: &mut Steps,
    ) -> Result<(), GpuError> {
        let (Some(ta), Some(sa)) = (&self.tat, &self.sat) else {
            return Ok(());
        };
        let w = |s: &str| p.param(&self.name(s));
        let x = &self.input;
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
        // σ(P + be), P = lhs·rhs, in the product's epilogue.
        let scores = Epilogue {
            matrix: Some(w("tat.be")),
            sigmoid: true,
            ..Epilogue::default()
        };
        steps.run(
            self.mm_tp()
                .forward_with(gpu, &ta.lhs, &ta.rhs, &ta.sig, Overwrite, scores),
        )?;
        steps.run(
            self.mm_ve()
                .forward(gpu, w("tat.Ve"), &ta.sig, &ta.e, Overwrite),
        )?;
        steps.run(self.temporal_softmax().forward(gpu, &ta.e, &ta.ep))?;
        steps.run(self.mm_xt().forward(gpu, x, &ta.ep, &sa.xt, Overwrite))?;
        Ok(())
    }

    /// From dX_t (`[B, N, C_in, T]`) into the attention's parameter gradients, and
    /// dX = dX_t·(E' + I)ᵀ + the projections' rank-1 terms, *added* to `d_in` (which the
    /// residual's backward wrote first). Nothing without attention.
    pub(crate) fn temporal_attention_backward(
        &self,
        gpu: &Gpu,
        p: &dyn ParamTable,
        scratch: &mut Scratch,
        steps: &mut Steps,
        dxt: &Tensor,
        d_in: &Tensor,
    ) -> Result<(), GpuError> {
        let Some(ta) = &self.tat else {
            return Ok(());
        };
        let d = self.d;
        let w = |s: &str| p.param(&self.name(s));
        let dw = |s: &str| p.grad(&self.name(s));
        let x = &self.input;
        // X_t = X·(E' + I), so dX += dX_t·(E' + I)ᵀ.
        let tt = [d.b, d.t, d.t];
        let (dep, de, dp) = (
            scratch.get("tat.dE'", &tt)?,
            scratch.get("tat.dE", &tt)?,
            scratch.get("tat.dP", &tt)?,
        );
        let mxt = self.mm_xt();
        steps.run(mxt.backward_b(gpu, x, dxt, &dep, Overwrite))?;
        steps.run(mxt.backward_a(gpu, &ta.ep, dxt, d_in, Add))?;
        steps.run(
            self.temporal_softmax()
                .backward(gpu, &ta.ep, &dep, &de, Overwrite),
        )?;
        let mve = self.mm_ve();
        steps.run(mve.backward_a(gpu, &ta.sig, &de, dw("tat.Ve"), Overwrite))?;
        // dP = (Veᵀ·dE) ⊙ σ'(·), the sigmoid's backward in the product's epilogue.
        let sigmoid = Epilogue {
            sigmoid_backward: Some(&ta.sig),
            ..Epilogue::default()
        };
        steps.run(mve.backward_b_with(gpu, w("tat.Ve"), &de, &dp, Overwrite, sigmoid))?;
        let be = self.temporal_score_bias();
        steps.run(be.backward(gpu, &dp, dw("tat.be"), Overwrite))?;
        let mtp = self.mm_tp();
        let (dlhs, drhs) = (
            scratch.get("tat.dlhs", &[d.b, d.t, d.n])?,
            scratch.get("tat.drhs", &[d.b, d.n, d.t])?,
        );
        steps.run(mtp.backward_a(gpu, &ta.rhs, &dp, &dlhs, Overwrite))?;
        steps.run(mtp.backward_b(gpu, &ta.lhs, &dp, &drhs, Overwrite))?;
        let mu3 = self.mm_u3();
        steps.run(mu3.backward_a(gpu, x, &drhs, dw("tat.U3"), Overwrite))?;
        let dxu1 = scratch.get("tat.dxu1", &[d.b, d.ci, d.t])?;
        let mu2 = self.mm_u2();
        steps.run(mu2.backward_a(gpu, w("tat.U2"), &dlhs, &dxu1, Overwrite))?;
        steps.run(mu2.backward_b(gpu, &ta.xu1, &dlhs, dw("tat.U2"), Overwrite))?;
        let mu1 = self.mm_u1();
        steps.run(mu1.backward_a(gpu, x, &dxu1, dw("tat.U1"), Overwrite))?;
        // dX += U3 ⊗ d rhs + U1 ⊗ d xu1, the projections' two rank-1 terms in one pass.
        let pair = self.rank_one_pair(Second::NodeByMatrix { nodes: self.d.n });
        let factors = [w("tat.U3"), &drhs, w("tat.U1"), &dxu1];
        steps.run(pair.apply(gpu, factors, d_in, Add))?;
        Ok(())
    }
}
