//! Step 3 on the device, the graph wavelet (or Chebyshev) convolution (docs/model.md
//! eq. 28–29 after 32–34): Ψ, Q = Ψ·(I + S'), M = Q·X_t (M = Ψ·X without attention) and
//! Z = ReLU(Wᵀ·M), forward and backward (from dG, the gradient past Z's ReLU, which step
//! 4's backward applies).

use crate::gpu::{Gpu, GpuError, Tensor};
use crate::model::block::wgsl::Block;
use crate::model::schedule::{ParamTable, Scratch, Steps};
use crate::ops::matmul::Epilogue;
use crate::ops::Accumulate::{Add, Overwrite};

/// What the graph convolution's backward leaves for the attentions'.
pub(crate) struct AttentionGrads {
    /// dX_t's term of M = Q·X_t, Qᵀ·dM `[B, N, C_in, T]`; the spatial attention's
    /// backward adds its own terms.
    pub(crate) dxt: Tensor,
    /// dS' `[B, N, N]`.
    pub(crate) dsp: Tensor,
}

impl Block {
    /// Z = ReLU(Wᵀ·M) from X_t and S' (with attention) or X, on all T steps.
    pub(crate) fn graph_conv_forward(
        &self,
        gpu: &Gpu,
        p: &dyn ParamTable,
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
        match &self.sat {
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

    /// From dG (`[B, N, C, T]`, the gradient past Z's ReLU) into d gwc.W and d gwc.theta.
    /// Without attention dX = Ψᵀ·dM is *added* to `d_in` and nothing is returned; with
    /// attention, dS' and dX_t's term Qᵀ·dM are returned for the attentions' backward.
    pub(crate) fn graph_conv_backward(
        &self,
        gpu: &Gpu,
        p: &dyn ParamTable,
        scratch: &mut Scratch,
        steps: &mut Steps,
        dg: &Tensor,
        d_in: &Tensor,
    ) -> Result<Option<AttentionGrads>, GpuError> {
        let d = self.d;
        let w = |s: &str| p.param(&self.name(s));
        let dw = |s: &str| p.grad(&self.name(s));
        let x = &self.input;
        let (mw, mix, mpsi) = (self.mm_w(), self.mm_mix(), self.mm_psi());
        let dm = scratch.get("dM", &[d.b, d.n, d.ci, d.t])?;
        steps.run(mw.backward_a(gpu, &self.m, dg, dw("gwc.W"), Overwrite))?;
        steps.run(mw.backward_b(gpu, w("gwc.W"), dg, &dm, Overwrite))?;
        let dpsi = scratch.get("dPsi", &[d.n, d.n])?;
        let basis = p.param("graph.basis");
        let Some(sa) = &self.sat else {
            // M = Ψ·X: dΨ, then dX accumulated onto the residual's contribution.
            steps.run(mix.backward_a(gpu, x, &dm, &dpsi, Overwrite))?;
            steps.run(mpsi.backward_a(gpu, basis, &dpsi, dw("gwc.theta"), Overwrite))?;
            steps.run(mix.backward_b(gpu, &self.psi, &dm, d_in, Add))?;
            return Ok(None);
        };
        // M = Q·X_t, Q = Ψ + Ψ·S': dQ, dΨ = Σ_b dQ·(I + S')ᵀ, dS' = Ψᵀ·dQ, dX_t = Qᵀ·dM.
        let nn = [d.b, d.n, d.n];
        let (dq, dsp) = (scratch.get("gwc.dQ", &nn)?, scratch.get("sat.dS'", &nn)?);
        let (mq, mqx) = (self.mm_q(), self.mm_qx());
        steps.run(mqx.backward_a(gpu, &sa.xt, &dm, &dq, Overwrite))?;
        steps.run(mq.backward_a(gpu, &sa.sp, &dq, &dpsi, Overwrite))?;
        steps.run(self.batch_sum_nn().backward(gpu, &dq, &dpsi, Add))?;
        steps.run(mpsi.backward_a(gpu, basis, &dpsi, dw("gwc.theta"), Overwrite))?;
        steps.run(mq.backward_b(gpu, &self.psi, &dq, &dsp, Overwrite))?;
        let dxt = scratch.get("dX_t", &[d.b, d.n, d.ci, d.t])?;
        steps.run(mqx.backward_b(gpu, &sa.q, &dm, &dxt, Overwrite))?;
        Ok(Some(AttentionGrads { dxt, dsp }))
    }
}
