// Batched matrix multiply, the workhorse of every layer (Rust side: src/ops/matmul.rs).
//
//   C[z] = alpha * sum_r op(A)[z, r] . op(B)[z, r]   (+ C[z] when accumulate = 1)
//
// Operands are strided views, so one kernel covers every transpose: element (i, kk) of
// op(A) is a[z*a_batch + r*a_reduce + i*a_row + kk*a_col], element (kk, j) of op(B) is
// b[z*b_batch + r*b_reduce + kk*b_row + j*b_col]; C is contiguous [M, N] per batch.
// The backward pass is this kernel again on transposed views (see ops/matmul.rs), and
// `reduce` sums over a batch axis when a shared operand's gradient is wanted.
//
// Each invocation computes a 4x4 block of C in registers (register blocking is what pays
// on lavapipe, shared-memory tiling buys nothing there).

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

// Four consecutive k of one row of op(A), starting at flat offset `o`.
fn a_k4(o: u32) -> vec4<f32> {
    let s = p.a_col;
    return vec4<f32>(a[o], a[o + s], a[o + 2u * s], a[o + 3u * s]);
}

// Four columns (flat offsets `cols`) of one row of op(B) at flat offset `o`.
fn b_n4(o: u32, cols: vec4<u32>) -> vec4<f32> {
    return vec4<f32>(b[o + cols.x], b[o + cols.y], b[o + cols.z], b[o + cols.w]);
}

