//! One module per op family: the dispatch of its WGSL forward/backward kernels next to
//! its f64 CPU reference. Ops see tensors only.

pub mod dropout;
pub mod elementwise;
pub mod layer_norm;
pub mod matmul;
pub mod softmax;

use crate::gpu::Shader;

/// Every op shader, for validation and for the pipeline warm-up.
pub fn shaders() -> [&'static Shader; 5] {
    [
        &dropout::SHADER,
        &elementwise::SHADER,
        &layer_norm::SHADER,
        &matmul::SHADER,
        &softmax::SHADER,
    ]
}
