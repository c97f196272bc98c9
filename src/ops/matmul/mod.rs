//! Batched matrix multiply with transposes: forward, backward, and the CPU reference.
//!
//! `C[z] = op(A)[z] · op(B)[z]` with `op(A)` of shape `[m, k]` and `op(B)` of shape
//! `[k, n]`. A transposed operand is stored as its transpose (`[k, m]` for A); a
//! *shared* operand has no batch axis and is used by every batch item (a weight
//! matrix), so its gradient sums over the batch. The backward pass reuses the forward
//! kernel on transposed strided views; see `shaders/matmul.wgsl`.
//!
//! This file holds the kernels and what callers pass in besides the shape; `plan.rs` turns
//! a [`Matmul`] into the strided products it launches and their load modes, `dispatch.rs`
//! records them (kernel choice, workgroups, split reductions), and [`cpu`] is the f64
//! reference.

mod dispatch;
mod plan;

pub mod cpu;

pub use plan::{plan, Matmul, Tiling};

pub(crate) use dispatch::Params;

use crate::gpu::{Binding, Gpu, Kernel, Shader, Tensor};

/// The portable WGSL module of this family (`shaders/matmul.wgsl`: the block kernel
/// `matmul`, the one-row kernel `matmul_row`, `sum_partials` of a split reduction), whose
/// declarations [`SUBGROUP_SHADER`] builds on.
pub static SHADER: Shader = Shader {
    name: "matmul",
    source: include_str!("../../../shaders/matmul.wgsl"),
    base: None,
};

/// The subgroup kernel, in its own module so that a device without subgroup operations
/// still compiles `matmul.wgsl`.
pub static SUBGROUP_SHADER: Shader = Shader {
    name: "matmul_subgroup",
    source: include_str!("../../../shaders/matmul_subgroup.wgsl"),
    base: Some(&SHADER),
};

/// `a`, `b`, `a` and `b` again as vectors (`a4`, `b4` in the shader), the bias, the
/// gate's other input, `c` as vectors (`c4`), `c`.
const BINDINGS: &[Binding] = &[
    Binding::read(1),
    Binding::read(2),
    Binding::read(4),
    Binding::read(5),
    Binding::read(6),
    Binding::read(7),
    Binding::read_write(8),
    Binding::read_write(3),
];

/// 8×8 blocks of C per invocation.
static KERNEL: Kernel = Kernel {
    shader: &SHADER,
    entry: "matmul",
    bindings: BINDINGS,
};

/// 32×16 tiles of C per subgroup of 8 lanes, op(B) loaded once per subgroup.
static KERNEL_SUBGROUP: Kernel = Kernel {
    shader: &SUBGROUP_SHADER,
    entry: "matmul_subgroup",
    bindings: BINDINGS,
};

/// 16 rows × 32 columns per subgroup of 8 lanes (products of at most 16 rows), op(A)
/// loaded once per subgroup.
static KERNEL_SUBGROUP_COLS: Kernel = Kernel {
    shader: &SUBGROUP_SHADER,
    entry: "matmul_subgroup_cols",
    bindings: BINDINGS,
};

/// The sum of a split product's partial results.
static KERNEL_SUM: Kernel = Kernel {
    shader: &SHADER,
    entry: "sum_partials",
    bindings: BINDINGS,
};

/// Four outputs of a single-row C per invocation.
static KERNEL_ROW: Kernel = Kernel {
    shader: &SHADER,
    entry: "matmul_row",
    bindings: BINDINGS,
};

/// Invocations per workgroup of [`KERNEL_ROW`].
const ROW_WORKGROUP: usize = 64;
/// Invocations per workgroup of [`KERNEL_SUM`] (the most lanes per output).
const SUM_WORKGROUP: usize = plan::SUM_MAX_LANES;

