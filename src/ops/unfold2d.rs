//! The 2-D unfolding (im2col) of a "same"-padded k×k convolution over an image
//! `[B, C, H, W]` into `col [B, C·k·k, H·W]`, so that the convolution is one product
//! `weight [C_out, C·k·k] · col[b]`; its backward folds ∂ℒ/∂col back onto the image. The
//! ConvLSTM baseline convolves the node × feature grid with it (docs/model.md "Baselines").
//! With the f64 CPU reference.

use crate::gpu::{grid_1d, Binding, Dispatch, Gpu, GpuError, Kernel, Shader, Tensor};
use crate::ops::Accumulate;

/// The WGSL module of this family (`shaders/unfold2d.wgsl`).
pub static SHADER: Shader = Shader {
    name: "unfold2d",
    source: include_str!("../../shaders/unfold2d.wgsl"),
    base: None,
};

static FORWARD: Kernel = Kernel {
    shader: &SHADER,
    entry: "unfold2d_forward",
    bindings: &[Binding::read(1), Binding::read_write(2)],
};
static BACKWARD: Kernel = Kernel {
    shader: &SHADER,
    entry: "unfold2d_backward",
    bindings: &[Binding::read(1), Binding::read_write(2)],
};

crate::gpu::uniform! {
    pub(crate) struct Params = Unfold2dParams in SHADER {
        batch: u32,
        channels: u32,
        height: u32,
        width: u32,
        kernel: u32,
        accumulate: u32,
        _pad0: u32,
        _pad1: u32,
    }
}

/// The shape of one unfolding.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Unfold2d {
    /// B: images.
    pub batch: usize,
    /// C: channels per image.
    pub channels: usize,
    /// H: rows (the nodes, for ConvLSTM).
    pub height: usize,
    /// W: columns (the features).
    pub width: usize,
    /// k: the kernel's side, odd (k/2 rows and columns of zero padding on each side).
    pub kernel: usize,
}

impl Unfold2d {
    /// Elements of the image, `B·C·H·W`.
    pub fn image_len(&self) -> usize {
        self.batch * self.channels * self.height * self.width
    }

    /// Elements of col, `B·C·k·k·H·W`.
    pub fn col_len(&self) -> usize {
        self.image_len() * self.kernel * self.kernel
    }

    fn params(&self, accumulate: Accumulate) -> Result<Params, GpuError> {
        if self.kernel.is_multiple_of(2) {
            return Err(GpuError::Shape {
                tensor: "unfold2d kernel".into(),
                expected: "an odd side (a centred \"same\" convolution)".into(),
                got: self.kernel.to_string(),
            });
        }
        Ok(Params {
            batch: self.batch as u32,
            channels: self.channels as u32,
            height: self.height as u32,
            width: self.width as u32,
            kernel: self.kernel as u32,
            accumulate: accumulate.flag(),
            _pad0: 0,
            _pad1: 0,
        })
    }

    /// `col` (overwritten) from `img`.
    pub fn forward(&self, gpu: &Gpu, img: &Tensor, col: &Tensor) -> Result<Dispatch, GpuError> {
        img.expect_len(self.image_len())?;
        col.expect_len(self.col_len())?;
        col.expect_distinct([img])?;
        let max = gpu.limits().max_compute_workgroups_per_dimension;
        let params = self.params(Accumulate::Overwrite)?;
        gpu.dispatch(
            &FORWARD,
            &[],
            &params,
            &[img, col],
            grid_1d(self.col_len(), 256, max),
        )
    }

    /// `d_img (+)= fold(d_col)`: each image element gets the sum of the col entries that
    /// read it.
    pub fn backward(
        &self,
        gpu: &Gpu,
        d_col: &Tensor,
        d_img: &Tensor,
        accumulate: Accumulate,
    ) -> Result<Dispatch, GpuError> {
        d_col.expect_len(self.col_len())?;
        d_img.expect_len(self.image_len())?;
        d_img.expect_distinct([d_col])?;
        let max = gpu.limits().max_compute_workgroups_per_dimension;
        let params = self.params(accumulate)?;
        let grid = grid_1d(self.image_len(), 256, max);
        gpu.dispatch(&BACKWARD, &[], &params, &[d_col, d_img], grid)
    }
}

/// f64 reference, for tests.
pub mod cpu {
    use super::Unfold2d;

    /// Where col entry (b, (c, ky, kx), (y, x)) reads the image, if inside it.
    fn source(u: &Unfold2d, b: usize, row: usize, pos: usize) -> Option<usize> {
        let kk = u.kernel * u.kernel;
        let (c, ky, kx) = (row / kk, (row % kk) / u.kernel, row % u.kernel);
        let half = u.kernel / 2;
        let y = (pos / u.width + ky)
            .checked_sub(half)
            .filter(|&y| y < u.height)?;
        let x = (pos % u.width + kx)
            .checked_sub(half)
            .filter(|&x| x < u.width)?;
        Some(((b * u.channels + c) * u.height + y) * u.width + x)
    }

    /// col `[B, C·k·k, H·W]` from the image.
    pub fn forward(u: &Unfold2d, img: &[f64]) -> Vec<f64> {
        let (rows, hw) = (u.channels * u.kernel * u.kernel, u.height * u.width);
        (0..u.col_len())
            .map(|k| {
                let (b, row, pos) = (k / (rows * hw), (k / hw) % rows, k % hw);
                source(u, b, row, pos).map_or(0.0, |s| img[s])
            })
            .collect()
    }

    /// ∂ℒ/∂img from ∂ℒ/∂col (the transpose of [`forward`]).
    pub fn backward(u: &Unfold2d, d_col: &[f64]) -> Vec<f64> {
        let (rows, hw) = (u.channels * u.kernel * u.kernel, u.height * u.width);
        let mut d = vec![0.0; u.image_len()];
        for (k, g) in d_col.iter().enumerate() {
            if let Some(s) = source(u, k / (rows * hw), (k / hw) % rows, k % hw) {
                d[s] += g;
            }
        }
        d
    }
}
