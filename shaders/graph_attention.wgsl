// Multi-head graph attention over the nodes of every (window, step) (Rust side:
// src/model/block/graph_attention/kernel.rs). q is [B, N, C, T]; head h owns the channels
// h·C/H .. (h+1)·C/H. For node i, its neighbour j (mask[i, j] = 1, self loops included):
//   e_ij = LeakyReLU(a_src·q_i + a_dst·q_j)      over the head's channels at step t
//   α_ij = softmax_j(e_ij) over the neighbours   (0 elsewhere), stored [B, T, H, N, N]
//   out_i = Σ_j α_ij q_j                          channel by channel
// The backward kernels: d_score (∂ℒ/∂ of the pre-LeakyReLU score, [B, T, H, N, N]), then
// ∂ℒ/∂q through both the values and the scores, then ∂ℒ/∂a_src and ∂ℒ/∂a_dst.

struct GatParams {
    batch: u32,
    nodes: u32,
    channels: u32,
    steps: u32,
    heads: u32,
    accumulate: u32,
    slope: f32,
    _pad: u32,
}

const GAT_WG: u32 = 64u;
const GAT_REDUCE_WG: u32 = 256u;

@group(0) @binding(0) var<uniform> p: GatParams;

@group(0) @binding(1) var<storage, read> q: array<f32>;
@group(0) @binding(2) var<storage, read> a_src: array<f32>;
@group(0) @binding(3) var<storage, read> a_dst: array<f32>;
@group(0) @binding(4) var<storage, read> mask: array<f32>;
@group(0) @binding(5) var<storage, read_write> alpha: array<f32>;

fn q_at(b: u32, n: u32, c: u32, t: u32) -> u32 {
    return ((b * p.nodes + n) * p.channels + c) * p.steps + t;
}

// a·q_n over head h's channels at (b, t).
fn head_dot(a_is_src: bool, b: u32, n: u32, h: u32, t: u32) -> f32 {
    let width = p.channels / p.heads;
    var s = 0.0;
    for (var k = 0u; k < width; k++) {
        let c = h * width + k;
        let a = select(a_dst[c], a_src[c], a_is_src);
        s += a * q[q_at(b, n, c, t)];
    }
    return s;
}

// (b, t, h, i) of row `id` of α [B, T, H, N, N] (one thread per row).
fn alpha_row(id: u32) -> vec4<u32> {
    let n = p.nodes;
    return vec4<u32>(id / (n * p.heads * p.steps), (id / (n * p.heads)) % p.steps,
                     (id / n) % p.heads, id % n);
}

// (b, n, c, t) of element `id` of q [B, N, C, T].
fn value_at(id: u32) -> vec4<u32> {
    return vec4<u32>(id / (p.steps * p.channels * p.nodes), (id / (p.steps * p.channels)) % p.nodes,
                     (id / p.steps) % p.channels, id % p.steps);
}

fn leaky(x: f32) -> f32 {
    return select(p.slope * x, x, x > 0.0);
}

// One thread per (b, t, h, i): row i of α.
@compute @workgroup_size(64)
fn gat_weights(@builtin(workgroup_id) wg: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
               @builtin(local_invocation_index) li: u32) {
    let id = flat_index(wg, nwg, li, GAT_WG);
    let n = p.nodes;
    if id >= p.batch * p.steps * p.heads * n {
        return;
    }
    let at = alpha_row(id);
    let b = at.x;
    let t = at.y;
    let h = at.z;
    let i = at.w;
    let row = id * n;
    let s = head_dot(true, b, i, h, t);
    var m = -3.0e38;
    for (var j = 0u; j < n; j++) {
        if mask[i * n + j] > 0.5 {
            let e = leaky(s + head_dot(false, b, j, h, t));
            alpha[row + j] = e;
            m = max(m, e);
        }
    }
    var z = 0.0;
    for (var j = 0u; j < n; j++) {
        if mask[i * n + j] > 0.5 {
            let w = exp(alpha[row + j] - m);
            alpha[row + j] = w;
            z += w;
        }
    }
    for (var j = 0u; j < n; j++) {
        alpha[row + j] = select(0.0, alpha[row + j] / z, mask[i * n + j] > 0.5);
    }
}

@group(0) @binding(5) var<storage, read> weights: array<f32>;
@group(0) @binding(6) var<storage, read_write> out: array<f32>;

// One thread per (b, i, c, t): out[b, i, c, t] (+)= Σ_j α[b, t, h(c), i, j] q[b, j, c, t].
@compute @workgroup_size(64)
fn gat_aggregate(@builtin(workgroup_id) wg: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
                 @builtin(local_invocation_index) li: u32) {
    let id = flat_index(wg, nwg, li, GAT_WG);
    let n = p.nodes;
    if id >= p.batch * n * p.channels * p.steps {
        return;
    }
    let at = value_at(id);
    let b = at.x;
    let i = at.y;
    let c = at.z;
    let t = at.w;
    let h = c / (p.channels / p.heads);
    let row = (((b * p.steps + t) * p.heads + h) * n + i) * n;
    var s = 0.0;
    for (var j = 0u; j < n; j++) {
        s += weights[row + j] * q[q_at(b, j, c, t)];
    }
    out[id] = select(0.0, out[id], p.accumulate == 1u) + s;
}

