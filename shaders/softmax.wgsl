// Softmax along one axis of a tensor viewed as [outer, L, inner] (Rust side:
// src/ops/softmax.rs). The attention of docs/model.md normalises E[b, t, t'] over t (L = T,
// inner = T) and S[b, i, j] over j (L = N, inner = 1). One invocation per (outer, inner)
// line; the maximum is subtracted before exp, so large scores never overflow.

struct SmParams {
    outer: u32,
    len: u32,
    inner: u32,
    accumulate: u32,
}

const SM_WG: u32 = 256u;

@group(0) @binding(0) var<uniform> p: SmParams;
@group(0) @binding(1) var<storage, read> x: array<f32>;
@group(0) @binding(2) var<storage, read_write> y: array<f32>;

// First element of line `line` (= o·inner + i); the axis stride is `inner`.
fn line_base(line: u32) -> u32 {
    let o = line / p.inner;
    let i = line - o * p.inner;
    return o * p.len * p.inner + i;
}

@compute @workgroup_size(256)
fn softmax_forward(@builtin(workgroup_id) wg: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
                   @builtin(local_invocation_index) li: u32) {
    let line = flat_index(wg, nwg, li, SM_WG);
    if line >= p.outer * p.inner {
        return;
    }
    let base = line_base(line);
    var m = x[base];
    for (var l = 1u; l < p.len; l++) {
        m = max(m, x[base + l * p.inner]);
    }
    var s = 0.0;
    for (var l = 0u; l < p.len; l++) {
        s += exp(x[base + l * p.inner] - m);
    }
    let inv = 1.0 / s;
    for (var l = 0u; l < p.len; l++) {
        let k = base + l * p.inner;
        y[k] = exp(x[k] - m) * inv;
    }
}

// dx = y ⊙ (dy − Σ_l dy·y) along the line.
@group(0) @binding(1) var<storage, read> by: array<f32>;
@group(0) @binding(2) var<storage, read> bdy: array<f32>;
@group(0) @binding(3) var<storage, read_write> dx: array<f32>;

@compute @workgroup_size(256)
fn softmax_backward(@builtin(workgroup_id) wg: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
                    @builtin(local_invocation_index) li: u32) {
    let line = flat_index(wg, nwg, li, SM_WG);
    if line >= p.outer * p.inner {
        return;
    }
    let base = line_base(line);
    var s = 0.0;
    for (var l = 0u; l < p.len; l++) {
        let k = base + l * p.inner;
        s += bdy[k] * by[k];
    }
    for (var l = 0u; l < p.len; l++) {
        let k = base + l * p.inner;
        let v = by[k] * (bdy[k] - s);
        if p.accumulate != 0u {
            dx[k] = dx[k] + v;
        } else {
            dx[k] = v;
        }
    }
}
