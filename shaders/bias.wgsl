// Per-channel bias over a tensor viewed as [outer, channels, inner] (Rust side:
// src/ops/bias.rs): the convolution biases (outer = B·N, inner = T), the attention
// score biases be/bs broadcast over the batch (outer = B, channels = T·T or N·N,
// inner = 1) and the head bias (outer = B, channels = O, inner = 1).

struct BiasParams {
    outer: u32,
    channels: u32,
    inner: u32,
    accumulate: u32,
    // `bias_grad` split along the outer axis: rows per slice and number of slices (the
    // whole axis and 1 when unsplit).
    slice: u32,
    slices: u32,
    pad0: u32,
    pad1: u32,
}

const BIAS_WG: u32 = 256u;
const GRAD_WG: u32 = 64u;

@group(0) @binding(0) var<uniform> p: BiasParams;

// y[o, c, i] += bias[c], in place.
@group(0) @binding(1) var<storage, read> bias: array<f32>;
@group(0) @binding(2) var<storage, read_write> y: array<f32>;

@compute @workgroup_size(256)
fn bias_add(@builtin(workgroup_id) wg: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
            @builtin(local_invocation_index) li: u32) {
    let i = flat_index(wg, nwg, li, BIAS_WG);
    if i >= p.outer * p.channels * p.inner {
        return;
    }
    let c = (i / p.inner) % p.channels;
    y[i] = y[i] + bias[c];
}

// dbias[c] (+)= Σ_{o,i} dy[o, c, i]: one workgroup per channel and slice of the outer
// axis, a strided sum per invocation over the flat (o, i) index (consecutive invocations
// read consecutive i), then a tree reduction. The (o, i) pair advances by a fixed step
// (`flat_walk`, which lifted this kernel from ~1 GB/s with a division per term). Split
// into `slices` (a GPU has far more workgroups to fill than channels), workgroup (c, s)
// writes its slice's sum to dbias[s * channels + c] of a scratch buffer, which
// `bias_grad_columns` then adds up (as a [slices, channels, 1] tensor, slices in order).
@group(0) @binding(1) var<storage, read> dy: array<f32>;
@group(0) @binding(2) var<storage, read_write> dbias: array<f32>;

var<workgroup> partial: array<f32, GRAD_WG>;

@compute @workgroup_size(64)
fn bias_grad(@builtin(workgroup_id) wg: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
             @builtin(local_invocation_index) li: u32) {
    let g = wg.y * nwg.x + wg.x;
    let c = g % p.channels;
    let slice = g / p.channels;
    let in_range = slice < p.slices;
    var s = 0.0;
    if in_range {
        let row = p.channels * p.inner;
        let begin = slice * p.slice;
        let end = min(begin + p.slice, p.outer);
        for (var at = flat_walk(begin * p.inner + li, GRAD_WG, p.inner); at.o < end; at = flat_walk_next(at)) {
            s += dy[at.o * row + c * p.inner + at.i];
        }
    }
    partial[li] = s;
    workgroupBarrier();
    for (var half = GRAD_WG / 2u; half > 0u; half /= 2u) {
        if li < half {
            partial[li] += partial[li + half];
        }
        workgroupBarrier();
    }
    if in_range && li == 0u {
        let o = slice * p.channels + c;
        if p.accumulate != 0u {
            dbias[o] = dbias[o] + partial[0];
        } else {
            dbias[o] = partial[0];
        }
    }
}

// The same sum with one invocation per channel looping over (o, i): for many channels with
// few terms each (be, bs: T·T or N·N channels over a batch of B), where a workgroup and a
// tree reduction per channel cost far more than the terms (5x faster on lavapipe), and
// for the slices of a split `bias_grad`.
@compute @workgroup_size(64)
fn bias_grad_columns(@builtin(workgroup_id) wg: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
                     @builtin(local_invocation_index) li: u32) {
    let c = flat_index(wg, nwg, li, GRAD_WG);
    if c >= p.channels {
        return;
    }
    var s = 0.0;
    for (var o = 0u; o < p.outer; o++) {
        let base = (o * p.channels + c) * p.inner;
        for (var i = 0u; i < p.inner; i++) {
            s += dy[base + i];
        }
    }
    if p.accumulate != 0u {
        s += dbias[c];
    }
    dbias[c] = s;
}