fn store_row(row: u32, col0: u32, base: u32, v: vec4<f32>) {
    if row >= p.m {
        return;
    }
    let o = base + row * p.n + col0;
    for (var j = 0u; j < 4u; j++) {
        if col0 + j < p.n {
            var x = p.alpha * v[j];
            if p.accumulate != 0u {
                x += c[o + j];
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

fn store_tile(row0: u32, col0: u32, z: u32, acc0: vec4<f32>, acc1: vec4<f32>, acc2: vec4<f32>, acc3: vec4<f32>) {
    let cbase = z * p.c_batch;
    store_row(row0, col0, cbase, acc0);
    store_row(row0 + 1u, col0, cbase, acc1);
    store_row(row0 + 2u, col0, cbase, acc2);
    store_row(row0 + 3u, col0, cbase, acc3);
}

@compute @workgroup_size(8, 8, 1)
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
            let ak = abase + kk * p.a_col;
            let a0 = a_k4(ak + ra.x);
            let a1 = a_k4(ak + ra.y);
            let a2 = a_k4(ak + ra.z);
            let a3 = a_k4(ak + ra.w);
            let bk = bbase + kk * p.b_row;
            let b0 = b_n4(bk, cb);
            let b1 = b_n4(bk + p.b_row, cb);
            let b2 = b_n4(bk + 2u * p.b_row, cb);
            let b3 = b_n4(bk + 3u * p.b_row, cb);
            acc0 += a0.x * b0 + a0.y * b1 + a0.z * b2 + a0.w * b3;
            acc1 += a1.x * b0 + a1.y * b1 + a1.z * b2 + a1.w * b3;
            acc2 += a2.x * b0 + a2.y * b1 + a2.z * b2 + a2.w * b3;
            acc3 += a3.x * b0 + a3.y * b1 + a3.z * b2 + a3.w * b3;
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
    store_tile(row0, col0, z, acc0, acc1, acc2, acc3);
}

// ---- vector-load variant ----------------------------------------------------------------
// Same contract, for operands whose contiguous axis, strides and K are multiples of 4:
// every load fetches four floats at once, which is what lavapipe (and real GPUs) reward.
// The override constants say along which axis each operand is contiguous; the host
// (ops/matmul.rs) picks this entry point only when the alignment holds.

@group(0) @binding(1) var<storage, read> a4: array<vec4<f32>>;
@group(0) @binding(2) var<storage, read> b4: array<vec4<f32>>;

// op(A) is contiguous along k (A stored untransposed); else along m.
override A_ALONG_K: bool = true;
// op(B) is contiguous along n (B stored untransposed); else along k.
override B_ALONG_N: bool = true;

@compute @workgroup_size(8, 8, 1)
fn matmul_vec4(@builtin(global_invocation_id) gid: vec3<u32>) {
    let row0 = gid.y * 4u;
    let col0 = gid.x * 4u;
    if row0 >= p.m || col0 >= p.n {
        return;
    }
    let z = gid.z;
    // Along a contiguous axis the four rows (columns) are loaded as one vector from
    // row0 (col0) instead: that axis is a multiple of 4, so they need no clamping.
    let ra = row_offsets(row0);
    let cb = col_offsets(col0);
    var acc0 = vec4<f32>(0.0);
    var acc1 = vec4<f32>(0.0);
    var acc2 = vec4<f32>(0.0);
    var acc3 = vec4<f32>(0.0);
    for (var r = 0u; r < p.reduce; r++) {
        let abase = z * p.a_batch + r * p.a_reduce;
        let bbase = z * p.b_batch + r * p.b_reduce;
        for (var kk = 0u; kk < p.k; kk += 4u) {
            // x0..x3: rows of the 4x4 block of op(A) (each over k).
            var x0: vec4<f32>;
            var x1: vec4<f32>;
            var x2: vec4<f32>;
            var x3: vec4<f32>;
            if A_ALONG_K {
                let o = abase + kk;
                x0 = a4[(o + ra.x) >> 2u];
                x1 = a4[(o + ra.y) >> 2u];
                x2 = a4[(o + ra.z) >> 2u];
                x3 = a4[(o + ra.w) >> 2u];
            } else {
                let o = abase + kk * p.a_col + row0;
                let c0 = a4[o >> 2u];
                let c1 = a4[(o + p.a_col) >> 2u];
                let c2 = a4[(o + 2u * p.a_col) >> 2u];
                let c3 = a4[(o + 3u * p.a_col) >> 2u];
                x0 = vec4<f32>(c0.x, c1.x, c2.x, c3.x);
                x1 = vec4<f32>(c0.y, c1.y, c2.y, c3.y);
                x2 = vec4<f32>(c0.z, c1.z, c2.z, c3.z);
                x3 = vec4<f32>(c0.w, c1.w, c2.w, c3.w);
            }
            // y0..y3: rows of the 4x4 block of op(B) (each over n).
            var y0: vec4<f32>;
            var y1: vec4<f32>;
            var y2: vec4<f32>;
            var y3: vec4<f32>;
            if B_ALONG_N {
                let o = bbase + kk * p.b_row + col0;
                y0 = b4[o >> 2u];
                y1 = b4[(o + p.b_row) >> 2u];
                y2 = b4[(o + 2u * p.b_row) >> 2u];
                y3 = b4[(o + 3u * p.b_row) >> 2u];
            } else {
                let o = bbase + kk;
                let w0 = b4[(o + cb.x) >> 2u];
                let w1 = b4[(o + cb.y) >> 2u];
                let w2 = b4[(o + cb.z) >> 2u];
                let w3 = b4[(o + cb.w) >> 2u];
                y0 = vec4<f32>(w0.x, w1.x, w2.x, w3.x);
                y1 = vec4<f32>(w0.y, w1.y, w2.y, w3.y);
                y2 = vec4<f32>(w0.z, w1.z, w2.z, w3.z);
                y3 = vec4<f32>(w0.w, w1.w, w2.w, w3.w);
            }
            acc0 += x0.x * y0 + x0.y * y1 + x0.z * y2 + x0.w * y3;
            acc1 += x1.x * y0 + x1.y * y1 + x1.z * y2 + x1.w * y3;
            acc2 += x2.x * y0 + x2.y * y1 + x2.z * y2 + x2.w * y3;
            acc3 += x3.x * y0 + x3.y * y1 + x3.z * y2 + x3.w * y3;
        }
    }
    store_tile(row0, col0, z, acc0, acc1, acc2, acc3);
}
