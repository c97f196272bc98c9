// The matmul with operand loads shared across a subgroup's lanes (Rust side:
// src/ops/matmul/), for devices whose subgroups have 8 lanes (lavapipe on 256-bit
// vectors). Compiled after matmul.wgsl: same parameters, bindings, load modes and
// epilogue, and the same terms added in the same order as its `matmul` (the compiler's
// multiply-add fusion may still differ, so the last bits can).
//
// Why: lavapipe (Mesa 22.3) turns each lane's storage load inside a loop into a per-lane,
// per-component sequence with a bounds check and a branch, some eight instructions per
// float per lane, so the 8x8 block kernel spends about eight times as long loading as
// multiplying. Here the 8 lanes of a subgroup compute a 32x16 tile of C: each lane owns
// 4 rows x 16 columns (64 accumulators, as in the block kernel) and loads its own 4 rows
// of op(A), while op(B)'s 16 columns are loaded once for the whole subgroup, two vectors
// per lane per 4 k, and handed to every lane by subgroupBroadcast (a register shuffle).
// Six vector loads per lane per 4 k instead of sixteen: 1.5-2.4x the block kernel on
// the model's products. `matmul_subgroup_cols` (at the end) splits by column instead,
// for products of at most 16 rows.

// Subgroups per workgroup, one 32-row tile each, stacked along the rows of C.
override SG_TILES: u32 = 2u;

