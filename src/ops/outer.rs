//! Two outer products per batch item, each with one shared factor, summed into one tensor:
//! `out[z, i, j] (+)= u[i]·v[z, j] + w[z, i]·q[j]`. The model uses it for the gradient that
//! reaches X_t through the spatial attention's projections `rhs = W3·X_t` and
//! `xw1 = X_t·W1`: one pass over `[B, N, C, T]` where two rank-1 matmul backward products
//! each read and wrote it. The kernel is itself a backward step (of two products whose own
//! backward is the matmul's), so it has no backward of its own.

use crate::gpu::{grid_1d, Binding, Dispatch, Gpu, GpuError, Kernel, Shader, Tensor};

pub static SHADER: Shader = Shader {
    name: "outer",
    source: include_str!("../../shaders/outer.wgsl"),
};

/// `u`, `v`, `w`, `q`, then `v` and `q` as vectors, `out` as vectors, `out`.
static KERNEL: Kernel = Kernel {
    shader: &SHADER,
    entry: "outer_pair",
    bindings: &[
        Binding::read(1),
        Binding::read(2),
        Binding::read(3),
        Binding::read(4),
        Binding::read(6),
        Binding::read(7),
        Binding::read_write(8),
        Binding::read_write(5),
    ],
};

/// Invocations per workgroup (one per output row).
const WORKGROUP: u32 = 64;

#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct Params {
    items: u32,
    rows: u32,
    cols: u32,
    accumulate: u32,
}

/// The shape: `out` is `[items, rows, cols]`, `u` `[rows]`, `v` `[items, cols]`,
/// `w` `[items, rows]`, `q` `[cols]`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct OuterPair {
    pub items: usize,
    pub rows: usize,
    pub cols: usize,
}

impl OuterPair {
    /// `out (+)= u ⊗ v + w ⊗ q` per item.
    pub fn apply(
        &self,
        gpu: &Gpu,
        [u, v, w, q]: [&Tensor; 4],
        out: &Tensor,
        accumulate: bool,
    ) -> Result<Dispatch, GpuError> {
        let (z, r, c) = (self.items, self.rows, self.cols);
        for (t, len) in [(u, r), (v, z * c), (w, z * r), (q, c), (out, z * r * c)] {
            t.expect_len(len)?;
        }
        for t in [u, v, w, q] {
            if t.buffer() == out.buffer() {
                return Err(GpuError::Shape {
                    tensor: out.name().to_string(),
                    expected: format!("a buffer distinct from input {}", t.name()),
                    got: "the same buffer".to_string(),
                });
            }
        }
        let params = Params {
            items: z as u32,
            rows: r as u32,
            cols: c as u32,
            accumulate: accumulate as u32,
        };
        let vec = f64::from(u8::from(c.is_multiple_of(4)));
        let limit = gpu.limits().max_compute_workgroups_per_dimension;
        let groups = grid_1d(z * r, WORKGROUP, limit);
        let tensors = [u, v, w, q, v, q, out, out];
        gpu.dispatch(&KERNEL, &[("VEC", vec)], &params, &tensors, groups)
    }
}

/// f64 reference, for tests.
pub mod cpu {
    use super::OuterPair;

    pub fn apply(op: &OuterPair, u: &[f64], v: &[f64], w: &[f64], q: &[f64]) -> Vec<f64> {
        let mut out = Vec::with_capacity(op.items * op.rows * op.cols);
        for z in 0..op.items {
            for i in 0..op.rows {
                for j in 0..op.cols {
                    out.push(u[i] * v[z * op.cols + j] + w[z * op.rows + i] * q[j]);
                }
            }
        }
        out
    }
}
