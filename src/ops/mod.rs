//! One module per op family: the dispatch of its WGSL forward/backward kernels next to
//! its f64 CPU reference. Ops see tensors only.

pub mod adam;
pub mod bias;
pub mod dropout;
pub mod elementwise;
pub mod fft;
pub mod gated_dcc;
pub mod graph_attention;
pub mod gru;
pub mod head;
pub mod layer_norm;
pub mod loss;
pub mod lstm;
pub mod matmul;
pub mod outer;
pub mod removal;
pub mod softmax;
pub mod time_step;
pub mod unfold2d;

use crate::gpu::Shader;

/// What a kernel does with the tensor it writes. Backward kernels add, so that a tensor
/// read by several ops receives one gradient contribution per dispatch; the first
/// contribution (or a forward result) overwrites.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Accumulate {
    /// `out = f(…)`: whatever the tensor held is replaced.
    Overwrite,
    /// `out += f(…)`: the result is added to what the tensor holds.
    Add,
}

impl Accumulate {
    /// Both modes, for tests that check each.
    pub const ALL: [Accumulate; 2] = [Accumulate::Overwrite, Accumulate::Add];

    /// The `accumulate` word of a kernel's uniform parameters: 1 to add, 0 to overwrite.
    pub(crate) fn flag(self) -> u32 {
        match self {
            Accumulate::Overwrite => 0,
            Accumulate::Add => 1,
        }
    }
}

/// Every op shader, for validation and for the pipeline warm-up.
pub fn shaders() -> [&'static Shader; 19] {
    [
        &adam::SHADER,
        &bias::SHADER,
        &dropout::SHADER,
        &elementwise::SHADER,
        &fft::SHADER,
        &gated_dcc::SHADER,
        &graph_attention::SHADER,
        &gru::SHADER,
        &head::SHADER,
        &layer_norm::SHADER,
        &loss::SHADER,
        &lstm::SHADER,
        &matmul::SHADER,
        &matmul::SUBGROUP_SHADER,
        &outer::SHADER,
        &removal::SHADER,
        &softmax::SHADER,
        &time_step::SHADER,
        &unfold2d::SHADER,
    ]
}