@compute @workgroup_size(8u * SG_TILES, 1, 1)
fn matmul_subgroup(@builtin(workgroup_id) wid: vec3<u32>, @builtin(subgroup_id) sg: u32,
                   @builtin(subgroup_invocation_id) lane: u32) {
    // x runs over (batch item, block of 16 columns) pairs, y over groups of tiles.
    let col_blocks = (p.n + 15u) / 16u;
    let z = wid.x / col_blocks;
    let col0 = (wid.x - z * col_blocks) * 16u;
    let tile = wid.y * SG_TILES + sg;
    // The same on every lane of the subgroup: it leaves as a whole.
    if z >= p.batches || tile * 32u >= p.m {
        return;
    }
    let row0 = tile * 32u + lane * 4u;
    let rows = clamp4(row0, p.m);
    var r0 = 0u;
    if A_VEC && !A_ALONG_K {
        r0 = vec_start(row0, p.m);
    }
    // This lane's share of op(B) in each step of 4 k. Along n (and through scalar loads):
    // rows kk + lane/4 and kk + 2 + lane/4 over the columns col0 + 4 (lane % 4) + 0..3.
    // Along k: columns col0 + lane and col0 + 8 + lane over kk..kk+3.
    let kq = lane >> 2u;
    let cq = col0 + 4u * (lane & 3u);
    let cols_q = clamp4(cq, p.n) * p.b_col;
    var c_vec = 0u;
    if B_VEC && B_ALONG_N {
        c_vec = vec_start(cq, p.n);
    }
    let col_k0 = min(col0 + lane, p.n - 1u) * p.b_col;
    let col_k1 = min(col0 + 8u + lane, p.n - 1u) * p.b_col;
    // acc_<g>: columns col0 + 4g .. +3; column i of each is row row0 + i.
    var acc_0 = mat4x4<f32>();
    var acc_1 = mat4x4<f32>();
    var acc_2 = mat4x4<f32>();
    var acc_3 = mat4x4<f32>();
    let k4 = p.k & ~3u;
    let rr = reduce_range(z);
    let item = operand_item(z);
    for (var r = rr.x; r < rr.y; r++) {
        let off = reduce_offsets(r);
        let abase = item * p.a_batch + off.x;
        let bbase = item * p.b_batch + off.y;
        var kk = 0u;
        for (; kk < k4; kk += 4u) {
            let x = a_rows(abase, kk, r0, rows);
            if B_VEC && !B_ALONG_N {
                // Column j of the tile: q0 of lane j (j < 8), q1 of lane j - 8.
                let q0 = b4[(bbase + kk + col_k0) >> 2u];
                let q1 = b4[(bbase + kk + col_k1) >> 2u];
                acc_0 += transpose(mat4x4<f32>(subgroupBroadcast(q0, 0u), subgroupBroadcast(q0, 1u),
                                               subgroupBroadcast(q0, 2u), subgroupBroadcast(q0, 3u))) * x;
                acc_1 += transpose(mat4x4<f32>(subgroupBroadcast(q0, 4u), subgroupBroadcast(q0, 5u),
                                               subgroupBroadcast(q0, 6u), subgroupBroadcast(q0, 7u))) * x;
                acc_2 += transpose(mat4x4<f32>(subgroupBroadcast(q1, 0u), subgroupBroadcast(q1, 1u),
                                               subgroupBroadcast(q1, 2u), subgroupBroadcast(q1, 3u))) * x;
                acc_3 += transpose(mat4x4<f32>(subgroupBroadcast(q1, 4u), subgroupBroadcast(q1, 5u),
                                               subgroupBroadcast(q1, 6u), subgroupBroadcast(q1, 7u))) * x;
            } else {
                // Row kk + i, columns 4g..4g+3 of the tile: lane g + 4 (i % 2), vector i / 2.
                let o0 = bbase + (kk + kq) * p.b_row;
                let o1 = o0 + 2u * p.b_row;
                var q0: vec4<f32>;
                var q1: vec4<f32>;
                if B_VEC {
                    q0 = b4[(o0 + c_vec) >> 2u];
                    q1 = b4[(o1 + c_vec) >> 2u];
                } else {
                    q0 = b_n4(o0, cols_q);
                    q1 = b_n4(o1, cols_q);
                }
                acc_0 += mat4x4<f32>(subgroupBroadcast(q0, 0u), subgroupBroadcast(q0, 4u),
                                     subgroupBroadcast(q1, 0u), subgroupBroadcast(q1, 4u)) * x;
                acc_1 += mat4x4<f32>(subgroupBroadcast(q0, 1u), subgroupBroadcast(q0, 5u),
                                     subgroupBroadcast(q1, 1u), subgroupBroadcast(q1, 5u)) * x;
                acc_2 += mat4x4<f32>(subgroupBroadcast(q0, 2u), subgroupBroadcast(q0, 6u),
                                     subgroupBroadcast(q1, 2u), subgroupBroadcast(q1, 6u)) * x;
                acc_3 += mat4x4<f32>(subgroupBroadcast(q0, 3u), subgroupBroadcast(q0, 7u),
                                     subgroupBroadcast(q1, 3u), subgroupBroadcast(q1, 7u)) * x;
            }
        }
        // A ragged K ends in scalar steps, each lane loading all 16 columns itself.
        for (; kk < p.k; kk++) {
            let x = a_m4(abase + kk * p.a_col, rows * p.a_row);
            let bk = bbase + kk * p.b_row;
            acc_0 += outer4(b_n4(bk, clamp4(col0, p.n) * p.b_col), x);
            acc_1 += outer4(b_n4(bk, clamp4(col0 + 4u, p.n) * p.b_col), x);
            acc_2 += outer4(b_n4(bk, clamp4(col0 + 8u, p.n) * p.b_col), x);
            acc_3 += outer4(b_n4(bk, clamp4(col0 + 12u, p.n) * p.b_col), x);
        }
    }
    store_quarter(z, row0, col0, acc_0);
    store_quarter(z, row0, col0 + 4u, acc_1);
    store_quarter(z, row0, col0 + 8u, acc_2);
    store_quarter(z, row0, col0 + 12u, acc_3);
}

// Products of at most 16 rows (the graph mix Q·X_t over 14 nodes, and its input gradient
// Qᵀ·dM) would leave most of a 32-row tile idle. Here the lanes split the columns
// instead: each owns all 16 rows x 4 columns (64 accumulators) and loads its own columns
// of op(B), while op(A)'s 16 rows are loaded once per subgroup, two rows per lane, and
// broadcast.

// Subgroups per workgroup, one block of 32 columns each.
override SG_COL_TILES: u32 = 4u;