@group(0) @binding(6) var<storage, read> d_out: array<f32>;
@group(0) @binding(7) var<storage, read_write> d_score: array<f32>;

// One thread per (b, t, h, i): ∂ℒ/∂α_ij = Σ_c d_out[b, i, c, t] q[b, j, c, t] over the head's
// channels, through the softmax and the LeakyReLU into d_score (overwritten; 0 off the mask).
@compute @workgroup_size(64)
fn gat_backward_scores(@builtin(workgroup_id) wg: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
                       @builtin(local_invocation_index) li: u32) {
    let id = flat_index(wg, nwg, li, GAT_WG);
    let n = p.nodes;
    if id >= p.batch * p.steps * p.heads * n {
        return;
    }
    let at = alpha_row(id);
    let b = at.x;
    let t = at.y;
    let h = at.z;
    let i = at.w;
    let row = id * n;
    let width = p.channels / p.heads;
    // d_score first holds ∂ℒ/∂α, then the dot product is removed.
    var dot = 0.0;
    for (var j = 0u; j < n; j++) {
        var da = 0.0;
        if mask[i * n + j] > 0.5 {
            for (var k = 0u; k < width; k++) {
                let c = h * width + k;
                da += d_out[q_at(b, i, c, t)] * q[q_at(b, j, c, t)];
            }
        }
        d_score[row + j] = da;
        dot += weights[row + j] * da;
    }
    let s = head_dot(true, b, i, h, t);
    for (var j = 0u; j < n; j++) {
        var g = 0.0;
        if mask[i * n + j] > 0.5 {
            let e = s + head_dot(false, b, j, h, t);
            let de = weights[row + j] * (d_score[row + j] - dot);
            g = select(p.slope * de, de, e > 0.0);
        }
        d_score[row + j] = g;
    }
}

@group(0) @binding(7) var<storage, read> score_grad: array<f32>;
@group(0) @binding(8) var<storage, read_write> d_q: array<f32>;

// Σ_k d_score[b, t, h, j, k] (j as the source) and Σ_i d_score[b, t, h, i, j] (j as a
// neighbour).
fn score_sums(b: u32, t: u32, h: u32, j: u32) -> vec2<f32> {
    let n = p.nodes;
    let base = ((b * p.steps + t) * p.heads + h) * n * n;
    var as_src = 0.0;
    var as_dst = 0.0;
    for (var k = 0u; k < n; k++) {
        as_src += score_grad[base + j * n + k];
        as_dst += score_grad[base + k * n + j];
    }
    return vec2<f32>(as_src, as_dst);
}

// One thread per (b, j, c, t): ∂ℒ/∂q[b, j, c, t] (+)= Σ_i α_ij d_out_i + a_src[c]·Σ_k
// d_score_jk + a_dst[c]·Σ_i d_score_ij.
@compute @workgroup_size(64)
fn gat_backward_values(@builtin(workgroup_id) wg: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
                       @builtin(local_invocation_index) li: u32) {
    let id = flat_index(wg, nwg, li, GAT_WG);
    let n = p.nodes;
    if id >= p.batch * n * p.channels * p.steps {
        return;
    }
    let at = value_at(id);
    let b = at.x;
    let j = at.y;
    let c = at.z;
    let t = at.w;
    let h = c / (p.channels / p.heads);
    let base = ((b * p.steps + t) * p.heads + h) * n * n;
    var g = 0.0;
    for (var i = 0u; i < n; i++) {
        g += weights[base + i * n + j] * d_out[q_at(b, i, c, t)];
    }
    let sums = score_sums(b, t, h, j);
    g += a_src[c] * sums.x + a_dst[c] * sums.y;
    d_q[id] = select(0.0, d_q[id], p.accumulate == 1u) + g;
}

@group(0) @binding(8) var<storage, read_write> d_a: array<f32>;

var<workgroup> partial: array<f32, 256>;

// One workgroup per (channel c, source or neighbour): ∂ℒ/∂a_src[c] = Σ_{b,t,j} q[b, j, c, t]
// Σ_k d_score_jk, ∂ℒ/∂a_dst[c] = Σ_{b,t,j} q[b, j, c, t] Σ_i d_score_ij; d_a is
// [a_src; a_dst] `[2C]`. A fixed-order tree reduction (deterministic).
@compute @workgroup_size(256)
fn gat_backward_params(@builtin(workgroup_id) wg: vec3<u32>,
                       @builtin(local_invocation_index) li: u32) {
    let c = wg.x;
    let as_src = wg.y == 0u;
    let h = c / (p.channels / p.heads);
    let n = p.nodes;
    let items = p.batch * n * p.steps;
    var s = 0.0;
    for (var it = li; it < items; it += GAT_REDUCE_WG) {
        let t = it % p.steps;
        let j = (it / p.steps) % n;
        let b = it / (p.steps * n);
        let sums = score_sums(b, t, h, j);
        s += q[q_at(b, j, c, t)] * select(sums.y, sums.x, as_src);
    }
    partial[li] = s;
    workgroupBarrier();
    for (var width = GAT_REDUCE_WG / 2u; width > 0u; width /= 2u) {
        if li < width {
            partial[li] += partial[li + width];
        }
        workgroupBarrier();
    }
    if li == 0u {
        let k = select(p.channels + c, c, as_src);
        d_a[k] = select(0.0, d_a[k], p.accumulate == 1u) + partial[0];
    }
}
