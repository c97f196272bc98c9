// Batched matrix multiply, the workhorse of every layer (Rust side: src/ops/matmul.rs).
//
//   C[z] = alpha * sum_r op(A)[z, r] . op(B)[z, r]   (+ bias) (+ C[z] when accumulate = 1)
//   then optionally C[z] = max(0, C[z])
//
// Operands are strided views, so one kernel covers every transpose: element (i, kk) of
// op(A) is a[z*a_batch + r*a_reduce + i*a_row + kk*a_col], element (kk, j) of op(B) is
// b[z*b_batch + r*b_reduce + kk*b_row + j*b_col]; C is contiguous [M, N] per batch.
// The backward pass is this kernel again on transposed views (see ops/matmul.rs), and
// `reduce` sums over a batch axis when a shared operand's gradient is wanted.
//
// Each invocation of `matmul` computes a 4x4 block of C in registers (register blocking
// is what pays on lavapipe, shared-memory tiling buys nothing there); `matmul_row`, for
// products with a single output row (the host turns a single column into one), computes
// four outputs of that row. Loads: an operand contiguous along one axis whose strides are
// multiples of 4 is read four floats at a time (override constants below, chosen per
// operand by ops/matmul.rs), any other through scalar loads; a K that is not a multiple
// of 4 ends in a scalar tail.

