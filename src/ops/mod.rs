//! One module per op family: the dispatch of its WGSL forward/backward kernels next to
//! its f64 CPU reference. Ops see tensors only.

pub mod adam;
pub mod bias;
pub mod dropout;
pub mod elementwise;
pub mod gated_dcc;
pub mod head;
pub mod layer_norm;
pub mod loss;
pub mod matmul;
pub mod outer;
pub mod softmax;

use crate::gpu::Shader;

/// Every op shader, for validation and for the pipeline warm-up.
pub fn shaders() -> [&'static Shader; 12] {
    [
        &adam::SHADER,
        &bias::SHADER,
        &dropout::SHADER,
        &elementwise::SHADER,
        &gated_dcc::SHADER,
        &head::SHADER,
        &layer_norm::SHADER,
        &loss::SHADER,
        &matmul::SHADER,
        &matmul::SUBGROUP_SHADER,
        &outer::SHADER,
        &softmax::SHADER,
    ]
}
