// Batched matrix multiply, the workhorse of every layer (Rust side: src/ops/matmul/).
//
//   C[z] = alpha * sum_r op(A)[z, r] . op(B)[z, r]   (+ bias) (+ C[z] when accumulate = 1)
//   then optionally C[z] = max(0, C[z]); with PLUS_I, one operand has an identity added
//   (op(A) or op(B) itself is added to the product)
//
// Operands are strided views, so one kernel covers every transpose: element (i, kk) of
// op(A) is a[z*a_batch + r*a_reduce + i*a_row + kk*a_col], element (kk, j) of op(B) is
// b[z*b_batch + r*b_reduce + kk*b_row + j*b_col] (with slices, r's item and slice
// offsets instead of r*a_reduce: `reduce_offsets`); C is contiguous [M, N] per batch.
// The backward pass is this kernel again on transposed views (see ops/matmul/), and
// `reduce` sums over a batch axis when a shared operand's gradient is wanted.
//
// Each invocation of `matmul` computes an 8x8 block of C in registers (register blocking
// is what pays on lavapipe, shared-memory tiling buys nothing there; 8x8 blocks reach 2x
// the GFLOP/s of 4x4 ones); `matmul_row`, for
// products with a single output row (the host turns a single column into one), computes
// four outputs of that row. Loads: an operand contiguous along one axis whose strides are
// multiples of 4 is read four floats at a time (override constants below, chosen per
// operand by ops/matmul/), any other through scalar loads; a K that is not a multiple
// of 4 ends in a scalar tail. Stores (with the epilogue) go four floats at a time when N
// is a multiple of 4 (C_VEC): 1.05-1.24x on the model's products, most on small K.

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
    // Batch items of C (the z extent; a workgroup may span several).
    batches: u32,
    // Split reduction: when nonzero, item z of C is the partial sum over reduction items
    // z*chunk .. (z+1)*chunk (see `sum_partials`).
    chunk: u32,
    // A reduction over batch items each cut into `slices` slices of k (a weight gradient
    // with a long k per item): reduction item r is slice r % slices of item r / slices,
    // the items a_reduce (b_reduce) apart and the slices a_slice (b_slice). 1 and 0
    // otherwise.
    slices: u32,
    a_slice: u32,
    b_slice: u32,
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
// With GATE: a tensor laid out like C (any read-only buffer otherwise).
@group(0) @binding(7) var<storage, read> gate_f: array<f32>;
// The same buffer as `c`, seen as vectors (stores with C_VEC).
@group(0) @binding(8) var<storage, read_write> c4: array<vec4<f32>>;

// 0: no bias; 1: bias[i] added to row i of C; 2: bias[j] added to column j; 3: a whole
// [M, N] matrix added to every batch item's C.
override BIAS: u32 = 0u;
// max(0, .) of the final value (after the bias and the accumulation).
override RELU: bool = false;
// N is a multiple of 4: each group of four outputs of a row is stored (and, when
// accumulating, read) as one vector, a quarter of the memory operations per lane.
override C_VEC: bool = false;
// The gated activation: C = tanh(gate_f) * sigmoid(C) elementwise (after the bias), the
// gate of the gated convolution fused into the gate product (gated_dcc.wgsl has it alone).
override GATE: bool = false;
// A sigmoid fused into a product (never with GATE or RELU): 1: C = sigmoid(C) (after the
// bias), an attention's scores; 2: C = C * s * (1 - s) with s = gate_f laid out like C
// (a sigmoid's output), the sigmoid's backward fused into the product of its output's
// gradient (elementwise.wgsl has both alone).
override SIGMOID: u32 = 0u;
// The product with an identity added to one operand, the identity's term added here:
// 1: C = op(A)·(op(B) + I), element (i, j) of op(A) added (k = n); 2: C = (op(A) + I)·op(B),
// element (i, j) of op(B) added (k = m). Never with a reduction over a batch axis.
override PLUS_I: u32 = 0u;

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

