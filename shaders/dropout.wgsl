// Inverted dropout with a counter-based RNG (Rust side:
// src/model/block/residual_layer_norm/dropout_kernel.rs): element i of
// training step `step` is kept when hash(i, seed, step) ≥ p·2³², then scaled by 1/(1−p).
// The mask is never stored: the backward pass recomputes the same bits from the same
// (seed, step), so forward and backward always agree.

struct DropParams {
    n: u32,
    seed: u32,
    step: u32,
    threshold: u32,
    scale: f32,
    accumulate: u32,
    // Element i draws the bit of index i·stride + offset (a strided subset of a larger
    // tensor gets the bits it has in the whole one).
    stride: u32,
    offset: u32,
}

const DROP_WG: u32 = 256u;

@group(0) @binding(0) var<uniform> p: DropParams;
@group(0) @binding(1) var<storage, read> src: array<f32>;
@group(0) @binding(2) var<storage, read_write> dst: array<f32>;

// lowbias32 is common.wgsl's (shared with layer_norm.wgsl, which fuses this mask).
fn keep(i: u32) -> bool {
    return lowbias32(i ^ lowbias32(p.seed ^ lowbias32(p.step))) >= p.threshold;
}

// Forward (src = x, dst = y) and backward (src = dy, dst = dx) are the same map.
@compute @workgroup_size(256)
fn dropout(@builtin(workgroup_id) wg: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
           @builtin(local_invocation_index) li: u32) {
    let i = flat_index(wg, nwg, li, DROP_WG);
    if i >= p.n {
        return;
    }
    let v = select(0.0, src[i] * p.scale, keep(i * p.stride + p.offset));
    if p.accumulate != 0u {
        dst[i] = dst[i] + v;
    } else {
        dst[i] = v;
    }
}
