//! Step 2 on the device, the spatial attention (docs/model.md eq. 32–34): S' from X_t,
//! forward and backward. The node mixing (I + S')·X_t is step 3's (Q = Ψ·(I + S')).

use crate::gpu::{Gpu, GpuError, Tensor};
use crate::model::block::wgsl::Block;
use crate::model::schedule::{ParamTable, Scratch, Steps};
use crate::ops::matmul::Epilogue;
use crate::ops::outer::Second;
use crate::ops::Accumulate::{Add, Overwrite};

impl Block {
    /// S' from X_t (the temporal attention's output). Nothing without attention.
    pub(crate) fn spatial_attention_forward(
        &self,
        gpu: &Gpu,
        p: &dyn ParamTable,
        steps: &mut Steps,
    ) -> Result<(), GpuError> {
        let Some(sa) = &self.sat else {
            return Ok(());
        };
        let w = |s: &str| p.param(&self.name(s));
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
        // σ(P + bs), P = lhs·rhsᵀ, in the product's epilogue.
        let scores = Epilogue {
            matrix: Some(w("sat.bs")),
            sigmoid: true,
            ..Epilogue::default()
        };
        steps.run(
            self.mm_sp()
                .forward_with(gpu, &sa.lhs, &sa.rhs, &sa.sig, Overwrite, scores),
        )?;
        steps.run(
            self.mm_vs()
                .forward(gpu, w("sat.Vs"), &sa.sig, &sa.s, Overwrite),
        )?;
        steps.run(self.spatial_softmax().forward(gpu, &sa.s, &sa.sp))?;
        Ok(())
    }

    /// From dS' (`[B, N, N]`, step 3's) into the attention's parameter gradients, and
    /// its terms of dX_t (the projections' rank-1 terms) *added* to `dxt`
    /// (`[B, N, C_in, T]`, which step 3's backward started). Only with attention.
    pub(crate) fn spatial_attention_backward(
        &self,
        gpu: &Gpu,
        p: &dyn ParamTable,
        scratch: &mut Scratch,
        steps: &mut Steps,
        dsp: &Tensor,
        dxt: &Tensor,
    ) -> Result<(), GpuError> {
        let d = self.d;
        // invariant: the caller passes step 3's dS', which exists only with attention.
        let sa = self.sat.as_ref().expect("dS' comes only with attention");
        let w = |s: &str| p.param(&self.name(s));
        let dw = |s: &str| p.grad(&self.name(s));
        let nn = [d.b, d.n, d.n];
        let (dss, dp) = (scratch.get("sat.dS", &nn)?, scratch.get("sat.dP", &nn)?);
        let xt = &sa.xt;
        steps.run(
            self.spatial_softmax()
                .backward(gpu, &sa.sp, dsp, &dss, Overwrite),
        )?;
        let mvs = self.mm_vs();
        steps.run(mvs.backward_a(gpu, &sa.sig, &dss, dw("sat.Vs"), Overwrite))?;
        // dP = (Vsᵀ·dS) ⊙ σ'(·), the sigmoid's backward in the product's epilogue.
        let sigmoid = Epilogue {
            sigmoid_backward: Some(&sa.sig),
            ..Epilogue::default()
        };
        steps.run(mvs.backward_b_with(gpu, w("sat.Vs"), &dss, &dp, Overwrite, sigmoid))?;
        let bs = self.spatial_score_bias();
        steps.run(bs.backward(gpu, &dp, dw("sat.bs"), Overwrite))?;
        let msp = self.mm_sp();
        let (dlhs, drhs) = (
            scratch.get("sat.dlhs", &[d.b, d.n, d.t])?,
            scratch.get("sat.drhs", &[d.b, d.n, d.t])?,
        );
        steps.run(msp.backward_a(gpu, &sa.rhs, &dp, &dlhs, Overwrite))?;
        steps.run(msp.backward_b(gpu, &sa.lhs, &dp, &drhs, Overwrite))?;
        let mw3 = self.mm_w3();
        steps.run(mw3.backward_a(gpu, xt, &drhs, dw("sat.W3"), Overwrite))?;
        let dxw1 = scratch.get("sat.dxw1", &[d.b, d.n, d.ci])?;
        let mw2 = self.mm_w2();
        steps.run(mw2.backward_a(gpu, w("sat.W2"), &dlhs, &dxw1, Overwrite))?;
        steps.run(mw2.backward_b(gpu, &sa.xw1, &dlhs, dw("sat.W2"), Overwrite))?;
        let mw1 = self.mm_w1();
        steps.run(mw1.backward_b(gpu, xt, &dxw1, dw("sat.W1"), Overwrite))?;
        // dX_t += the projections' two rank-1 terms (W3 ⊗ d rhs + d xw1 ⊗ W1) in one pass.
        let pair = self.rank_one_pair(Second::RowsByCols);
        let factors = [w("sat.W3"), &drhs, &dxw1, w("sat.W1")];
        steps.run(pair.apply(gpu, factors, dxt, Add))?;
        Ok(())
    }
}
