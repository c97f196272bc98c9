// LayerNorm over the channel axis of [B, N, C, T] activations (docs/model.md step 6), forward
// and backward (Rust side: src/model/block/residual_layer_norm/layer_norm_kernel.rs).
//
// Rows are (b·N + n, t) pairs: `outer` = B·N blocks of C·T elements, channel stride T.
// Forward saves each row's mean and 1/σ for the backward pass.
//
// With `drop`, the dropout that follows (step 7, dropout.wgsl's mask) is fused in: the
// forward writes the dropped output, and the backward reads its gradient through the
// same mask (element i keeps its bit of index i·drop_stride + drop_offset).

struct LnParams {
    outer: u32,
    channels: u32,
    steps: u32,
    accumulate: u32,
    eps: f32,
    // Backward input: x is a ReLU's output and the gradient wanted is its input's,
    // (x > 0)·dx.
    relu_input: u32,
    drop: u32,
    // lowbias32(seed ^ lowbias32(step)) of the training step (common.wgsl).
    drop_key: u32,
    drop_threshold: u32,
    drop_scale: f32,
    drop_stride: u32,
    drop_offset: u32,
    // The parameter gradients split along the outer axis: blocks per slice and number of
    // slices (the whole axis and 1 when unsplit).
    slice: u32,
    slices: u32,
    pad0: u32,
    pad1: u32,
}

const LN_WG: u32 = 256u;

@group(0) @binding(0) var<uniform> p: LnParams;
@group(0) @binding(1) var<storage, read> x: array<f32>;
@group(0) @binding(2) var<storage, read> gamma: array<f32>;
@group(0) @binding(3) var<storage, read> beta: array<f32>;
@group(0) @binding(4) var<storage, read_write> y: array<f32>;
@group(0) @binding(5) var<storage, read_write> mean: array<f32>;
@group(0) @binding(6) var<storage, read_write> rstd: array<f32>;

// Element i's value through the dropout: 0, or scaled by 1/(1 − p) (itself without it).
fn dropped(v: f32, i: u32) -> f32 {
    if p.drop == 0u {
        return v;
    }
    let kept = lowbias32((i * p.drop_stride + p.drop_offset) ^ p.drop_key) >= p.drop_threshold;
    return select(0.0, v * p.drop_scale, kept);
}

// The same for elements 4q .. 4q+3.
fn dropped4(v: vec4<f32>, q: u32) -> vec4<f32> {
    if p.drop == 0u {
        return v;
    }
    let i = 4u * q;
    return vec4<f32>(dropped(v.x, i), dropped(v.y, i + 1u), dropped(v.z, i + 2u),
                     dropped(v.w, i + 3u));
}

// First element of row `row` (= o·T + t) and the channel stride.
fn row_base(row: u32) -> u32 {
    let o = row / p.steps;
    let t = row - o * p.steps;
    return o * p.channels * p.steps + t;
}

@compute @workgroup_size(256)
fn layer_norm_forward(@builtin(workgroup_id) wg: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
                      @builtin(local_invocation_index) li: u32) {
    let row = flat_index(wg, nwg, li, LN_WG);
    if row >= p.outer * p.steps {
        return;
    }
    let base = row_base(row);
    let c = f32(p.channels);
    var s = 0.0;
    for (var k = 0u; k < p.channels; k++) {
        s += x[base + k * p.steps];
    }
    let mu = s / c;
    var v = 0.0;
    for (var k = 0u; k < p.channels; k++) {
        let d = x[base + k * p.steps] - mu;
        v += d * d;
    }
    let r = 1.0 / sqrt(v / c + p.eps);
    mean[row] = mu;
    rstd[row] = r;
    for (var k = 0u; k < p.channels; k++) {
        let i = base + k * p.steps;
        y[i] = dropped(gamma[k] * (x[i] - mu) * r + beta[k], i);
    }
}

// ---- backward ---------------------------------------------------------------------------
// Input gradient: dx = r/C · (C·g − Σg − x̂·Σ(g·x̂)), g = dy·γ, per row.

@group(0) @binding(1) var<storage, read> bx: array<f32>;
@group(0) @binding(2) var<storage, read> bgamma: array<f32>;
@group(0) @binding(3) var<storage, read> bdy: array<f32>;
@group(0) @binding(4) var<storage, read> bmean: array<f32>;
@group(0) @binding(5) var<storage, read> brstd: array<f32>;
@group(0) @binding(6) var<storage, read_write> dx: array<f32>;

