// Two outer products per batch item, each with one shared factor (Rust side: src/ops/outer.rs):
//
//   out[z, i, j] (+)= u[i] * v[z, j] + w[z, i] * q[j]
//
// with u [rows] and q [cols] shared, v [items, cols] and w [items, rows] per item. This is
// the gradient reaching X_t through the spatial attention's two projections,
// rhs = W3·X_t and xw1 = X_t·W1 (u = W3, v = d rhs, w = d xw1, q = W1), in one pass over
// the output instead of two read-modify-write rank-1 products.
//
// One invocation per row (z, i), sweeping its columns four at a time when cols is a
// multiple of 4 (VEC, every row then starts on a 16-byte boundary), one at a time
// otherwise: no integer division inside the loop.

struct OuterParams {
    items: u32,
    rows: u32,
    cols: u32,
    accumulate: u32,
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

const OUTER_WG: u32 = 64u;

@compute @workgroup_size(64)
fn outer_pair(@builtin(workgroup_id) wg: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
              @builtin(local_invocation_index) li: u32) {
    let row = flat_index(wg, nwg, li, OUTER_WG);
    if row >= p.items * p.rows {
        return;
    }
    let z = row / p.rows;
    let a = u[row - z * p.rows];
    let s = w[row];
    let vo = z * p.cols;
    let o = row * p.cols;
    if VEC {
        for (var j = 0u; j < p.cols; j += 4u) {
            var x = a * v4[(vo + j) >> 2u] + s * q4[j >> 2u];
            if p.accumulate != 0u {
                x += out4[(o + j) >> 2u];
            }
            out4[(o + j) >> 2u] = x;
        }
        return;
    }
    for (var j = 0u; j < p.cols; j++) {
        var x = a * v[vo + j] + s * q[j];
        if p.accumulate != 0u {
            x += out[o + j];
        }
        out[o + j] = x;
    }
}
