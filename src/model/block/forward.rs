//! The forward schedule of one block: steps 1–7 as a call list of the step methods, each
//! in its own file beside its backward.

use super::Pass;
use super::{Block, MaskedStep, ParamTable};
use crate::gpu::{Gpu, GpuError};
use crate::model::schedule::Steps;

impl Block {
    /// The forward pass. For [`Pass::Train`], LayerNorm writes the output through the
    /// dropout (its mask's step is set later through the returned dispatch) and G_g is
    /// kept for the backward pass; otherwise the gate is fused into the gate product and
    /// LayerNorm writes the output as it is.
    pub fn forward(
        &self,
        gpu: &Gpu,
        p: &dyn ParamTable,
        steps: &mut Steps,
        pass: Pass,
    ) -> Result<Option<MaskedStep>, GpuError> {
        self.temporal_attention_forward(gpu, p, steps)?;
        self.spatial_attention_forward(gpu, p, steps)?;
        if self.gat.is_some() {
            self.graph_attention_forward(gpu, p, steps)?;
        } else {
            self.graph_conv_forward(gpu, p, steps)?;
        }
        self.gated_dcc_forward(gpu, p, steps, pass)?;
        self.residual_layer_norm_forward(gpu, p, steps, pass)
    }
}