@compute @workgroup_size(256)
fn layer_norm_backward_input(@builtin(workgroup_id) wg: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
                             @builtin(local_invocation_index) li: u32) {
    let row = flat_index(wg, nwg, li, LN_WG);
    if row >= p.outer * p.steps {
        return;
    }
    let base = row_base(row);
    let mu = bmean[row];
    let r = brstd[row];
    var sg = 0.0;
    var sgx = 0.0;
    for (var k = 0u; k < p.channels; k++) {
        let i = base + k * p.steps;
        let g = dropped(bdy[i], i) * bgamma[k];
        sg += g;
        sgx += g * (bx[i] - mu) * r;
    }
    let c = f32(p.channels);
    for (var k = 0u; k < p.channels; k++) {
        let i = base + k * p.steps;
        let xh = (bx[i] - mu) * r;
        var v = r / c * (c * dropped(bdy[i], i) * bgamma[k] - sg - xh * sgx);
        if p.relu_input != 0u && bx[i] <= 0.0 {
            v = 0.0;
        }
        if p.accumulate != 0u {
            dx[i] = dx[i] + v;
        } else {
            dx[i] = v;
        }
    }
}

// The forward and input-gradient maps four rows (t .. t+3) per invocation, when T is a
// multiple of 4: vector loads and stores along t (about 2x faster on lavapipe).
@group(0) @binding(1) var<storage, read> x4: array<vec4<f32>>;
@group(0) @binding(4) var<storage, read_write> y4: array<vec4<f32>>;
@group(0) @binding(5) var<storage, read_write> mean4: array<vec4<f32>>;
@group(0) @binding(6) var<storage, read_write> rstd4: array<vec4<f32>>;

// Vector index of channel 0 of quad `q` (rows 4q .. 4q+3), and the channel stride.
fn quad_base(q: u32) -> u32 {
    let quads = p.steps / 4u;
    let o = q / quads;
    return o * p.channels * quads + (q - o * quads);
}

@compute @workgroup_size(256)
fn layer_norm_forward4(@builtin(workgroup_id) wg: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
                       @builtin(local_invocation_index) li: u32) {
    let q = flat_index(wg, nwg, li, LN_WG);
    let quads = p.steps / 4u;
    if q >= p.outer * quads {
        return;
    }
    let base = quad_base(q);
    let c = f32(p.channels);
    var s = vec4<f32>(0.0);
    for (var k = 0u; k < p.channels; k++) {
        s += x4[base + k * quads];
    }
    let mu = s / c;
    var v = vec4<f32>(0.0);
    for (var k = 0u; k < p.channels; k++) {
        let d = x4[base + k * quads] - mu;
        v += d * d;
    }
    let r = 1.0 / sqrt(v / c + p.eps);
    mean4[q] = mu;
    rstd4[q] = r;
    for (var k = 0u; k < p.channels; k++) {
        let i = base + k * quads;
        y4[i] = dropped4(gamma[k] * (x4[i] - mu) * r + beta[k], i);
    }
}

@group(0) @binding(1) var<storage, read> bx4: array<vec4<f32>>;
@group(0) @binding(3) var<storage, read> bdy4: array<vec4<f32>>;
@group(0) @binding(4) var<storage, read> bmean4: array<vec4<f32>>;
@group(0) @binding(5) var<storage, read> brstd4: array<vec4<f32>>;
@group(0) @binding(6) var<storage, read_write> dx4: array<vec4<f32>>;

