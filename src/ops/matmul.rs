//! Batched matrix multiply with transposes: forward, backward, and the CPU reference.
//!
//! `C[z] = op(A)[z] · op(B)[z]` with `op(A)` of shape `[m, k]` and `op(B)` of shape
//! `[k, n]`. A transposed operand is stored as its transpose (`[k, m]` for A); a
//! *shared* operand has no batch axis and is used by every batch item (a weight
//! matrix), so its gradient sums over the batch. The backward pass reuses the forward
//! kernel on transposed strided views; see `shaders/matmul.wgsl`.

use crate::gpu::{grid_1d, Binding, DType, Dispatch, Gpu, GpuError, Kernel, Shader, Tensor};

pub static SHADER: Shader = Shader {
    name: "matmul",
    source: include_str!("../../shaders/matmul.wgsl"),
    base: None,
};

/// The subgroup kernel, in its own module so that a device without subgroup operations
/// still compiles `matmul.wgsl`.
pub static SUBGROUP_SHADER: Shader = Shader {
    name: "matmul_subgroup",
    source: include_str!("../../shaders/matmul_subgroup.wgsl"),
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

/// Outputs per invocation along each axis of the block kernel (8×8: large blocks are what
/// pays on lavapipe, 2× the GFLOP/s of 4×4 blocks), and invocations per workgroup axis
/// (chosen per product by [`Gemm::group`]).
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

/// Which kernel computes a product of more than one row of C.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Tiling {
    /// A subgroup kernel where the device has 8-lane subgroups (for products of at
    /// most 16 rows, only when they have at least 32 columns), else the block kernel.
    #[default]
    Auto,
    /// 8×8 blocks of C per invocation (`matmul`), on any device.
    Block,
    /// 32×16 tiles per 8-lane subgroup (`matmul_subgroup`), or 16×32 ones split by
    /// column for at most 16 rows (`matmul_subgroup_cols`); an error on other devices.
    Subgroup,
}

/// Operand bytes per chunk of a split reduction (about one core's L2), and the most
/// scratch its partial results may take (see [`Gemm::split_chunk`]).
const SPLIT_CHUNK_BYTES: usize = 1 << 20;
const SPLIT_PARTIALS_BYTES: usize = 32 << 20;

/// Shape of one (batched) product.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Matmul {
    pub batch: usize,
    pub m: usize,
    pub n: usize,
    pub k: usize,
    /// A is stored `[k, m]` (per batch item) and used transposed.
    pub trans_a: bool,
    /// B is stored `[n, k]` and used transposed.
    pub trans_b: bool,
    /// A has no batch axis: the same matrix for every batch item.
    pub shared_a: bool,
    /// B has no batch axis.
    pub shared_b: bool,
    /// `C = op(A) · (op(B) + I)` (k = n): the identity's term, op(A) itself, is added in
    /// the epilogue of the forward and dA products, saving a copy of A into C before an
    /// accumulating product and an extra pass adding dC into dA. dB is unchanged.
    pub plus_identity: bool,
    /// The kernel for products of more than one row ([`Tiling::Auto`] unless a test or a
    /// benchmark wants one).
    pub tiling: Tiling,
}

/// A strided 2-D view with a batch stride (0 when shared).
#[derive(Clone, Copy, Debug)]
struct View {
    row: usize,
    col: usize,
    batch: usize,
}

impl View {
    /// Logical `[rows, cols]`, stored row-major or (when `trans`) as its transpose.
    fn of(rows: usize, cols: usize, trans: bool, batch: usize) -> View {
        if trans {
            View {
                row: 1,
                col: rows,
                batch,
            }
        } else {
            View {
                row: cols,
                col: 1,
                batch,
            }
        }
    }

    fn t(self) -> View {
        View {
            row: self.col,
            col: self.row,
            batch: self.batch,
        }
    }
}

#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct Params {
    m: u32,
    n: u32,
    k: u32,
    reduce: u32,
    a_row: u32,
    a_col: u32,
    b_row: u32,
    b_col: u32,
    a_batch: u32,
    b_batch: u32,
    c_batch: u32,
    accumulate: u32,
    a_reduce: u32,
    b_reduce: u32,
    alpha: f32,
    batches: u32,
    chunk: u32,
}

