//! The backward schedule of one block: steps 7–1 in reverse, from ∂ℒ/∂output into the
//! parameter gradients and ∂ℒ/∂input.

use super::{Block, ParamTable};
use crate::gpu::{Gpu, GpuError, Tensor};
use crate::model::schedule::{Scratch, Steps};
use crate::ops::bias::Bias;
use crate::ops::elementwise::{unary_backward, Unary};
use crate::ops::gated_dcc::{gate_backward_stacked, ReluOutput};
use crate::ops::layer_norm::LayerNorm;
use crate::ops::outer::Second;
use crate::ops::Accumulate::{Add, Overwrite};

impl Block {
    /// The backward pass of a training forward: from `d_out` (∂ℒ/∂output) into the
    /// parameter gradients and `d_in` (∂ℒ/∂input, overwritten). Returns the index of
    /// the dropout dispatch.
    pub fn backward(
        &self,
        gpu: &Gpu,
        p: &dyn ParamTable,
        scratch: &mut Scratch,
        steps: &mut Steps,
        d_out: &Tensor,
        d_in: &Tensor,
    ) -> Result<usize, GpuError> {
        let d = self.d;
        let w = |s: &str| p.param(&self.name(s));
        let dw = |s: &str| p.grad(&self.name(s));
        let x = &self.input;
        let hidden = [d.b, d.n, d.c, d.t];
        let out = [d.b, d.n, d.c, d.to];
        let acts = [d.b, d.n, d.ci, d.t];
        // 7. Dropout: the same mask as the forward pass.
        let dy = scratch.get("dY", &out)?;
        let slot = steps.run(self.dropout.apply(gpu, 0, d_out, &dy, Overwrite))?;
        // 6. LayerNorm and the ReLU before it (its input was the ReLU's output; the mask
        // is applied by the LayerNorm backward).
        let ln = LayerNorm {
            relu_input: true,
            ..self.layer_norm()
        };
        let ds = scratch.get("dS", &out)?;
        steps.run(ln.backward_input(
            gpu,
            &self.s,
            w("ln.gamma"),
            &dy,
            &self.mean,
            &self.rstd,
            &ds,
            Overwrite,
        ))?;
        steps.run(ln.backward_params(
            gpu,
            &self.s,
            &dy,
            &self.mean,
            &self.rstd,
            dw("ln.gamma"),
            dw("ln.beta"),
            Overwrite,
        ))?;
        // 5. Residual: ∂/∂H = ∂/∂R = dS.
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
        // 4. Gate and convolutions.
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
                gpu, &self.f, &self.gg, &ds, &dfg, block,
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
                &ds,
                &df,
                Overwrite,
            ))?;
            steps.run(bias.backward(gpu, &df, dw("tcn.filter.bias"), Overwrite))?;
            let weight = dw("tcn.filter.weight");
            steps.run(conv.backward_a(gpu, &self.col, &df, weight, Overwrite))?;
            steps.run(conv.backward_b(gpu, w("tcn.filter.weight"), &df, &dcol, Overwrite))?;
        }
        // 3. Graph convolution: Z = ReLU(G), masked by the unfolding's backward.
        let dg = scratch.get("dG", &hidden)?;
        let z = ReluOutput(&self.z);
        steps.run(self.unfold().backward_through_relu(gpu, &dcol, z, &dg))?;
        if let Some(gat) = &self.gat {
            // st-gat: through the graph attention into dQ, d a_src and d a_dst, then the
            // channel mix Q = Wᵀ·X (dX accumulated onto the residual's contribution).
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
            for dispatch in
                op.backward(gpu, inputs, &gat.alpha, &dg, &d_score, &dq, &da, Overwrite)?
            {
                steps.run(Ok(dispatch))?;
            }
            steps.copy_range((&da, 0), (dw("gat.a_src"), 0), d.c);
            steps.copy_range((&da, d.c), (dw("gat.a_dst"), 0), d.c);
            let mw = self.mm_w();
            steps.run(mw.backward_a(gpu, x, &dq, dw("gat.W"), Overwrite))?;
            steps.run(mw.backward_b(gpu, w("gat.W"), &dq, d_in, Add))?;
            return Ok(slot);
        }
        let (mw, mix, mpsi) = (self.mm_w(), self.mm_mix(), self.mm_psi());
        let dm = scratch.get("dM", &acts)?;
        steps.run(mw.backward_a(gpu, &self.m, &dg, dw("gwc.W"), Overwrite))?;
        steps.run(mw.backward_b(gpu, w("gwc.W"), &dg, &dm, Overwrite))?;
        let dpsi = scratch.get("dPsi", &[d.n, d.n])?;
        let basis = p.param("graph.basis");
        let Some((ta, sa)) = self.tat.as_ref().zip(self.sat.as_ref()) else {
            // M = Ψ·X: dΨ, then dX accumulated onto the residual's contribution.
            steps.run(mix.backward_a(gpu, x, &dm, &dpsi, Overwrite))?;
            steps.run(mpsi.backward_a(gpu, basis, &dpsi, dw("gwc.theta"), Overwrite))?;
            steps.run(mix.backward_b(gpu, &self.psi, &dm, d_in, Add))?;
            return Ok(slot);
        };
        // M = Q·X_t, Q = Ψ + Ψ·S': dQ, dΨ = Σ_b dQ·(I + S')ᵀ, dS' = Ψᵀ·dQ (dX_t = Qᵀ·dM + the
        // attention's terms, at the end).
        let nn = [d.b, d.n, d.n];
        let (dq, dsp, dss, dsig, dp) = (
            scratch.get("gwc.dQ", &nn)?,
            scratch.get("sat.dS'", &nn)?,
            scratch.get("sat.dS", &nn)?,
            scratch.get("sat.dsig", &nn)?,
            scratch.get("sat.dP", &nn)?,
        );
        let dxt = scratch.get("dX_t", &acts)?;
        let xt = &sa.xt;
        let (mq, mqx) = (self.mm_q(), self.mm_qx());
        steps.run(mqx.backward_a(gpu, xt, &dm, &dq, Overwrite))?;
        steps.run(mq.backward_a(gpu, &sa.sp, &dq, &dpsi, Overwrite))?;
        steps.run(self.batch_sum_nn().backward(gpu, &dq, &dpsi, Add))?;
        steps.run(mpsi.backward_a(gpu, basis, &dpsi, dw("gwc.theta"), Overwrite))?;
        steps.run(mq.backward_b(gpu, &self.psi, &dq, &dsp, Overwrite))?;
        // 2. Spatial attention.
        steps.run(
            self.spatial_softmax()
                .backward(gpu, &sa.sp, &dsp, &dss, Overwrite),
        )?;
        let mvs = self.mm_vs();
        steps.run(mvs.backward_a(gpu, &sa.sig, &dss, dw("sat.Vs"), Overwrite))?;
        steps.run(mvs.backward_b(gpu, w("sat.Vs"), &dss, &dsig, Overwrite))?;
        steps.run(unary_backward(
            gpu,
            Unary::Sigmoid,
            &sa.sig,
            &dsig,
            &dp,
            Overwrite,
        ))?;
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
        // dX_t: the projections' two rank-1 terms (W3 ⊗ d rhs + d xw1 ⊗ W1) in one pass, then
        // Qᵀ·dM accumulated onto them.
        let pair = self.rank_one_pair(Second::RowsByCols);
        let factors = [w("sat.W3"), &drhs, &dxw1, w("sat.W1")];
        steps.run(pair.apply(gpu, factors, &dxt, Overwrite))?;
        steps.run(mqx.backward_b(gpu, &sa.q, &dm, &dxt, Add))?;
        // 1. Temporal attention: X_t = X·(E' + I), so dX += dX_t·(E' + I)ᵀ.
        let tt = [d.b, d.t, d.t];
        let (dep, de, dsig, dp) = (
            scratch.get("tat.dE'", &tt)?,
            scratch.get("tat.dE", &tt)?,
            scratch.get("tat.dsig", &tt)?,
            scratch.get("tat.dP", &tt)?,
        );
        let mxt = self.mm_xt();
        steps.run(mxt.backward_b(gpu, x, &dxt, &dep, Overwrite))?;
        steps.run(mxt.backward_a(gpu, &ta.ep, &dxt, d_in, Add))?;
        steps.run(
            self.temporal_softmax()
                .backward(gpu, &ta.ep, &dep, &de, Overwrite),
        )?;
        let mve = self.mm_ve();
        steps.run(mve.backward_a(gpu, &ta.sig, &de, dw("tat.Ve"), Overwrite))?;
        steps.run(mve.backward_b(gpu, w("tat.Ve"), &de, &dsig, Overwrite))?;
        steps.run(unary_backward(
            gpu,
            Unary::Sigmoid,
            &ta.sig,
            &dsig,
            &dp,
            Overwrite,
        ))?;
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
        Ok(slot)
    }
}
