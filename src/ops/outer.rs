//! Two outer products per batch item, each with one shared factor, summed into one tensor:
//! `out[z, i, j] (+)= u[i]·v[z, j] + second term`, the second term being `w[z, i]·q[j]`
//! ([`Second::RowsByCols`]) or `w[z mod nodes]·q[z / nodes, i, j]` ([`Second::NodeByMatrix`]).
//! The model uses them for the gradients that reach a block's input through the rank-1
//! projections of its attentions: `rhs = W3·X_t` and `xw1 = X_t·W1` (spatial, first form),
//! `rhs = U3·X` and `xu1 = U1·X` (temporal, second form). One pass over `[B, N, C, T]` where
//! two rank-1 matmul backward products each read and wrote it. The kernel is itself a
//! backward step (of products whose own backward is the matmul's), so it has no backward
//! of its own.

use crate::gpu::{grid_1d, Binding, Dispatch, Gpu, GpuError, Kernel, Shader, Tensor};
use crate::ops::Accumulate;

/// The WGSL module of this family (`shaders/outer.wgsl`, entry `outer_pair`).
pub static SHADER: Shader = Shader {
    name: "outer",
    source: include_str!("../../shaders/outer.wgsl"),
    base: None,
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

crate::gpu::uniform! {
    pub(crate) struct Params = OuterParams in SHADER {
        items: u32,
        rows: u32,
        cols: u32,
        accumulate: u32,
        nodes: u32,
        _pad0: u32,
        _pad1: u32,
        _pad2: u32,
    }
}

/// The second outer product of each item `z` of `out [items, rows, cols]`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Second {
    /// `w[z, i]·q[j]`: `w [items, rows]`, `q [cols]`.
    RowsByCols,
    /// `w[z mod nodes]·q[z / nodes, i, j]`: `w [nodes]`, `q [items / nodes, rows, cols]`
    /// (items run over (batch, node) pairs).
    NodeByMatrix {
        /// Nodes N per batch item: item z is node `z mod N` of batch item `z / N`.
        nodes: usize,
    },
}

/// The shape: `out` is `[items, rows, cols]`, `u` `[rows]`, `v` `[items, cols]`; `w` and
/// `q` as [`Second`] says.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct OuterPair {
    /// Number of items z, each an output matrix of its own (B·N in a block).
    pub items: usize,
    /// Rows i of each item's matrix, and the length of `u` (C_in in a block).
    pub rows: usize,
    /// Columns j of each item's matrix (T in a block).
    pub cols: usize,
    /// The form of the second outer product, and the shapes of `w` and `q`.
    pub second: Second,
}

impl OuterPair {
    /// `out (+)= u ⊗ v + w ⊗ q` per item.
    pub fn apply(
        &self,
        gpu: &Gpu,
        [u, v, w, q]: [&Tensor; 4],
        out: &Tensor,
        accumulate: Accumulate,
    ) -> Result<Dispatch, GpuError> {
        let (z, r, c) = (self.items, self.rows, self.cols);
        let (w_len, q_len, nodes) = match self.second {
            Second::RowsByCols => (z * r, c, 1),
            Second::NodeByMatrix { nodes } => {
                if nodes == 0 || !z.is_multiple_of(nodes) {
                    return Err(GpuError::Shape {
                        tensor: out.name().to_string(),
                        expected: format!("items ({z}) a whole number of batches of nodes"),
                        got: format!("{nodes} nodes"),
                    });
                }
                (nodes, z * r * c / nodes, nodes)
            }
        };
        for (t, len) in [(u, r), (v, z * c), (w, w_len), (q, q_len), (out, z * r * c)] {
            t.expect_len(len)?;
        }
        out.expect_distinct([u, v, w, q])?;
        let params = Params {
            items: z as u32,
            rows: r as u32,
            cols: c as u32,
            accumulate: accumulate.flag(),
            nodes: nodes as u32,
            _pad0: 0,
            _pad1: 0,
            _pad2: 0,
        };
        let flag = |x: bool| f64::from(u8::from(x));
        let node_matrix = matches!(self.second, Second::NodeByMatrix { .. });
        let constants = [
            ("VEC", flag(c.is_multiple_of(4))),
            ("NODE_MATRIX", flag(node_matrix)),
        ];
        let limit = gpu.limits().max_compute_workgroups_per_dimension;
        let groups = grid_1d(z * r, WORKGROUP, limit);
        let tensors = [u, v, w, q, v, q, out, out];
        gpu.dispatch(&KERNEL, &constants, &params, &tensors, groups)
    }
}

/// f64 reference, for tests.
pub mod cpu {
    use super::{OuterPair, Second};

    /// `out [items, rows, cols] = u ⊗ v + w ⊗ q` per item, as a new vector (the
    /// overwriting form of [`OuterPair::apply`]).
    pub fn apply(op: &OuterPair, u: &[f64], v: &[f64], w: &[f64], q: &[f64]) -> Vec<f64> {
        let (rows, cols) = (op.rows, op.cols);
        let mut out = Vec::with_capacity(op.items * rows * cols);
        for z in 0..op.items {
            for i in 0..rows {
                for j in 0..cols {
                    let second = match op.second {
                        Second::RowsByCols => w[z * rows + i] * q[j],
                        Second::NodeByMatrix { nodes } => {
                            w[z % nodes] * q[((z / nodes) * rows + i) * cols + j]
                        }
                    };
                    out.push(u[i] * v[z * cols + j] + second);
                }
            }
        }
        out
    }
}