impl Matmul {
    /// A single `[m, k] · [k, n]` product.
    pub fn new(m: usize, n: usize, k: usize) -> Matmul {
        Matmul {
            batch: 1,
            m,
            n,
            k,
            trans_a: false,
            trans_b: false,
            shared_a: false,
            shared_b: false,
            plus_identity: false,
            tiling: Tiling::Auto,
        }
    }

    pub fn batched(self, batch: usize) -> Matmul {
        Matmul { batch, ..self }
    }

    pub fn transpose_a(self, trans_a: bool) -> Matmul {
        Matmul { trans_a, ..self }
    }

    pub fn transpose_b(self, trans_b: bool) -> Matmul {
        Matmul { trans_b, ..self }
    }

    pub fn share_a(self, shared_a: bool) -> Matmul {
        Matmul { shared_a, ..self }
    }

    pub fn share_b(self, shared_b: bool) -> Matmul {
        Matmul { shared_b, ..self }
    }

    pub fn plus_identity(self, plus_identity: bool) -> Matmul {
        Matmul {
            plus_identity,
            ..self
        }
    }

    pub fn tiling(self, tiling: Tiling) -> Matmul {
        Matmul { tiling, ..self }
    }

    /// `plus_identity` needs a square op(B) of more than one row, and dA per batch item
    /// (a shared A's gradient would need the batch sum of dC as well).
    fn check_identity(&self, tensor: &Tensor) -> Result<(), GpuError> {
        if self.plus_identity && (self.k != self.n || self.n < 2 || self.shared_a) {
            return Err(GpuError::Shape {
                tensor: tensor.name().to_string(),
                expected: "a square op(B) (k = n > 1) and an unshared A for op(A)·(op(B) + I)"
                    .into(),
                got: format!("{self:?}"),
            });
        }
        Ok(())
    }

    pub fn a_len(&self) -> usize {
        self.m * self.k * if self.shared_a { 1 } else { self.batch }
    }

    pub fn b_len(&self) -> usize {
        self.k * self.n * if self.shared_b { 1 } else { self.batch }
    }

    pub fn c_len(&self) -> usize {
        self.batch * self.m * self.n
    }

    /// Multiply-adds counted twice, as usual for GFLOP/s.
    pub fn flops(&self) -> f64 {
        2.0 * (self.batch * self.m * self.n * self.k) as f64
    }

    fn view_a(&self) -> View {
        let stride = if self.shared_a { 0 } else { self.m * self.k };
        View::of(self.m, self.k, self.trans_a, stride)
    }

    fn view_b(&self) -> View {
        let stride = if self.shared_b { 0 } else { self.k * self.n };
        View::of(self.k, self.n, self.trans_b, stride)
    }

    fn view_c(&self) -> View {
        View::of(self.m, self.n, false, self.m * self.n)
    }

    /// `c (+)= op(a) · op(b)`.
    pub fn forward(
        &self,
        gpu: &Gpu,
        a: &Tensor,
        b: &Tensor,
        c: &Tensor,
        accumulate: bool,
    ) -> Result<Dispatch, GpuError> {
        self.forward_with(gpu, a, b, c, accumulate, Epilogue::default())
    }

    /// `c = op(a) · op(b) (+ bias) (+ c)`, then ReLU if asked: the epilogue's bias `[m]` is
    /// added to row i of every batch item. Fusing a channel bias or an activation into the
    /// product saves a pass over `c`.
    pub fn forward_with(
        &self,
        gpu: &Gpu,
        a: &Tensor,
        b: &Tensor,
        c: &Tensor,
        accumulate: bool,
        epilogue: Epilogue,
    ) -> Result<Dispatch, GpuError> {
        a.expect_len(self.a_len())?;
        b.expect_len(self.b_len())?;
        if let Some(bias) = epilogue.bias {
            bias.expect_len(self.m)?;
        }
        if let Some(matrix) = epilogue.matrix {
            matrix.expect_len(self.m * self.n)?;
            if epilogue.bias.is_some() || self.n == 1 {
                return Err(GpuError::Shape {
                    tensor: matrix.name().to_string(),
                    expected: "a matrix added alone, to a product with more than one column".into(),
                    got: format!("{self:?} with a row bias too: {}", epilogue.bias.is_some()),
                });
            }
        }
        if let Some(gate) = epilogue.gate {
            gate.expect_len(self.c_len())?;
        }
        c.expect_len(self.c_len())?;
        self.check_identity(c)?;
        self.forward_gemm()
            .dispatch_with(gpu, a, b, c, accumulate, epilogue)
    }