/// Outputs per invocation along each axis of the block kernel (8×8: large blocks are what
/// pays on lavapipe, 2× the GFLOP/s of 4×4 blocks), and invocations per workgroup axis
/// (chosen per product by `Gemm::group`).
const BLOCK: usize = 8;
const WORKGROUP: usize = 8;
/// The most invocations along y of a flat-grid group (8 × 32 = 256, WebGPU's default limit
/// per group).
const MAX_GROUP_Y: usize = 32;
/// Outputs per invocation of the row kernel.
const ROW_BLOCK: usize = 4;
/// The subgroup kernel: lanes per subgroup it is written for, the rows and columns of C
/// per subgroup, and the most subgroups per workgroup.
const SUBGROUP_LANES: u32 = 8;
const TILE_ROWS: usize = 32;
const TILE_COLS: usize = 16;
const MAX_TILES: usize = 8;
/// The column-split subgroup kernel: the most rows of C it covers, its columns per
/// subgroup, subgroups per workgroup, and the fewest columns it is chosen for.
const COLS_MAX_M: usize = 16;
const COLS_TILE: usize = 32;
const COLS_PER_GROUP: usize = 4;
const COLS_MIN_N: usize = 32;

/// True when `gpu` runs the subgroup kernel: subgroup operations enabled (see
/// [`crate::gpu::SUBGROUPS_ENV`]) and subgroups of exactly 8 lanes.
pub fn subgroup_kernel_available(gpu: &Gpu) -> bool {
    gpu.subgroup_size() == Some(SUBGROUP_LANES)
}

/// What a forward product does to each output before storing it.
#[derive(Clone, Copy, Debug, Default)]
pub struct Epilogue<'t> {
    /// `[m]`, added to row i.
    pub bias: Option<&'t Tensor>,
    /// `[m, n]`, added to every batch item (instead of `bias`).
    pub matrix: Option<&'t Tensor>,
    /// max(0, ·) of the final value (after the bias and any accumulation).
    pub relu: bool,
    /// Laid out like C: the output becomes `tanh(gate) ⊙ σ(product + bias)`, the gated
    /// activation fused into the gate product.
    pub gate: Option<&'t Tensor>,
    /// σ(·) of the final value (after the bias): an attention's scores fused into the
    /// product that forms them.
    pub sigmoid: bool,
    /// Laid out like C, the output `s` of a sigmoid: the output becomes
    /// `product ⊙ s ⊙ (1 − s)`, the sigmoid's backward fused into the product of its
    /// output's gradient (overwriting C only).
    pub sigmoid_backward: Option<&'t Tensor>,
}

impl Epilogue<'_> {
    /// Nothing added or applied: the product alone.
    pub(super) fn is_plain(&self) -> bool {
        self.bias.is_none()
            && self.matrix.is_none()
            && self.gate.is_none()
            && !self.relu
            && !self.sigmoid
            && self.sigmoid_backward.is_none()
    }

    /// The tensor laid out like C that the epilogue reads (the gate's filter or the
    /// sigmoid's output), if any.
    pub(super) fn like_c(&self) -> Option<&Tensor> {
        self.gate.or(self.sigmoid_backward)
    }

    /// `SIGMOID` of `matmul.wgsl`: 0 none, 1 σ of the output, 2 the sigmoid's backward.
    pub(super) fn sigmoid_mode(&self) -> u32 {
        match (self.sigmoid, self.sigmoid_backward) {
            (true, _) => 1,
            (false, Some(_)) => 2,
            (false, None) => 0,
        }
    }
}

/// How `matmul.wgsl` loads each operand (its override constants).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Loads {
    /// op(A) read four floats at a time...
    pub a_vec: bool,
    /// ...along k (else along m).
    pub a_along_k: bool,
    /// op(B) read four floats at a time...
    pub b_vec: bool,
    /// ...along n (else along k).
    pub b_along_n: bool,
}

impl Loads {
    fn constants(self) -> [(&'static str, f64); 4] {
        let f = |x: bool| f64::from(u8::from(x));
        [
            ("A_VEC", f(self.a_vec)),
            ("A_ALONG_K", f(self.a_along_k)),
            ("B_VEC", f(self.b_vec)),
            ("B_ALONG_N", f(self.b_along_n)),
        ]
    }
}
