//! Step 7, dropout, forward and backward: the same mask both ways, its training step set
//! later through the dispatch's index ([`Dropout::set_step`](crate::ops::dropout::Dropout::set_step)).
//! The native path fuses it with LayerNorm's affine map (`layer_norm_dropout`).

use super::Block;
use crate::gpu::{Gpu, GpuError, Tensor};
use crate::model::schedule::{Scratch, Steps};
use crate::ops::Accumulate::Overwrite;

impl Block {
    /// The block output from Y; returns the dispatch's index.
    pub(crate) fn dropout_forward(&self, gpu: &Gpu, steps: &mut Steps) -> Result<usize, GpuError> {
        steps.run(self.dropout.apply(gpu, 0, &self.y, &self.output, Overwrite))
    }

    /// dY (returned, `[B, N, C, to]`) from ∂ℒ/∂output, and the dispatch's index.
    pub(crate) fn dropout_backward(
        &self,
        gpu: &Gpu,
        scratch: &mut Scratch,
        steps: &mut Steps,
        d_out: &Tensor,
    ) -> Result<(Tensor, usize), GpuError> {
        let d = self.d;
        let dy = scratch.get("dY", &[d.b, d.n, d.c, d.to])?;
        let slot = steps.run(self.dropout.apply(gpu, 0, d_out, &dy, Overwrite))?;
        Ok((dy, slot))
    }
}