    fn forward_gemm(&self) -> Gemm {
        Gemm {
            m: self.m,
            n: self.n,
            k: self.k,
            lhs: self.view_a(),
            rhs: self.view_b(),
            out_shared: false,
            batch: self.batch,
            plus: self.identity_on(Plus::Lhs),
            tiling: self.tiling,
        }
    }

    /// The operand a product's epilogue adds for `plus_identity`: `side`, or none.
    fn identity_on(&self, side: Plus) -> Plus {
        if self.plus_identity {
            side
        } else {
            Plus::None
        }
    }

    /// `da (+)= ∂L/∂a` given `dc = ∂L/∂c` (needs `b`).
    pub fn backward_a(
        &self,
        gpu: &Gpu,
        b: &Tensor,
        dc: &Tensor,
        da: &Tensor,
        accumulate: bool,
    ) -> Result<Dispatch, GpuError> {
        b.expect_len(self.b_len())?;
        dc.expect_len(self.c_len())?;
        da.expect_len(self.a_len())?;
        self.check_identity(da)?;
        let (gemm, b_first) = self.backward_a_gemm();
        let (lhs, rhs) = if b_first { (b, dc) } else { (dc, b) };
        gemm.dispatch(gpu, lhs, rhs, da, accumulate)
    }

    /// The product giving dA, and whether its left operand is B (else dC).
    fn backward_a_gemm(&self) -> (Gemm, bool) {
        let (dcv, bv) = (self.view_c(), self.view_b());
        // op(A) grad = dC · op(B)ᵀ, stored as its transpose when A is; with the identity,
        // dC · (op(B) + I)ᵀ adds dC itself (the operand beside op(B)).
        if self.trans_a {
            let gemm = Gemm {
                m: self.k,
                n: self.m,
                k: self.n,
                lhs: bv,
                rhs: dcv.t(),
                out_shared: self.shared_a,
                batch: self.batch,
                plus: self.identity_on(Plus::Rhs),
                tiling: self.tiling,
            };
            (gemm, true)
        } else {
            let gemm = Gemm {
                m: self.m,
                n: self.k,
                k: self.n,
                lhs: dcv,
                rhs: bv.t(),
                out_shared: self.shared_a,
                batch: self.batch,
                plus: self.identity_on(Plus::Lhs),
                tiling: self.tiling,
            };
            (gemm, false)
        }
    }

    /// `db (+)= ∂L/∂b` given `dc = ∂L/∂c` (needs `a`).
    pub fn backward_b(
        &self,
        gpu: &Gpu,
        a: &Tensor,
        dc: &Tensor,
        db: &Tensor,
        accumulate: bool,
    ) -> Result<Dispatch, GpuError> {
        a.expect_len(self.a_len())?;
        dc.expect_len(self.c_len())?;
        db.expect_len(self.b_len())?;
        let (gemm, dc_first) = self.backward_b_gemm();
        let (lhs, rhs) = if dc_first { (dc, a) } else { (a, dc) };
        gemm.dispatch(gpu, lhs, rhs, db, accumulate)
    }

    /// The product giving dB, and whether its left operand is dC (else A).
    fn backward_b_gemm(&self) -> (Gemm, bool) {
        let (av, dcv) = (self.view_a(), self.view_c());
        // op(B) grad = op(A)ᵀ · dC, stored as its transpose when B is.
        if self.trans_b {
            let gemm = Gemm {
                m: self.n,
                n: self.k,
                k: self.m,
                lhs: dcv.t(),
                rhs: av,
                out_shared: self.shared_b,
                batch: self.batch,
                plus: Plus::None,
                tiling: self.tiling,
            };
            (gemm, true)
        } else {
            let gemm = Gemm {
                m: self.k,
                n: self.n,
                k: self.m,
                lhs: av.t(),
                rhs: dcv,
                out_shared: self.shared_b,
                batch: self.batch,
                plus: Plus::None,
                tiling: self.tiling,
            };
            (gemm, false)
        }
    }
}