@compute @workgroup_size(8u * SG_COL_TILES, 1, 1)
fn matmul_subgroup_cols(@builtin(workgroup_id) wid: vec3<u32>, @builtin(subgroup_id) sg: u32,
                        @builtin(subgroup_invocation_id) lane: u32) {
    // Subgroups run over (batch item, block of 32 columns) pairs.
    let col_blocks = (p.n + 31u) / 32u;
    let flat = wid.x * SG_COL_TILES + sg;
    let z = flat / col_blocks;
    // The same on every lane of the subgroup: it leaves as a whole.
    if z >= p.batches {
        return;
    }
    let col0 = (flat - z * col_blocks) * 32u + 4u * lane;
    let cols = clamp4(col0, p.n);
    var c0 = 0u;
    if B_VEC && B_ALONG_N {
        c0 = vec_start(col0, p.n);
    }
    // This lane's rows of op(A): 2 lane and 2 lane + 1 (clamped), so that rows
    // 4g..4g+3 are held by lanes 2g and 2g + 1.
    let ra0 = min(2u * lane, p.m - 1u) * p.a_row;
    let ra1 = min(2u * lane + 1u, p.m - 1u) * p.a_row;
    // acc_<g>: column i is row 4g + i over this lane's four columns.
    var acc_0 = mat4x4<f32>();
    var acc_1 = mat4x4<f32>();
    var acc_2 = mat4x4<f32>();
    var acc_3 = mat4x4<f32>();
    let k4 = p.k & ~3u;
    let rr = reduce_range(z);
    let item = operand_item(z);
    for (var r = rr.x; r < rr.y; r++) {
        let off = reduce_offsets(r);
        let abase = item * p.a_batch + off.x;
        let bbase = item * p.b_batch + off.y;
        var kk = 0u;
        for (; kk < k4; kk += 4u) {
            let y = b_cols(bbase, kk, c0, cols);
            let x0 = a_row_k4(abase, kk, ra0);
            let x1 = a_row_k4(abase, kk, ra1);
            acc_0 += y * mat4x4<f32>(subgroupBroadcast(x0, 0u), subgroupBroadcast(x1, 0u),
                                     subgroupBroadcast(x0, 1u), subgroupBroadcast(x1, 1u));
            acc_1 += y * mat4x4<f32>(subgroupBroadcast(x0, 2u), subgroupBroadcast(x1, 2u),
                                     subgroupBroadcast(x0, 3u), subgroupBroadcast(x1, 3u));
            acc_2 += y * mat4x4<f32>(subgroupBroadcast(x0, 4u), subgroupBroadcast(x1, 4u),
                                     subgroupBroadcast(x0, 5u), subgroupBroadcast(x1, 5u));
            acc_3 += y * mat4x4<f32>(subgroupBroadcast(x0, 6u), subgroupBroadcast(x1, 6u),
                                     subgroupBroadcast(x0, 7u), subgroupBroadcast(x1, 7u));
        }
        for (; kk < p.k; kk++) {
            let y = b_n4(bbase + kk * p.b_row, cols * p.b_col);
            let ak = abase + kk * p.a_col;
            let x0 = a[ak + ra0];
            let x1 = a[ak + ra1];
            acc_0 += outer4(y, vec4<f32>(subgroupBroadcast(x0, 0u), subgroupBroadcast(x1, 0u),
                                         subgroupBroadcast(x0, 1u), subgroupBroadcast(x1, 1u)));
            acc_1 += outer4(y, vec4<f32>(subgroupBroadcast(x0, 2u), subgroupBroadcast(x1, 2u),
                                         subgroupBroadcast(x0, 3u), subgroupBroadcast(x1, 3u)));
            acc_2 += outer4(y, vec4<f32>(subgroupBroadcast(x0, 4u), subgroupBroadcast(x1, 4u),
                                         subgroupBroadcast(x0, 5u), subgroupBroadcast(x1, 5u)));
            acc_3 += outer4(y, vec4<f32>(subgroupBroadcast(x0, 6u), subgroupBroadcast(x1, 6u),
                                         subgroupBroadcast(x0, 7u), subgroupBroadcast(x1, 7u)));
        }
    }
    store_quarter(z, 0u, col0, acc_0);
    store_quarter(z, 4u, col0, acc_1);
    store_quarter(z, 8u, col0, acc_2);
    store_quarter(z, 12u, col0, acc_3);
}
