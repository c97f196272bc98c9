//! Batched matrix multiply with transposes: forward, backward, and the CPU reference.
//!
//! `C[z] = op(A)[z] · op(B)[z]` with `op(A)` of shape `[m, k]` and `op(B)` of shape
//! `[k, n]`. A transposed operand is stored as its transpose (`[k, m]` for A); a
//! *shared* operand has no batch axis and is used by every batch item (a weight
//! matrix), so its gradient sums over the batch. The backward pass reuses the forward
//! kernel on transposed strided views; see `shaders/matmul.wgsl`.

use crate::gpu::{Binding, Dispatch, Gpu, GpuError, Kernel, Shader, Tensor};

pub static SHADER: Shader = Shader {
    name: "matmul",
    source: include_str!("../../shaders/matmul.wgsl"),
};

const BINDINGS: &[Binding] = &[Binding::read(1), Binding::read(2), Binding::read_write(3)];

/// Scalar loads: any shape and stride.
static KERNEL: Kernel = Kernel {
    shader: &SHADER,
    entry: "matmul",
    bindings: BINDINGS,
};

/// Four-float loads: operands aligned to 4 along their contiguous axis (see [`Gemm::vec4`]).
static KERNEL_VEC4: Kernel = Kernel {
    shader: &SHADER,
    entry: "matmul_vec4",
    bindings: BINDINGS,
};

/// Outputs per invocation along each axis, and invocations per workgroup axis.
const BLOCK: usize = 4;
const WORKGROUP: usize = 8;

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
    _pad: u32,
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
        a.expect_len(self.a_len())?;
        b.expect_len(self.b_len())?;
        c.expect_len(self.c_len())?;
        let gemm = Gemm {
            m: self.m,
            n: self.n,
            k: self.k,
            lhs: self.view_a(),
            rhs: self.view_b(),
            out_shared: false,
            batch: self.batch,
        };
        gemm.dispatch(gpu, a, b, c, accumulate)
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
        let (dcv, bv) = (self.view_c(), self.view_b());
        // op(A) grad = dC · op(B)ᵀ, stored as its transpose when A is.
        let (gemm, lhs, rhs) = if self.trans_a {
            let gemm = Gemm {
                m: self.k,
                n: self.m,
                k: self.n,
                lhs: bv,
                rhs: dcv.t(),
                out_shared: self.shared_a,
                batch: self.batch,
            };
            (gemm, b, dc)
        } else {
            let gemm = Gemm {
                m: self.m,
                n: self.k,
                k: self.n,
                lhs: dcv,
                rhs: bv.t(),
                out_shared: self.shared_a,
                batch: self.batch,
            };
            (gemm, dc, b)
        };
        gemm.dispatch(gpu, lhs, rhs, da, accumulate)
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
        let (av, dcv) = (self.view_a(), self.view_c());
        // op(B) grad = op(A)ᵀ · dC, stored as its transpose when B is.
        let (gemm, lhs, rhs) = if self.trans_b {
            let gemm = Gemm {
                m: self.n,
                n: self.k,
                k: self.m,
                lhs: dcv.t(),
                rhs: av,
                out_shared: self.shared_b,
                batch: self.batch,
            };
            (gemm, dc, a)
        } else {
            let gemm = Gemm {
                m: self.k,
                n: self.n,
                k: self.m,
                lhs: av.t(),
                rhs: dcv,
                out_shared: self.shared_b,
                batch: self.batch,
            };
            (gemm, a, dc)
        };
        gemm.dispatch(gpu, lhs, rhs, db, accumulate)
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
}

impl Gemm {
    /// The override constants of `matmul_vec4` when every vector load is aligned: each
    /// operand contiguous along one axis, that axis, K, the other stride and the batch
    /// strides all multiples of 4. `None` means the scalar kernel.
    fn vec4(&self) -> Option<[(&'static str, f64); 2]> {
        let aligned = |xs: &[usize]| xs.iter().all(|x| x % 4 == 0);
        if !aligned(&[self.k, self.lhs.batch, self.rhs.batch]) {
            return None;
        }
        let a_along_k = if self.lhs.col == 1 && aligned(&[self.lhs.row]) {
            true
        } else if self.lhs.row == 1 && aligned(&[self.lhs.col, self.m]) {
            false
        } else {
            return None;
        };
        let b_along_n = if self.rhs.col == 1 && aligned(&[self.rhs.row, self.n]) {
            true
        } else if self.rhs.row == 1 && aligned(&[self.rhs.col]) {
            false
        } else {
            return None;
        };
        Some([
            ("A_ALONG_K", f64::from(u8::from(a_along_k))),
            ("B_ALONG_N", f64::from(u8::from(b_along_n))),
        ])
    }

    fn dispatch(
        self,
        gpu: &Gpu,
        lhs: &Tensor,
        rhs: &Tensor,
        out: &Tensor,
        accumulate: bool,
    ) -> Result<Dispatch, GpuError> {
        for t in [lhs, rhs] {
            if t.buffer() == out.buffer() {
                return Err(GpuError::Shape {
                    tensor: out.name().to_string(),
                    expected: format!("a buffer distinct from input {}", t.name()),
                    got: "the same buffer".to_string(),
                });
            }
        }
        let (out_batches, reduce) = if self.out_shared {
            (1, self.batch)
        } else {
            (self.batch, 1)
        };
        let (lb, lr) = if self.out_shared {
            (0, self.lhs.batch)
        } else {
            (self.lhs.batch, 0)
        };
        let (rb, rr) = if self.out_shared {
            (0, self.rhs.batch)
        } else {
            (self.rhs.batch, 0)
        };
        let params = Params {
            m: self.m as u32,
            n: self.n as u32,
            k: self.k as u32,
            reduce: reduce as u32,
            a_row: self.lhs.row as u32,
            a_col: self.lhs.col as u32,
            b_row: self.rhs.row as u32,
            b_col: self.rhs.col as u32,
            a_batch: lb as u32,
            b_batch: rb as u32,
            c_batch: (self.m * self.n) as u32,
            accumulate: accumulate as u32,
            a_reduce: lr as u32,
            b_reduce: rr as u32,
            alpha: 1.0,
            _pad: 0,
        };
        let tile = BLOCK * WORKGROUP;
        let groups = [
            self.n.div_ceil(tile).max(1) as u32,
            self.m.div_ceil(tile).max(1) as u32,
            out_batches as u32,
        ];
        match self.vec4() {
            Some(constants) => {
                gpu.dispatch(&KERNEL_VEC4, &constants, &params, &[lhs, rhs, out], groups)
            }
            None => gpu.dispatch(&KERNEL, &[], &params, &[lhs, rhs, out], groups),
        }
    }
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

    fn b_at(mm: &Matmul, b: &[f64], z: usize, kk: usize, j: usize) -> f64 {
        let base = if mm.shared_b { 0 } else { z * mm.k * mm.n };
        if mm.trans_b {
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
