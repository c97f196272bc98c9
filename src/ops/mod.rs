//! One module per op family: the dispatch of its WGSL forward/backward kernels next to
//! its f64 CPU reference. Ops see tensors only.

pub mod adam;
pub mod bias;
pub mod elementwise;
pub mod fft;
pub mod gru;
pub mod head;
pub mod loss;
pub mod lstm;
pub mod matmul;
pub mod outer;
pub mod removal;
pub mod softmax;
pub mod time_step;
pub mod unfold2d;

use crate::gpu::{Shader, Uniform, UniformLayout};

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

/// Terms of a per-channel sum that one workgroup takes at least when the sum is split
/// along the outer axis ([`outer_slices`]).
const SLICE_TERMS: usize = 8192;

/// How a per-channel sum over `outer · inner` terms (a bias's or a LayerNorm's parameter
/// gradient) is split along the outer axis, one workgroup per channel and slice, each
/// taking at least [`SLICE_TERMS`] terms: the number of slices and the outer rows per
/// slice (1 slice of all rows when the sum is short). A GPU has far more workgroups to
/// fill than a layer has channels.
pub(crate) fn outer_slices(outer: usize, inner: usize) -> (usize, usize) {
    let wanted = (outer * inner / SLICE_TERMS).clamp(1, outer.max(1));
    let per = outer.div_ceil(wanted).max(1);
    (outer.div_ceil(per).max(1), per)
}

/// Every shared op's shader, for validation (the steps' own kernels: `model::block::shaders`).
pub fn shaders() -> [&'static Shader; 15] {
    [
        &adam::SHADER,
        &bias::SHADER,
        &elementwise::SHADER,
        &fft::SHADER,
        &gru::SHADER,
        &head::SHADER,
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

/// Every shared op's uniform block on the Rust side (the steps' own: `model::block::uniforms`),
/// for the test that compares each with its WGSL struct (`tests/shaders.rs`). A block missing here is still checked on its
/// kernel's first dispatch ([`crate::gpu::Gpu::dispatch`]); the test fails on a shader
/// struct without an entry.
pub fn uniforms() -> Vec<UniformLayout> {
    vec![
        adam::Params::layout(),
        bias::Params::layout(),
        elementwise::Params::layout(),
        fft::Params::layout(),
        gru::Params::layout(),
        head::Params::layout(),
        loss::Params::layout(),
        lstm::Params::layout(),
        matmul::Params::layout(),
        outer::Params::layout(),
        removal::Params::layout(),
        softmax::Params::layout(),
        time_step::Params::layout(),
        unfold2d::Params::layout(),
    ]
}
