//! The backward schedule of one block: the forward's call list reversed, from
//! ∂ℒ/∂output into the parameter gradients and ∂ℒ/∂input, each step taking the gradient
//! the later step left and returning what the earlier one needs.

use super::{Block, MaskedStep, ParamTable};
use crate::gpu::{Gpu, GpuError, Tensor};
use crate::model::schedule::{Scratch, Steps};

impl Block {
    /// The backward pass of a training forward: from `d_out` (∂ℒ/∂output) into the
    /// parameter gradients and `d_in` (∂ℒ/∂input, overwritten). Returns the two
    /// dispatches that read the dropout's mask.
    pub fn backward(
        &self,
        gpu: &Gpu,
        p: &dyn ParamTable,
        scratch: &mut Scratch,
        steps: &mut Steps,
        d_out: &Tensor,
        d_in: &Tensor,
    ) -> Result<[MaskedStep; 2], GpuError> {
        // Writes all of d_in; the steps below add to it.
        let (dh, masked) =
            self.residual_layer_norm_backward(gpu, p, scratch, steps, d_out, d_in)?;
        let dg = self.gated_dcc_backward(gpu, p, scratch, steps, &dh)?;
        if self.gat.is_some() {
            self.graph_attention_backward(gpu, p, scratch, steps, &dg, d_in)?;
        } else if let Some(g) = self.graph_conv_backward(gpu, p, scratch, steps, &dg, d_in)? {
            let dxt = self.spatial_attention_backward(gpu, p, scratch, steps, &g.dsp, &g.dm)?;
            self.temporal_attention_backward(gpu, p, scratch, steps, &dxt, d_in)?;
        }
        Ok(masked)
    }
}