@compute @workgroup_size(256)
fn layer_norm_backward_input4(@builtin(workgroup_id) wg: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
                              @builtin(local_invocation_index) li: u32) {
    let q = flat_index(wg, nwg, li, LN_WG);
    let quads = p.steps / 4u;
    if q >= p.outer * quads {
        return;
    }
    let base = quad_base(q);
    let mu = bmean4[q];
    let r = brstd4[q];
    var sg = vec4<f32>(0.0);
    var sgx = vec4<f32>(0.0);
    for (var k = 0u; k < p.channels; k++) {
        let i = base + k * quads;
        let g = dropped4(bdy4[i], i) * bgamma[k];
        sg += g;
        sgx += g * (bx4[i] - mu) * r;
    }
    let c = f32(p.channels);
    for (var k = 0u; k < p.channels; k++) {
        let i = base + k * quads;
        let xh = (bx4[i] - mu) * r;
        var v = r / c * (c * dropped4(bdy4[i], i) * bgamma[k] - sg - xh * sgx);
        if p.relu_input != 0u {
            v = select(vec4<f32>(0.0), v, bx4[i] > vec4<f32>(0.0));
        }
        if p.accumulate != 0u {
            v += dx4[i];
        }
        dx4[i] = v;
    }
}

// Parameter gradients: dγ[c] = Σ dy·x̂, dβ[c] = Σ dy over all rows (dy through the
// dropout's mask when it is fused). One workgroup per channel and slice of the outer
// axis (workgroup (c, s)); its threads stride over the slice's rows and reduce in
// workgroup memory. Unsplit (slices = 1), it writes dγ[c] and dβ[c]; split (a GPU has far
// more workgroups to fill than channels), it writes its slice's sums to element
// s·C + c of two scratch buffers, always overwriting, and `layer_norm_params_sum` adds
// the slices in order.

@group(0) @binding(1) var<storage, read> px: array<f32>;
@group(0) @binding(2) var<storage, read> pdy: array<f32>;
@group(0) @binding(3) var<storage, read> pmean: array<f32>;
@group(0) @binding(4) var<storage, read> prstd: array<f32>;
@group(0) @binding(5) var<storage, read_write> dgamma: array<f32>;
@group(0) @binding(6) var<storage, read_write> dbeta: array<f32>;

var<workgroup> red_g: array<f32, 256>;
var<workgroup> red_b: array<f32, 256>;

@compute @workgroup_size(256)
fn layer_norm_backward_params(@builtin(workgroup_id) wg: vec3<u32>, @builtin(local_invocation_index) li: u32) {
    let k = wg.x;
    let slice = wg.y;
    let begin = slice * p.slice;
    let end = min(begin + p.slice, p.outer) * p.steps;
    var sg = 0.0;
    var sb = 0.0;
    // row = o * steps + t from the slice's first row by LN_WG, (o, t) kept by `flat_walk`.
    var at = flat_walk(begin * p.steps + li, LN_WG, p.steps);
    for (var row = begin * p.steps + li; row < end; row += LN_WG) {
        let i = (at.o * p.channels + k) * p.steps + at.i;
        let g = dropped(pdy[i], i);
        sg += g * (px[i] - pmean[row]) * prstd[row];
        sb += g;
        at = flat_walk_next(at);
    }
    red_g[li] = sg;
    red_b[li] = sb;
    workgroupBarrier();
    for (var half = LN_WG / 2u; half > 0u; half /= 2u) {
        if li < half {
            red_g[li] += red_g[li + half];
            red_b[li] += red_b[li + half];
        }
        workgroupBarrier();
    }
    if li == 0u {
        let o = slice * p.channels + k;
        if p.accumulate != 0u && p.slices == 1u {
            dgamma[o] = dgamma[o] + red_g[0];
            dbeta[o] = dbeta[o] + red_b[0];
        } else {
            dgamma[o] = red_g[0];
            dbeta[o] = red_b[0];
        }
    }
}

// The second launch of a split parameter gradient: dγ[c] (+)= Σ_s partial_g[s·C + c] and
// dβ likewise, the slices added in order, one invocation per channel.
@group(0) @binding(1) var<storage, read> partial_g: array<f32>;
@group(0) @binding(2) var<storage, read> partial_b: array<f32>;

@compute @workgroup_size(64)
fn layer_norm_params_sum(@builtin(global_invocation_id) gid: vec3<u32>) {
    let k = gid.x;
    if k >= p.channels {
        return;
    }
    var sg = 0.0;
    var sb = 0.0;
    for (var s = 0u; s < p.slices; s++) {
        sg += partial_g[s * p.channels + k];
        sb += partial_b[s * p.channels + k];
    }
    if p.accumulate != 0u {
        sg += dgamma[k];
        sb += dbeta[k];
    }
    dgamma[k] = sg;
    dbeta[k] = sb;
}