// Four consecutive k (kk..kk+3) of the row of op(A) at flat row offset `ra` (row x a_row):
// one vector when A is read along k, else four scalars.
fn a_row_k4(abase: u32, kk: u32, ra: u32) -> vec4<f32> {
    if A_VEC && A_ALONG_K {
        return a4[(abase + kk + ra) >> 2u];
    }
    return a_k4(abase + kk * p.a_col + ra);
}

// Four rows (flat offsets `rows`, row x a_row) of op(A) at one k, flat offset `o`.
fn a_m4(o: u32, rows: vec4<u32>) -> vec4<f32> {
    return vec4<f32>(a[o + rows.x], a[o + rows.y], a[o + rows.z], a[o + rows.w]);
}

// Four columns (flat offsets `cols`) of one row of op(B) at flat offset `o`.
fn b_n4(o: u32, cols: vec4<u32>) -> vec4<f32> {
    return vec4<f32>(b[o + cols.x], b[o + cols.y], b[o + cols.z], b[o + cols.w]);
}

// Rows of op(A) for k = kk..kk+3, four at a time: column i of the result holds row
// `rows[i]` (over k). `rows` are clamped row indices; `row0` (a multiple of 4, used only
// along m, which the host allows only when m is a multiple of 4) is the first of them.
fn a_rows(abase: u32, kk: u32, row0: u32, rows: vec4<u32>) -> mat4x4<f32> {
    if A_VEC && !A_ALONG_K {
        let o = abase + kk * p.a_col + row0;
        let s = p.a_col;
        return transpose(mat4x4<f32>(a4[o >> 2u], a4[(o + s) >> 2u], a4[(o + 2u * s) >> 2u], a4[(o + 3u * s) >> 2u]));
    }
    let ra = rows * p.a_row;
    return mat4x4<f32>(a_row_k4(abase, kk, ra.x), a_row_k4(abase, kk, ra.y),
                       a_row_k4(abase, kk, ra.z), a_row_k4(abase, kk, ra.w));
}

