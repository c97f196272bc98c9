//! The GRU state update `h' = u ⊙ h + (1 − u) ⊙ c` (u the update gate, c the candidate)
//! and its backward, element by element, with the f64 CPU reference.

use crate::gpu::{grid_1d, Binding, Dispatch, Gpu, GpuError, Kernel, Shader, Tensor};
use crate::ops::Accumulate;

/// The WGSL module of this family (`shaders/gru.wgsl`: `gru_forward`, `gru_backward`).
pub static SHADER: Shader = Shader {
    name: "gru",
    source: include_str!("../../shaders/gru.wgsl"),
    base: None,
};

static FORWARD: Kernel = Kernel {
    shader: &SHADER,
    entry: "gru_forward",
    bindings: &[
        Binding::read(1),
        Binding::read(2),
        Binding::read(3),
        Binding::read_write(4),
    ],
};
static BACKWARD: Kernel = Kernel {
    shader: &SHADER,
    entry: "gru_backward",
    bindings: &[
        Binding::read(1),
        Binding::read(2),
        Binding::read(3),
        Binding::read(4),
        Binding::read_write(5),
        Binding::read_write(6),
        Binding::read_write(7),
    ],
};

crate::gpu::uniform! {
    pub(crate) struct Params = GruParams in SHADER {
        n: u32,
        accumulate: u32,
        _pad0: u32,
        _pad1: u32,
    }
}

fn launch(
    gpu: &Gpu,
    kernel: &Kernel,
    tensors: &[&Tensor],
    accumulate: Accumulate,
) -> Result<Dispatch, GpuError> {
    let n = tensors[0].numel();
    for t in tensors {
        t.expect_len(n)?;
    }
    let params = Params {
        n: n as u32,
        accumulate: accumulate.flag(),
        _pad0: 0,
        _pad1: 0,
    };
    let max = gpu.limits().max_compute_workgroups_per_dimension;
    gpu.dispatch(kernel, &[], &params, tensors, grid_1d(n, 256, max))
}

/// `out = u ⊙ h + (1 − u) ⊙ c` (all the same length).
pub fn forward(
    gpu: &Gpu,
    u: &Tensor,
    h: &Tensor,
    c: &Tensor,
    out: &Tensor,
) -> Result<Dispatch, GpuError> {
    out.expect_distinct([u, h, c])?;
    launch(gpu, &FORWARD, &[u, h, c, out], Accumulate::Overwrite)
}

/// From `d_out`: `du = (h − c) ⊙ d_out` and `dc = (1 − u) ⊙ d_out` (overwritten), and
/// `dh (+)= u ⊙ d_out`.
#[allow(clippy::too_many_arguments)]
pub fn backward(
    gpu: &Gpu,
    u: &Tensor,
    h: &Tensor,
    c: &Tensor,
    d_out: &Tensor,
    du: &Tensor,
    dc: &Tensor,
    dh: &Tensor,
    accumulate: Accumulate,
) -> Result<Dispatch, GpuError> {
    for d in [du, dc, dh] {
        d.expect_distinct([u, h, c, d_out])?;
    }
    launch(gpu, &BACKWARD, &[u, h, c, d_out, du, dc, dh], accumulate)
}

/// f64 reference, for tests.
pub mod cpu {
    /// `u ⊙ h + (1 − u) ⊙ c`.
    pub fn forward(u: &[f64], h: &[f64], c: &[f64]) -> Vec<f64> {
        u.iter()
            .zip(h)
            .zip(c)
            .map(|((u, h), c)| u * h + (1.0 - u) * c)
            .collect()
    }

    /// `(du, dc, dh)` from the upstream gradient `g`.
    pub fn backward(u: &[f64], h: &[f64], c: &[f64], g: &[f64]) -> (Vec<f64>, Vec<f64>, Vec<f64>) {
        let du = h
            .iter()
            .zip(c)
            .zip(g)
            .map(|((h, c), g)| (h - c) * g)
            .collect();
        let dc = u.iter().zip(g).map(|(u, g)| (1.0 - u) * g).collect();
        let dh = u.iter().zip(g).map(|(u, g)| u * g).collect();
        (du, dc, dh)
    }
}