/// One launch of the kernel: `out[m, n] = lhs[m, k] · rhs[k, n]` over strided views.
#[derive(Clone, Copy, Debug)]
struct Gemm {
    m: usize,
    n: usize,
    k: usize,
    lhs: View,
    rhs: View,
    /// The output has no batch axis: sum the products of all batch items into it.
    out_shared: bool,
    batch: usize,
    /// An operand added to the product in the epilogue (never with `out_shared`).
    plus: Plus,
    tiling: Tiling,
}

/// Which operand, if any, the epilogue adds to C: `lhs · (rhs + I)` adds element (i, j)
/// of lhs (k = n), `(lhs + I) · rhs` adds element (i, j) of rhs (k = m).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Plus {
    None,
    Lhs,
    Rhs,
}

impl Plus {
    /// The value of `matmul.wgsl`'s PLUS_I.
    fn mode(self) -> u8 {
        match self {
            Plus::None => 0,
            Plus::Lhs => 1,
            Plus::Rhs => 2,
        }
    }

    /// The same term after the operands are swapped and transposed.
    fn swapped(self) -> Plus {
        match self {
            Plus::None => Plus::None,
            Plus::Lhs => Plus::Rhs,
            Plus::Rhs => Plus::Lhs,
        }
    }
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

impl Gemm {
    /// A product with one output column is the product with one output row of the
    /// transposed views (`Cᵀ = op(B)ᵀ · op(A)ᵀ`, the same memory since C is a vector per
    /// batch item), which the row kernel computes without wasting 7/8 of an 8×8 block.
    fn canonical(self) -> (Gemm, bool) {
        if self.n == 1 && self.m > 1 {
            let t = Gemm {
                m: 1,
                n: self.m,
                k: self.k,
                lhs: self.rhs.t(),
                rhs: self.lhs.t(),
                plus: self.plus.swapped(),
                ..self
            };
            (t, true)
        } else {
            (self, false)
        }
    }

    /// Vector loads for each operand that allows them: contiguous along one axis, with
    /// that axis (where blocks read it unclamped), the other stride and the batch stride
    /// multiples of 4, so every vector starts on a 16-byte boundary. Loads within the
    /// k-loop step by 4 from there; a ragged K ends in scalar loads.
    fn loads(&self) -> Loads {
        let aligned = |xs: &[usize]| xs.iter().all(|x| x % 4 == 0);
        let (l, r) = (self.lhs, self.rhs);
        // One row reads no row stride.
        let a_k = l.col == 1 && aligned(&[l.batch]) && (self.m == 1 || aligned(&[l.row]));
        let a_m = self.m > 1 && l.row == 1 && aligned(&[l.batch, l.col, self.m]);
        let b_n = r.col == 1 && aligned(&[r.batch, r.row, self.n]);
        let b_k = r.row == 1 && aligned(&[r.batch, r.col]);
        Loads {
            a_vec: a_k || a_m,
            a_along_k: !a_m,
            b_vec: b_n || b_k,
            b_along_n: !b_k,
        }
    }

    /// Invocations per workgroup along n, m and the batch for the block kernel, from
    /// measurements on lavapipe (which runs 8 consecutive invocations as SIMD lanes: they
    /// had better differ in the column, sharing A, so always 8 along x):
    /// - one output (a weight gradient summed over the batch): 8×1×1, as many groups as
    ///   possible to keep every thread busy (1.3× over 8×8 on the paper's conv weight);
    /// - per-item outputs of at most two block rows or 48 blocks: 8×1×8, packing eight
    ///   batch items to a group (1.8–2.3× over 8×8 on the small shape's products);
    /// - otherwise 8×8×1 (64×64 outputs per group).
    ///
    /// Batched products whose items end mid-group along n run on a flat grid instead
    /// (see [`Gemm::block_grid`]).
    fn group(&self, batches: usize) -> [usize; 3] {
        let (nx, ny) = (self.n.div_ceil(BLOCK), self.m.div_ceil(BLOCK));
        if batches == 1 {
            [WORKGROUP, 1, 1]
        } else if ny <= 2 || nx * ny <= 48 {
            [WORKGROUP, 1, WORKGROUP]
        } else {
            [WORKGROUP, WORKGROUP, 1]
        }
    }

