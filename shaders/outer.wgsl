// Two outer products per batch item, each with one shared factor (Rust side: src/ops/outer.rs):
//
//   out[z, i, j] (+)= u[i] * v[z, j] + w[z, i] * q[j]                     (NODE_MATRIX off)
//   out[z, i, j] (+)= u[i] * v[z, j] + w[z % nodes] * q[z / nodes, i, j]  (NODE_MATRIX on)
//
// with u [rows] shared and v [items, cols] per item; then w [items, rows] and q [cols] shared,
// or w [nodes] shared and q [items / nodes, rows, cols]. The first form is the gradient
// reaching X_t through the spatial attention's projections rhs = W3·X_t and xw1 = X_t·W1
// (u = W3, v = d rhs, w = d xw1, q = W1); the second the gradient reaching X through the
// temporal attention's rhs = U3·X and xu1 = U1·X (u = U3, v = d rhs, w = U1, q = d xu1,
// items = B·N, nodes = N). One pass over the output instead of two read-modify-write rank-1
// products.
//
// One invocation per row (z, i), sweeping its columns four at a time when cols is a
// multiple of 4 (VEC, every row then starts on a 16-byte boundary), one at a time
// otherwise: no integer division inside the loop.

struct OuterParams {
    items: u32,
    rows: u32,
    cols: u32,
    accumulate: u32,
    nodes: u32,
    _pad0: u32,
    _pad1: u32,
    _pad2: u32,
}

@group(0) @binding(0) var<uniform> p: OuterParams;
@group(0) @binding(1) var<storage, read> u: array<f32>;
@group(0) @binding(2) var<storage, read> v: array<f32>;
@group(0) @binding(3) var<storage, read> w: array<f32>;
@group(0) @binding(4) var<storage, read> q: array<f32>;
@group(0) @binding(5) var<storage, read_write> out: array<f32>;
// `v`, `q` and `out` seen as vectors (VEC).
@group(0) @binding(6) var<storage, read> v4: array<vec4<f32>>;
@group(0) @binding(7) var<storage, read> q4: array<vec4<f32>>;
@group(0) @binding(8) var<storage, read_write> out4: array<vec4<f32>>;

override VEC: bool = false;
override NODE_MATRIX: bool = false;

const OUTER_WG: u32 = 64u;

@compute @workgroup_size(64)
fn outer_pair(@builtin(workgroup_id) wg: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
              @builtin(local_invocation_index) li: u32) {
    let row = flat_index(wg, nwg, li, OUTER_WG);
    if row >= p.items * p.rows {
        return;
    }
    let z = row / p.rows;
    let i = row - z * p.rows;
    let a = u[i];
    let vo = z * p.cols;
    let o = row * p.cols;
    // The second term's scalar and where its row of q starts.
    var s: f32;
    var qo = 0u;
    if NODE_MATRIX {
        let b = z / p.nodes;
        s = w[z - b * p.nodes];
        qo = (b * p.rows + i) * p.cols;
    } else {
        s = w[row];
    }
    if VEC {
        for (var j = 0u; j < p.cols; j += 4u) {
            var x = a * v4[(vo + j) >> 2u] + s * q4[(qo + j) >> 2u];
            if p.accumulate != 0u {
                x += out4[(o + j) >> 2u];
            }
            out4[(o + j) >> 2u] = x;
        }
        return;
    }
    for (var j = 0u; j < p.cols; j++) {
        var x = a * v[vo + j] + s * q[qo + j];
        if p.accumulate != 0u {
            x += out[o + j];
        }
        out[o + j] = x;
    }
}