// Four columns of op(B) for k = kk..kk+3: column i of the result holds row kk+i (over
// the columns `cols`, clamped indices; `col0` their first, used along n, which the host
// allows only when n is a multiple of 4).
fn b_cols(bbase: u32, kk: u32, col0: u32, cols: vec4<u32>) -> mat4x4<f32> {
    let s = p.b_row;
    let cb = cols * p.b_col;
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

// Element (row, col) of the operand PLUS_I adds, for batch item z.
fn plus_at(z: u32, row: u32, col: u32) -> f32 {
    if PLUS_I == 1u {
        return a[z * p.a_batch + row * p.a_row + col * p.a_col];
    }
    return b[z * p.b_batch + row * p.b_row + col * p.b_col];
}

// Elements (row, col0..col0+3) of that operand, all of which exist (C_VEC).
fn plus4(z: u32, row: u32, col0: u32) -> vec4<f32> {
    if PLUS_I == 1u && A_VEC && A_ALONG_K {
        return a4[(z * p.a_batch + row * p.a_row + col0) >> 2u];
    }
    if PLUS_I == 2u && B_VEC && B_ALONG_N {
        return b4[(z * p.b_batch + row * p.b_row + col0) >> 2u];
    }
    return vec4<f32>(plus_at(z, row, col0), plus_at(z, row, col0 + 1u),
                     plus_at(z, row, col0 + 2u), plus_at(z, row, col0 + 3u));
}

fn store_row(z: u32, row: u32, col0: u32, v: vec4<f32>) {
    if row >= p.m {
        return;
    }
    let o = z * p.c_batch + row * p.n + col0;
    if C_VEC {
        // All four columns exist or none does (n and col0 are multiples of 4).
        if col0 >= p.n {
            return;
        }
        var x = p.alpha * v;
        if PLUS_I != 0u {
            x += p.alpha * plus4(z, row, col0);
        }
        if BIAS == 1u {
            x += vec4<f32>(bias[row]);
        } else if BIAS == 2u {
            x += vec4<f32>(bias[col0], bias[col0 + 1u], bias[col0 + 2u], bias[col0 + 3u]);
        } else if BIAS == 3u {
            let b = row * p.n + col0;
            x += vec4<f32>(bias[b], bias[b + 1u], bias[b + 2u], bias[b + 3u]);
        }
        if p.accumulate != 0u {
            x += c4[o >> 2u];
        }
        if GATE {
            let f = vec4<f32>(tanh_stable(gate_f[o]), tanh_stable(gate_f[o + 1u]),
                              tanh_stable(gate_f[o + 2u]), tanh_stable(gate_f[o + 3u]));
            x = f * vec4<f32>(sigmoid(x.x), sigmoid(x.y), sigmoid(x.z), sigmoid(x.w));
        }
        if SIGMOID == 1u {
            x = vec4<f32>(sigmoid(x.x), sigmoid(x.y), sigmoid(x.z), sigmoid(x.w));
        } else if SIGMOID == 2u {
            let s = vec4<f32>(gate_f[o], gate_f[o + 1u], gate_f[o + 2u], gate_f[o + 3u]);
            x = x * s * (1.0 - s);
        }
        if RELU {
            x = vec4<f32>(relu(x.x), relu(x.y), relu(x.z), relu(x.w));
        }
        c4[o >> 2u] = x;
        return;
    }
    for (var j = 0u; j < 4u; j++) {
        if col0 + j < p.n {
            var x = p.alpha * v[j];
            if PLUS_I != 0u {
                x += p.alpha * plus_at(z, row, col0 + j);
            }
            if BIAS == 1u {
                x += bias[row];
            } else if BIAS == 2u {
                x += bias[col0 + j];
            } else if BIAS == 3u {
                x += bias[row * p.n + col0 + j];
            }
            if p.accumulate != 0u {
                x += c[o + j];
            }
            if GATE {
                x = tanh_stable(gate_f[o + j]) * sigmoid(x);
            }
            if SIGMOID == 1u {
                x = sigmoid(x);
            } else if SIGMOID == 2u {
                let s = gate_f[o + j];
                x = x * s * (1.0 - s);
            }
            if RELU {
                x = relu(x);
            }
            c[o + j] = x;
        }
    }
}

// The product sums over a batch axis (`reduce` > 1, or a split's chunks). Without it the
// reduction loop has one constant trip, which the compiler removes: a loop around the k
// loop costs lavapipe up to 1.2x on the subgroup kernel.
override REDUCE: bool = true;

// A split reduction's chunks per batch item of the operands: item z of C is chunk
// z % chunks of operand item z / chunks (a weight gradient has one operand item, whose
// batch strides are 0; a product split along k within each item has one per item).
fn split_chunks() -> u32 {
    return (p.reduce + p.chunk - 1u) / p.chunk;
}

// The reduction items batch item `z` of C sums over: [x, y).
fn reduce_range(z: u32) -> vec2<u32> {
    if !REDUCE {
        return vec2<u32>(0u, 1u);
    }
    if p.chunk != 0u {
        let begin = (z % split_chunks()) * p.chunk;
        return vec2<u32>(begin, min(p.reduce, begin + p.chunk));
    }
    return vec2<u32>(0u, p.reduce);
}

// Where reduction item `r` starts in op(A) and op(B) (from their batch item's start).
fn reduce_offsets(r: u32) -> vec2<u32> {
    let item = r / p.slices;
    let slice = r - item * p.slices;
    return vec2<u32>(item * p.a_reduce + slice * p.a_slice, item * p.b_reduce + slice * p.b_slice);
}

// The batch item of the operands that batch item `z` of C reads.
fn operand_item(z: u32) -> u32 {
    if REDUCE && p.chunk != 0u {
        return z / split_chunks();
    }
    return z;
}

// Indices of four rows of op(A) (columns of op(B)) from `i0`, clamped to the last one so
// every load stays in bounds; results past the edge are computed but never stored, which
// keeps the inner loops branch-free.
fn clamp4(i0: u32, len: u32) -> vec4<u32> {
    return min(vec4<u32>(i0, i0 + 1u, i0 + 2u, i0 + 3u), vec4<u32>(len - 1u));
}

// The first of four consecutive rows (columns) read as one vector, moved back so that all
// four exist (the axis is a multiple of 4 when vectors are read along it).
fn vec_start(i0: u32, len: u32) -> u32 {
    return min(i0, len - 4u);
}

// Workgroup shape, chosen per product by ops/matmul/: 8x8x1 (64x64 outputs) in general,
// flatter when M is small, and spanning several batch items when each item's C is small.
override GROUP_X: u32 = 8u;
override GROUP_Y: u32 = 8u;
override GROUP_Z: u32 = 1u;
// The x axis of the grid runs over (batch item, block of 8 columns) pairs, so the eight
// SIMD lanes along x stay busy when a batch item's columns end mid-group (n = 100: 13
// blocks of 8 would fill 16 lanes, 19% idle).
override FLAT_X: bool = false;

// An 8x8 block of C per invocation: rows row0..row0+7 in two halves (lo, hi) of four, and
// columns col0..col0+7 in two halves (l, r). acc_<rows><cols>[i] is row i of that quarter.
@compute @workgroup_size(GROUP_X, GROUP_Y, GROUP_Z)
fn matmul(@builtin(global_invocation_id) gid: vec3<u32>) {
    var z = gid.z;
    var block = gid.x;
    if FLAT_X {
        let blocks = (p.n + 7u) / 8u;
        z = gid.x / blocks;
        block = gid.x - z * blocks;
    }
    let row0 = gid.y * 8u;
    let col0 = block * 8u;
    if row0 >= p.m || col0 >= p.n || z >= p.batches {
        return;
    }
    let rows_lo = clamp4(row0, p.m);
    let rows_hi = clamp4(row0 + 4u, p.m);
    let cols_l = clamp4(col0, p.n);
    let cols_r = clamp4(col0 + 4u, p.n);
    var r0 = 0u;
    var r1 = 0u;
    var c0 = 0u;
    var c1 = 0u;
    if A_VEC && !A_ALONG_K {
        r0 = vec_start(row0, p.m);
        r1 = vec_start(row0 + 4u, p.m);
    }
    if B_VEC && B_ALONG_N {
        c0 = vec_start(col0, p.n);
        c1 = vec_start(col0 + 4u, p.n);
    }
    var acc_lo_l = mat4x4<f32>();
    var acc_lo_r = mat4x4<f32>();
    var acc_hi_l = mat4x4<f32>();
    var acc_hi_r = mat4x4<f32>();
    let k4 = p.k & ~3u;
    let rr = reduce_range(z);
    let item = operand_item(z);
    for (var r = rr.x; r < rr.y; r++) {
        let off = reduce_offsets(r);
        let abase = item * p.a_batch + off.x;
        let bbase = item * p.b_batch + off.y;
        var kk = 0u;
        for (; kk < k4; kk += 4u) {
            let xl = a_rows(abase, kk, r0, rows_lo);
            let xh = a_rows(abase, kk, r1, rows_hi);
            let yl = b_cols(bbase, kk, c0, cols_l);
            let yr = b_cols(bbase, kk, c1, cols_r);
            acc_lo_l += yl * xl;
            acc_lo_r += yr * xl;
            acc_hi_l += yl * xh;
            acc_hi_r += yr * xh;
        }
        for (; kk < p.k; kk++) {
            let ak = abase + kk * p.a_col;
            let bk = bbase + kk * p.b_row;
            let bl = b_n4(bk, cols_l * p.b_col);
            let br = b_n4(bk, cols_r * p.b_col);
            let xl = a_m4(ak, rows_lo * p.a_row);
            let xh = a_m4(ak, rows_hi * p.a_row);
            acc_lo_l += outer4(bl, xl);
            acc_lo_r += outer4(br, xl);
            acc_hi_l += outer4(bl, xh);
            acc_hi_r += outer4(br, xh);
        }
    }
    // Constant indices only: a dynamically indexed matrix would live in memory.
    store_quarter(z, row0, col0, acc_lo_l);
    store_quarter(z, row0, col0 + 4u, acc_lo_r);
    store_quarter(z, row0 + 4u, col0, acc_hi_l);
    store_quarter(z, row0 + 4u, col0 + 4u, acc_hi_r);
}

fn store_quarter(z: u32, row: u32, col: u32, q: mat4x4<f32>) {
    store_row(z, row, col, q[0]);
    store_row(z, row + 1u, col, q[1]);
    store_row(z, row + 2u, col, q[2]);
    store_row(z, row + 3u, col, q[3]);
}

// The matrix whose column i is x[i] * y: one k step of a 4x4 quarter.
fn outer4(y: vec4<f32>, x: vec4<f32>) -> mat4x4<f32> {
    return mat4x4<f32>(x.x * y, x.y * y, x.z * y, x.w * y);
}

// The second launch of a split reduction: the `batches` partial results of each batch
// item of C, as a `matmul` launch with `chunk` set wrote them, summed in a fixed order
// (the result does not depend on the grid): c[i] (+)= sum over z of a[(item * batches +
// z) * m + j] for i = item * m + j, m the length of one item of C, n the length of C.
// SUM_LANES lanes (a power of two dividing 64) add each output's partial sums: lane l
// adds z = l, l + SUM_LANES, ... in order, then the lanes' sums are added in a fixed tree
// in workgroup memory (one lane adding all of them in order when SUM_LANES = 1). A
// workgroup holds 64 / SUM_LANES consecutive outputs, the lanes of one output that far
// apart so that neighbouring invocations read neighbouring outputs. A 1-D grid of
// workgroups folded into x and y.
override SUM_LANES: u32 = 1u;
const SUM_WG: u32 = 64u;
var<workgroup> lane_sums: array<f32, SUM_WG>;

@compute @workgroup_size(SUM_WG, 1, 1)
fn sum_partials(@builtin(workgroup_id) wg: vec3<u32>, @builtin(num_workgroups) groups: vec3<u32>,
                @builtin(local_invocation_index) li: u32) {
    let outputs = SUM_WG / SUM_LANES;
    let x = li % outputs;
    let lane = li / outputs;
    let i = (wg.y * groups.x + wg.x) * outputs + x;
    let live = i < p.n;
    var s = 0.0;
    if live {
        let item = i / p.m;
        let j = i - item * p.m;
        for (var z = lane; z < p.batches; z += SUM_LANES) {
            s += a[(item * p.batches + z) * p.m + j];
        }
    }
    if SUM_LANES > 1u {
        lane_sums[li] = s;
        workgroupBarrier();
        for (var half = SUM_LANES / 2u; half > 0u; half /= 2u) {
            if lane < half {
                lane_sums[li] += lane_sums[li + half * outputs];
            }
            workgroupBarrier();
        }
        s = lane_sums[x];
    }
    if !live || lane != 0u {
        return;
    }
    if p.accumulate != 0u {
        s += c[i];
    }
    c[i] = s;
}

// m = 1: four columns of the single row per invocation, 64 invocations per workgroup.
@compute @workgroup_size(64, 1, 1)
fn matmul_row(@builtin(global_invocation_id) gid: vec3<u32>) {
    let col0 = gid.x * 4u;
    if col0 >= p.n {
        return;
    }
    let z = gid.z;
    let cols = clamp4(col0, p.n);
    let cb = cols * p.b_col;
    var acc = vec4<f32>(0.0);
    let k4 = p.k & ~3u;
    let rr = reduce_range(z);
    let item = operand_item(z);
    for (var r = rr.x; r < rr.y; r++) {
        let off = reduce_offsets(r);
        let abase = item * p.a_batch + off.x;
        let bbase = item * p.b_batch + off.y;
        var kk = 0u;
        for (; kk < k4; kk += 4u) {
            // One row: A is only ever read as vectors along k here.
            acc += b_cols(bbase, kk, col0, cols) * a_row_k4(abase, kk, 0u);
        }
        for (; kk < p.k; kk++) {
            acc += a[abase + kk * p.a_col] * b_n4(bbase + kk * p.b_row, cb);
        }
    }
    store_row(z, 0u, col0, acc);
}