struct MatmulParams {
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

@group(0) @binding(0) var<uniform> p: MatmulParams;
@group(0) @binding(1) var<storage, read> a: array<f32>;
@group(0) @binding(2) var<storage, read> b: array<f32>;
@group(0) @binding(3) var<storage, read_write> c: array<f32>;
// The same buffers as `a` and `b`, seen as vectors.
@group(0) @binding(4) var<storage, read> a4: array<vec4<f32>>;
@group(0) @binding(5) var<storage, read> b4: array<vec4<f32>>;
// A bias added to every output (any read-only buffer when BIAS = 0).
@group(0) @binding(6) var<storage, read> bias: array<f32>;

// 0: no bias; 1: bias[i] added to row i of C; 2: bias[j] added to column j.
override BIAS: u32 = 0u;
// max(0, .) of the final value (after the bias and the accumulation).
override RELU: bool = false;

// op(A) is read as vectors, along k (A stored untransposed) or else along m.
override A_VEC: bool = false;
override A_ALONG_K: bool = true;
// op(B) is read as vectors, along n (B stored untransposed) or else along k.
override B_VEC: bool = false;
override B_ALONG_N: bool = true;

// Four consecutive k of one row of op(A), starting at flat offset `o`.
fn a_k4(o: u32) -> vec4<f32> {
    let s = p.a_col;
    return vec4<f32>(a[o], a[o + s], a[o + 2u * s], a[o + 3u * s]);
}

// Four columns (flat offsets `cols`) of one row of op(B) at flat offset `o`.
fn b_n4(o: u32, cols: vec4<u32>) -> vec4<f32> {
    return vec4<f32>(b[o + cols.x], b[o + cols.y], b[o + cols.z], b[o + cols.w]);
}

// The 4x4 block of op(A) at k = kk..kk+3: column i holds row i of the block (over k).
// `ra` are the clamped row offsets, `row0` the first row (used unclamped only along m,
// which the host allows only when m is a multiple of 4).
fn a_block(abase: u32, kk: u32, row0: u32, ra: vec4<u32>) -> mat4x4<f32> {
    if A_VEC && A_ALONG_K {
        let o = abase + kk;
        return mat4x4<f32>(a4[(o + ra.x) >> 2u], a4[(o + ra.y) >> 2u], a4[(o + ra.z) >> 2u], a4[(o + ra.w) >> 2u]);
    }
    if A_VEC {
        let o = abase + kk * p.a_col + row0;
        let s = p.a_col;
        return transpose(mat4x4<f32>(a4[o >> 2u], a4[(o + s) >> 2u], a4[(o + 2u * s) >> 2u], a4[(o + 3u * s) >> 2u]));
    }
    let o = abase + kk * p.a_col;
    return mat4x4<f32>(a_k4(o + ra.x), a_k4(o + ra.y), a_k4(o + ra.z), a_k4(o + ra.w));
}

// The 4x4 block of op(B) at k = kk..kk+3: column i holds row kk+i of the block (over n).
fn b_block(bbase: u32, kk: u32, col0: u32, cb: vec4<u32>) -> mat4x4<f32> {
    let s = p.b_row;
    if B_VEC && B_ALONG_N {
        let o = bbase + kk * s + col0;
        return mat4x4<f32>(b4[o >> 2u], b4[(o + s) >> 2u], b4[(o + 2u * s) >> 2u], b4[(o + 3u * s) >> 2u]);
    }
    if B_VEC {
        let o = bbase + kk;
        return transpose(mat4x4<f32>(b4[(o + cb.x) >> 2u], b4[(o + cb.y) >> 2u], b4[(o + cb.z) >> 2u], b4[(o + cb.w) >> 2u]));
    }
    let o = bbase + kk * s;
    return mat4x4<f32>(b_n4(o, cb), b_n4(o + s, cb), b_n4(o + 2u * s, cb), b_n4(o + 3u * s, cb));
}

fn store_row(row: u32, col0: u32, base: u32, v: vec4<f32>) {
    if row >= p.m {
        return;
    }
    let o = base + row * p.n + col0;
    for (var j = 0u; j < 4u; j++) {
        if col0 + j < p.n {
            var x = p.alpha * v[j];
            if BIAS == 1u {
                x += bias[row];
            } else if BIAS == 2u {
                x += bias[col0 + j];
            }
            if p.accumulate != 0u {
                x += c[o + j];
            }
            if RELU {
                x = relu(x);
            }
            c[o + j] = x;
        }
    }
}

// Offsets of the four rows of op(A) (times a_row) and the four columns of op(B) (times
// b_col) of this invocation's block. Rows/columns past the edge are clamped so every load
// stays in bounds; their results are computed but never stored, which keeps the inner
// loops branch-free.
fn row_offsets(row0: u32) -> vec4<u32> {
    let ml = p.m - 1u;
    return vec4<u32>(min(row0, ml), min(row0 + 1u, ml), min(row0 + 2u, ml), min(row0 + 3u, ml)) * p.a_row;
}

fn col_offsets(col0: u32) -> vec4<u32> {
    let nl = p.n - 1u;
    return vec4<u32>(min(col0, nl), min(col0 + 1u, nl), min(col0 + 2u, nl), min(col0 + 3u, nl)) * p.b_col;
}

// Workgroup shape: 8x8 (32x32 outputs) in general, 64x1 (4 rows of 256 outputs) when M is
// small, so that few invocations of a workgroup fall past the last row.
override GROUP_X: u32 = 8u;
override GROUP_Y: u32 = 8u;

@compute @workgroup_size(GROUP_X, GROUP_Y, 1)
fn matmul(@builtin(global_invocation_id) gid: vec3<u32>) {
    let row0 = gid.y * 4u;
    let col0 = gid.x * 4u;
    if row0 >= p.m || col0 >= p.n {
        return;
    }
    let z = gid.z;
    let ra = row_offsets(row0);
    let cb = col_offsets(col0);
    var acc0 = vec4<f32>(0.0);
    var acc1 = vec4<f32>(0.0);
    var acc2 = vec4<f32>(0.0);
    var acc3 = vec4<f32>(0.0);
    let k4 = p.k & ~3u;
    for (var r = 0u; r < p.reduce; r++) {
        let abase = z * p.a_batch + r * p.a_reduce;
        let bbase = z * p.b_batch + r * p.b_reduce;
        var kk = 0u;
        for (; kk < k4; kk += 4u) {
            let x = a_block(abase, kk, row0, ra);
            let y = b_block(bbase, kk, col0, cb);
            acc0 += y * x[0];
            acc1 += y * x[1];
            acc2 += y * x[2];
            acc3 += y * x[3];
        }
        for (; kk < p.k; kk++) {
            let ak = abase + kk * p.a_col;
            let bv = b_n4(bbase + kk * p.b_row, cb);
            acc0 += a[ak + ra.x] * bv;
            acc1 += a[ak + ra.y] * bv;
            acc2 += a[ak + ra.z] * bv;
            acc3 += a[ak + ra.w] * bv;
        }
    }
    let cbase = z * p.c_batch;
    store_row(row0, col0, cbase, acc0);
    store_row(row0 + 1u, col0, cbase, acc1);
    store_row(row0 + 2u, col0, cbase, acc2);
    store_row(row0 + 3u, col0, cbase, acc3);
}

// m = 1: four columns of the single row per invocation, 64 invocations per workgroup.
@compute @workgroup_size(64, 1, 1)
fn matmul_row(@builtin(global_invocation_id) gid: vec3<u32>) {
    let col0 = gid.x * 4u;
    if col0 >= p.n {
        return;
    }
    let z = gid.z;
    let cb = col_offsets(col0);
    var acc = vec4<f32>(0.0);
    let k4 = p.k & ~3u;
    for (var r = 0u; r < p.reduce; r++) {
        let abase = z * p.a_batch + r * p.a_reduce;
        let bbase = z * p.b_batch + r * p.b_reduce;
        var kk = 0u;
        for (; kk < k4; kk += 4u) {
            var x: vec4<f32>;
            if A_VEC {
                x = a4[(abase + kk) >> 2u];
            } else {
                x = a_k4(abase + kk * p.a_col);
            }
            acc += b_block(bbase, kk, col0, cb) * x;
        }
        for (; kk < p.k; kk++) {
            acc += a[abase + kk * p.a_col] * b_n4(bbase + kk * p.b_row, cb);
        }
    }
    store_row(0u, col0, z * p.c_batch, acc);
}
