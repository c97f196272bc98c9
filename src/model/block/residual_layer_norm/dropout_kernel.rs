//! Inverted dropout (docs/model.md step 7) with a counter-based RNG: the mask is a hash of
//! (element, seed, step), recomputed in the backward pass instead of stored. Forward and
//! backward are the same kernel (`y = mask·x/(1−p)`, `dx = mask·dy/(1−p)`).

use crate::gpu::{grid_1d, Binding, Dispatch, Gpu, GpuError, Kernel, Shader, Tensor};
use crate::ops::Accumulate;

/// The WGSL module of this family (`shaders/dropout.wgsl`, entry `dropout`).
pub static SHADER: Shader = Shader {
    name: "dropout",
    source: include_str!("../../../../shaders/dropout.wgsl"),
    base: None,
};

static KERNEL: Kernel = Kernel {
    shader: &SHADER,
    entry: "dropout",
    bindings: &[Binding::read(1), Binding::read_write(2)],
};

crate::gpu::uniform! {
    #[derive(Debug, PartialEq)]
    pub(crate) struct Params = DropParams in SHADER {
        n: u32,
        seed: u32,
        step: u32,
        threshold: u32,
        scale: f32,
        accumulate: u32,
        stride: u32,
        offset: u32,
    }
}

/// Dropout with probability `p` over `n` elements, seeded. Element `i` draws the mask
/// bit of index `i·stride + offset`: a strided subset of a larger tensor (the last
/// block's last step) gets exactly the bits it has in the whole one.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Dropout {
    /// Number of elements the op reads and writes.
    pub n: usize,
    /// Drop probability, in [0, 1); kept elements are scaled by 1/(1−p).
    pub p: f64,
    /// The mask seed: `seed_l = seed32 + l` of block l (docs/model.md step 7, "how the mask
    /// is drawn").
    pub seed: u32,
    /// Flat-index step in the larger tensor between consecutive elements (1 for the whole
    /// tensor).
    pub stride: usize,
    /// Flat index in the larger tensor of element 0 (0 for the whole tensor).
    pub offset: usize,
}

impl Dropout {
    /// Dropout over all of `n` elements.
    pub fn new(n: usize, p: f64, seed: u32) -> Dropout {
        Dropout {
            n,
            p,
            seed,
            stride: 1,
            offset: 0,
        }
    }

    /// The same bits for the `n` elements `i·stride + offset` of a larger tensor.
    pub fn strided(self, n: usize, stride: usize, offset: usize) -> Dropout {
        Dropout {
            n,
            stride,
            offset,
            ..self
        }
    }

    fn params(&self, step: u32, accumulate: Accumulate) -> Params {
        Params {
            n: self.n as u32,
            seed: self.seed,
            step,
            threshold: self.threshold(),
            scale: self.scale(),
            accumulate: accumulate.flag(),
            stride: self.stride as u32,
            offset: self.offset as u32,
        }
    }

    /// The hash key of training step `step`: element i is kept when
    /// `lowbias32(i·stride + offset ^ key) ≥ threshold` (a kernel that fuses the mask
    /// takes the key, the threshold and the scale as parameters).
    pub(crate) fn key(&self, step: u32) -> u32 {
        lowbias32(self.seed ^ lowbias32(step))
    }

    /// `p·2³²`: elements whose hash is below it are dropped.
    pub(crate) fn threshold(&self) -> u32 {
        threshold(self.p)
    }

    /// 1/(1−p), the factor of a kept element.
    pub(crate) fn scale(&self) -> f32 {
        (1.0 / (1.0 - self.p)) as f32
    }

    /// Applies the mask of training step `step` to `src` into `dst` (forward: x → y;
    /// backward: dy → dx). Change the step of a built dispatch with [`Dropout::set_step`].
    pub fn apply(
        &self,
        gpu: &Gpu,
        step: u32,
        src: &Tensor,
        dst: &Tensor,
        accumulate: Accumulate,
    ) -> Result<Dispatch, GpuError> {
        src.expect_len(self.n)?;
        dst.expect_len(self.n)?;
        let grid = grid_1d(
            self.n,
            256,
            gpu.limits().max_compute_workgroups_per_dimension,
        );
        gpu.dispatch(
            &KERNEL,
            &[],
            &self.params(step, accumulate),
            &[src, dst],
            grid,
        )
    }

    /// Points a dispatch built by [`Dropout::apply`] at another training step (no
    /// allocation: rewrites its uniform block).
    pub fn set_step(
        &self,
        gpu: &Gpu,
        dispatch: &Dispatch,
        step: u32,
        accumulate: Accumulate,
    ) -> Result<(), GpuError> {
        dispatch.write_params(gpu, &self.params(step, accumulate))
    }
}

/// Elements whose hash is below `p·2³²` are dropped.
fn threshold(p: f64) -> u32 {
    (p.clamp(0.0, 1.0) * 4294967296.0).min(u32::MAX as f64) as u32
}

/// The shader's hash, bit for bit.
pub fn lowbias32(v: u32) -> u32 {
    let mut h = v;
    h ^= h >> 16;
    h = h.wrapping_mul(0x7feb_352d);
    h ^= h >> 15;
    h = h.wrapping_mul(0x846c_a68b);
    h ^= h >> 16;
    h
}

/// The CPU reference of the mask: `true` where element `i` is kept at `step`.
pub fn keep(d: &Dropout, step: u32, i: usize) -> bool {
    let index = (i * d.stride + d.offset) as u32;
    lowbias32(index ^ d.key(step)) >= d.threshold()
}

/// [`keep`] of the elements `first`, `first + 1`, … into `kept`, with the key and the
/// threshold made once and the index in wrapping u32 arithmetic (the same bits as the
/// usize arithmetic cut to 32 bits), so that the loop vectorises in the caller's
/// instruction set.
#[inline(always)]
pub(crate) fn keep_run(d: &Dropout, step: u32, first: usize, kept: &mut [bool]) {
    let (key, threshold) = (d.key(step), d.threshold());
    let (stride, offset) = (d.stride as u32, d.offset as u32);
    let first = first as u32;
    for (tau, k) in kept.iter_mut().enumerate() {
        let index = first
            .wrapping_add(tau as u32)
            .wrapping_mul(stride)
            .wrapping_add(offset);
        *k = lowbias32(index ^ key) >= threshold;
    }
}