    /// `matmul.wgsl`'s override constants for the loads and the epilogue (`swapped`: rows
    /// of C are columns of this product). C is stored four floats at a time (C_VEC) when
    /// every row of C starts on a 16-byte boundary and ends with a whole vector.
    fn constants(&self, epilogue: &Epilogue, swapped: bool) -> Vec<(&'static str, f64)> {
        let flag = |x: bool| f64::from(u8::from(x));
        let bias_mode = match (epilogue.bias, epilogue.matrix, swapped) {
            (Some(_), _, false) => 1,
            (Some(_), _, true) => 2,
            (None, Some(_), _) => 3,
            (None, None, _) => 0,
        };
        let mut constants = self.loads().constants().to_vec();
        constants.extend([
            ("BIAS", f64::from(bias_mode)),
            ("RELU", flag(epilogue.relu)),
            ("GATE", flag(epilogue.gate.is_some())),
            ("C_VEC", flag(self.n.is_multiple_of(4))),
            ("PLUS_I", f64::from(self.plus.mode())),
        ]);
        constants
    }

    /// The block kernel's workgroup shape (pushed onto `constants`) and grid for
    /// `batches` items of C.
    fn block_grid(&self, batches: usize, constants: &mut Vec<(&'static str, f64)>) -> [u32; 3] {
        let (nx, ny) = (self.n.div_ceil(BLOCK), self.m.div_ceil(BLOCK));
        // Lanes along x over (item, column block) pairs when an item's blocks would leave
        // lanes of its last group idle: 1.04–1.2× on the model's n = 100 and n = 48
        // products (FLAT_X in the shader).
        // (At most 65535 groups along x: the WebGPU default limit per dimension.)
        let flat_groups = (nx * batches).div_ceil(WORKGROUP);
        if batches > 1 && nx % WORKGROUP != 0 && flat_groups <= u16::MAX as usize {
            // All of an item's row blocks in one group where they fit (≤ 256 invocations),
            // so the groups running together share that item's operands in cache; with
            // several groups along y each would stream every item's operands again:
            // 1.2–1.25× on the temporal attention's T × T products (13 row blocks).
            let y = if ny <= MAX_GROUP_Y { ny } else { WORKGROUP };
            constants.extend([
                ("GROUP_X", WORKGROUP as f64),
                ("GROUP_Y", y as f64),
                ("GROUP_Z", 1.0),
                ("FLAT_X", 1.0),
            ]);
            return [flat_groups as u32, ny.div_ceil(y) as u32, 1];
        }
        let [x, y, z] = self.group(batches);
        constants.extend([
            ("GROUP_X", x as f64),
            ("GROUP_Y", y as f64),
            ("GROUP_Z", z as f64),
        ]);
        [
            self.n.div_ceil(BLOCK * x).max(1) as u32,
            self.m.div_ceil(BLOCK * y).max(1) as u32,
            batches.div_ceil(z) as u32,
        ]
    }

    /// One of the subgroup kernels and its grid for `batches` items of C (its workgroup
    /// size pushed onto `constants`), or `None` where the block kernel runs instead.
    /// - `matmul_subgroup` (more than 16 rows): x over (item, block of 16 columns) pairs,
    ///   y over groups of 32-row tiles (all of a column block's tiles in one group where
    ///   they fit, so the subgroups running together share its op(B) in cache);
    /// - `matmul_subgroup_cols` (at most 16 rows): x over groups of (item, block of 32
    ///   columns) pairs.
    fn subgroup_grid(
        &self,
        gpu: &Gpu,
        batches: usize,
        constants: &mut Vec<(&'static str, f64)>,
    ) -> Result<Option<(&'static Kernel, [u32; 3])>, GpuError> {
        let usable = subgroup_kernel_available(gpu);
        let cols = self.m <= COLS_MAX_M;
        let x = if cols {
            (batches * self.n.div_ceil(COLS_TILE)).div_ceil(COLS_PER_GROUP)
        } else {
            batches * self.n.div_ceil(TILE_COLS)
        };
        let fits = x <= gpu.limits().max_compute_workgroups_per_dimension as usize;
        match self.tiling {
            Tiling::Block => return Ok(None),
            Tiling::Auto if !usable || !fits || (cols && self.n < COLS_MIN_N) => return Ok(None),
            Tiling::Subgroup if !usable => {
                return Err(GpuError::Device(format!(
                    "the subgroup matmul needs {SUBGROUP_LANES}-lane subgroups; {} has {:?}",
                    gpu.info().name,
                    gpu.subgroup_size()
                )))
            }
            _ => {}
        }
        if cols {
            constants.push(("SG_COL_TILES", COLS_PER_GROUP as f64));
            return Ok(Some((&KERNEL_SUBGROUP_COLS, [x as u32, 1, 1])));
        }
        let tiles = self.m.div_ceil(TILE_ROWS);
        // More tiles than fit: the largest group that divides them evenly, if not too
        // small, so that no subgroup idles.
        let per_group = if tiles <= MAX_TILES {
            tiles
        } else {
            (MAX_TILES / 2..=MAX_TILES)
                .rev()
                .find(|&d| tiles.is_multiple_of(d))
                .unwrap_or(MAX_TILES)
        };
        constants.push(("SG_TILES", per_group as f64));
        let groups = [x as u32, tiles.div_ceil(per_group) as u32, 1];
        Ok(Some((&KERNEL_SUBGROUP, groups)))
    }

    /// The kernel and grid for a product of more than one row: a subgroup kernel where
    /// [`Gemm::subgroup_grid`] allows it, else the block kernel.
    fn tiled_grid(
        &self,
        gpu: &Gpu,
        batches: usize,
        constants: &mut Vec<(&'static str, f64)>,
    ) -> Result<(&'static Kernel, [u32; 3]), GpuError> {
        Ok(match self.subgroup_grid(gpu, batches, constants)? {
            Some(chosen) => chosen,
            None => (&KERNEL, self.block_grid(batches, constants)),
        })
    }

    /// Reduction items per chunk when a batch-summed product (a weight gradient) is better
    /// split: each chunk's sum goes to its own slice of a scratch buffer, and a second
    /// launch adds the slices in order. A single launch sweeps all items in every
    /// invocation, so each item's operands stream from memory again for every block of C
    /// (the paper's conv weight gradient ran at 0.6 of the best matmul). Chunks whose
    /// operands fit in one core's L2 let the blocks of C that run together share them:
    /// 1.8× on that product (7.7 → 14–15.7 GFLOP/s, best with ~1 MiB chunks).
    fn split_chunk(&self, reduce: usize) -> Option<usize> {
        if !self.out_shared || self.m == 1 {
            return None;
        }
        let item_bytes = 4 * self.k * (self.m + self.n);
        let partial_bytes = 4 * self.m * self.n;
        let chunk = (SPLIT_CHUNK_BYTES / item_bytes)
            .max(1)
            .max((reduce * partial_bytes).div_ceil(SPLIT_PARTIALS_BYTES));
        (chunk < reduce).then_some(chunk)
    }

    /// The two launches of a split product: partial sums over `chunk` items each, then
    /// their sum into `out` (accumulating when `params.accumulate` is set).
    fn dispatch_split(
        self,
        gpu: &Gpu,
        [lhs, rhs, out]: [&Tensor; 3],
        params: Params,
        chunk: usize,
        flops: f64,
    ) -> Result<Dispatch, GpuError> {
        let chunks = (params.reduce as usize).div_ceil(chunk);
        let len = self.m * self.n;
        let partials = gpu.zeros(
            &format!("{} partials", out.name()),
            &[chunks, len],
            DType::F32,
        );
        let part = Params {
            batches: chunks as u32,
            chunk: chunk as u32,
            accumulate: 0,
            ..params
        };
        let mut constants = self.constants(&Epilogue::default(), false);
        constants.push(("REDUCE", 1.0));
        let (kernel, groups) = self.tiled_grid(gpu, chunks, &mut constants)?;
        let tensors = [lhs, rhs, lhs, rhs, lhs, lhs, &partials, &partials];
        let first = gpu.dispatch(kernel, &constants, &part, &tensors, groups)?;
        let sum = Params {
            n: len as u32,
            batches: chunks as u32,
            ..params
        };
        let limit = gpu.limits().max_compute_workgroups_per_dimension;
        let groups = grid_1d(len, 64, limit);
        let tensors = [&partials; 6]
            .into_iter()
            .chain([out, out])
            .collect::<Vec<_>>();
        let sum = gpu.dispatch(&KERNEL_SUM, &[], &sum, &tensors, groups)?;
        Ok(first.then(sum).with_flops(flops))
    }

    fn dispatch(
        self,
        gpu: &Gpu,
        lhs: &Tensor,
        rhs: &Tensor,
        out: &Tensor,
        accumulate: bool,
    ) -> Result<Dispatch, GpuError> {
        self.dispatch_with(gpu, lhs, rhs, out, accumulate, Epilogue::default())
    }

    /// The launch, with what the epilogue adds or applies to the outputs.
    fn dispatch_with(
        self,
        gpu: &Gpu,
        lhs: &Tensor,
        rhs: &Tensor,
        out: &Tensor,
        accumulate: bool,
        epilogue: Epilogue,
    ) -> Result<Dispatch, GpuError> {
        let bias = epilogue.bias.or(epilogue.matrix);
        out.expect_distinct(
            [Some(lhs), Some(rhs), bias, epilogue.gate]
                .into_iter()
                .flatten(),
        )?;
        let flops = 2.0 * (self.batch * self.m * self.n * self.k) as f64;
        let (gemm, swapped) = self.canonical();
        let (lhs, rhs) = if swapped { (rhs, lhs) } else { (lhs, rhs) };
        let (out_batches, reduce) = if gemm.out_shared {
            (1, gemm.batch)
        } else {
            (gemm.batch, 1)
        };
        let (lb, lr) = if gemm.out_shared {
            (0, gemm.lhs.batch)
        } else {
            (gemm.lhs.batch, 0)
        };
        let (rb, rr) = if gemm.out_shared {
            (0, gemm.rhs.batch)
        } else {
            (gemm.rhs.batch, 0)
        };
        let params = Params {
            m: gemm.m as u32,
            n: gemm.n as u32,
            k: gemm.k as u32,
            reduce: reduce as u32,
            a_row: gemm.lhs.row as u32,
            a_col: gemm.lhs.col as u32,
            b_row: gemm.rhs.row as u32,
            b_col: gemm.rhs.col as u32,
            a_batch: lb as u32,
            b_batch: rb as u32,
            c_batch: (gemm.m * gemm.n) as u32,
            accumulate: accumulate as u32,
            a_reduce: lr as u32,
            b_reduce: rr as u32,
            alpha: 1.0,
            batches: out_batches as u32,
            chunk: 0,
        };
        let plain = epilogue.bias.is_none()
            && epilogue.matrix.is_none()
            && epilogue.gate.is_none()
            && !epilogue.relu
            && gemm.plus == Plus::None;
        if let Some(chunk) = gemm.split_chunk(reduce).filter(|_| plain) {
            return gemm.dispatch_split(gpu, [lhs, rhs, out], params, chunk, flops);
        }
        let mut constants = gemm.constants(&epilogue, swapped);
        constants.push(("REDUCE", f64::from(u8::from(reduce > 1))));
        let (kernel, groups) = if gemm.m == 1 {
            let per_group = ROW_BLOCK * ROW_WORKGROUP;
            let groups = [
                gemm.n.div_ceil(per_group).max(1) as u32,
                1,
                out_batches as u32,
            ];
            (&KERNEL_ROW, groups)
        } else {
            gemm.tiled_grid(gpu, out_batches, &mut constants)?
        };
        let gate = epilogue.gate.unwrap_or(lhs);
        let tensors = [lhs, rhs, lhs, rhs, bias.unwrap_or(lhs), gate, out, out];
        let d = gpu.dispatch(kernel, &constants, &params, &tensors, groups)?;
        Ok(d.with_flops(flops))
    }
}

/// The kernel entry and load modes `matmul.wgsl` uses for `mm`'s forward, dA and dB
/// products (in that order), for tests and profiles. The entry is the portable one
/// (`matmul` or `matmul_row`); on a device with 8-lane subgroups a product named
/// `matmul` runs on a subgroup kernel instead, with the same load modes.
pub fn plan(mm: &Matmul) -> [(&'static str, Loads); 3] {
    let describe = |g: Gemm| {
        let (g, _) = g.canonical();
        (if g.m == 1 { "matmul_row" } else { "matmul" }, g.loads())
    };
    [
        describe(mm.forward_gemm()),
        describe(mm.backward_a_gemm().0),
        describe(mm.backward_b_gemm().0),
    ]
}

/// Plain f64 reference of the same contract, written from the definition (no strides
/// shared with the GPU path), for tests.
pub mod cpu {
    use super::Matmul;

    /// Element `(i, kk)` of `op(A)` for batch item `z`.
    fn a_at(mm: &Matmul, a: &[f64], z: usize, i: usize, kk: usize) -> f64 {
        let base = if mm.shared_a { 0 } else { z * mm.m * mm.k };
        if mm.trans_a {
            a[base + kk * mm.m + i]
        } else {
            a[base + i * mm.k + kk]
        }
    }

    /// Element `(kk, j)` of `op(B)`, plus the identity's when `plus_identity`.
    fn b_at(mm: &Matmul, b: &[f64], z: usize, kk: usize, j: usize) -> f64 {
        let base = if mm.shared_b { 0 } else { z * mm.k * mm.n };
        let identity = if mm.plus_identity && kk == j {
            1.0
        } else {
            0.0
        };
        identity
            + if mm.trans_b {
                b[base + j * mm.k + kk]
            } else {
                b[base + kk * mm.n + j]
            }
    }

    pub fn forward(mm: &Matmul, a: &[f64], b: &[f64]) -> Vec<f64> {
        let mut c = vec![0.0; mm.c_len()];
        for z in 0..mm.batch {
            for i in 0..mm.m {
                for j in 0..mm.n {
                    let s: f64 = (0..mm.k)
                        .map(|kk| a_at(mm, a, z, i, kk) * b_at(mm, b, z, kk, j))
                        .sum();
                    c[(z * mm.m + i) * mm.n + j] = s;
                }
            }
        }
        c
    }

    /// Returns `(da, db)` for upstream gradient `dc`.
    pub fn backward(mm: &Matmul, a: &[f64], b: &[f64], dc: &[f64]) -> (Vec<f64>, Vec<f64>) {
        let mut da = vec![0.0; mm.a_len()];
        let mut db = vec![0.0; mm.b_len()];
        for z in 0..mm.batch {
            let abase = if mm.shared_a { 0 } else { z * mm.m * mm.k };
            let bbase = if mm.shared_b { 0 } else { z * mm.k * mm.n };
            for i in 0..mm.m {
                for kk in 0..mm.k {
                    let g: f64 = (0..mm.n)
                        .map(|j| dc[(z * mm.m + i) * mm.n + j] * b_at(mm, b, z, kk, j))
                        .sum();
                    let idx = if mm.trans_a {
                        kk * mm.m + i
                    } else {
                        i * mm.k + kk
                    };
                    da[abase + idx] += g;
                }
            }
            for kk in 0..mm.k {
                for j in 0..mm.n {
                    let g: f64 = (0..mm.m)
                        .map(|i| a_at(mm, a, z, i, kk) * dc[(z * mm.m + i) * mm.n + j])
                        .sum();
                    let idx = if mm.trans_b {
                        j * mm.k + kk
                    } else {
                        kk * mm.n + j
                    };
                    db[bbase + idx] += g;
                }
            }
        }
        (da, db)
    }
}
