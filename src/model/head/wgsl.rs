//! The head on the device: ŷ = h·Wᵀ + b for a batch, as a product and a bias (the shared
//! ops), and its backward.

use crate::gpu::{Gpu, GpuError, Tensor};
use crate::model::config::ModelConfig;
use crate::model::schedule::{ParamTable, Steps};
use crate::ops::bias::Bias;
use crate::ops::matmul::Matmul;
use crate::ops::Accumulate::Overwrite;

/// The head's launches for `batch` windows of a `width`-wide input.
pub(crate) struct Head {
    product: Matmul,
    bias: Bias,
}

impl Head {
    /// h `[B, width]`: the trimmed last block's last step (N·C), or a recurrent baseline's
    /// last state or context.
    pub(crate) fn new(config: &ModelConfig, batch: usize, width: usize) -> Head {
        let o = config.outputs;
        Head {
            product: Matmul::new(batch, o, width).transpose_b(true),
            bias: Bias {
                outer: batch,
                channels: o,
                inner: 1,
            },
        }
    }

    /// Appends ŷ = h·head.weightᵀ + head.bias, written into `out` `[B, O]`, to `steps`.
    pub(crate) fn forward(
        &self,
        gpu: &Gpu,
        table: &dyn ParamTable,
        h: &Tensor,
        out: &Tensor,
        steps: &mut Steps,
    ) -> Result<(), GpuError> {
        let weight = table.param("head.weight");
        steps.run(self.product.forward(gpu, h, weight, out, Overwrite))?;
        steps.run(self.bias.forward(gpu, table.param("head.bias"), out))?;
        Ok(())
    }

    /// Appends the backward from dŷ `d_out` to `steps`: the bias's and the weight's
    /// gradients and dh, each overwritten.
    pub(crate) fn backward(
        &self,
        gpu: &Gpu,
        table: &dyn ParamTable,
        h: &Tensor,
        d_out: &Tensor,
        dh: &Tensor,
        steps: &mut Steps,
    ) -> Result<(), GpuError> {
        steps.run(
            self.bias
                .backward(gpu, d_out, table.grad("head.bias"), Overwrite),
        )?;
        let d_weight = table.grad("head.weight");
        steps.run(self.product.backward_b(gpu, h, d_out, d_weight, Overwrite))?;
        let weight = table.param("head.weight");
        steps.run(self.product.backward_a(gpu, weight, d_out, dh, Overwrite))?;
        Ok(())
    }
}
